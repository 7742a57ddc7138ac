"""THE build-config builder of the tests: a build of a generated mission, defaults overridden by
keyword.

``config_doc`` gives the YAML document (a dict), ``build_config`` the parsed ``BuildConfig``,
``config_file`` writes the document as YAML and returns its path (for ``load_config`` and the
CLI). Paths in the document are absolute (the mission's folders and ``out``).

Overrides: each keyword names a section whose keys update the defaults' (``chips={"size_px":
32}`` keeps ``size_m``); a section given as ``None`` is left out (e.g. ``splits=None``);
``whole={"splits": {...}}`` replaces whole default sections first (e.g. cross-area splits
without the default ``block_m``), the keyword sections then update them.
``fine=True`` starts from the finer geometry (radius 600 m, every 16th ray, 128 m chips of 128
px) instead of the cheap one (radius 300 m, every 32nd ray, 64 m chips of 64 px).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from mars_pairs.pipeline.config import BuildConfig, parse_config

CHEAP: dict[str, dict[str, Any]] = {
    "geometry": {"radius": 300, "ray_stride": 32},
    "chips": {"size_m": 64, "size_px": 64},
    "splits": {"block_m": 100},
}
FINE: dict[str, dict[str, Any]] = {
    "geometry": {"radius": 600, "ray_stride": 16},
    "chips": {"size_m": 128, "size_px": 128},
    "splits": {"block_m": 100},
}


Labels = str | Path | list[str] | tuple[str, ...]


def mission_inputs(
    mission: Path, *, labels: Labels | None = None, places: str | Path | None = None
) -> dict[str, Any]:
    """Labels, PLACES table, DEM and ortho of ``mission`` (``synth.generate_mission``'s
    layout); ``labels`` (a glob or a list of globs) and ``places`` replace the mission's own."""
    if isinstance(labels, list | tuple):
        return {**mission_inputs(mission, places=places), "labels": [str(g) for g in labels]}
    return {
        "labels": str(labels if labels is not None else mission / "labels" / "*.xml"),
        "places": str(places if places is not None else mission / "places" / "best_interp.csv"),
        "dem": str(mission / "orbital" / "dem.tif"),
        "ortho": str(mission / "orbital" / "ortho.tif"),
    }


def config_doc(
    mission: Path,
    out: Path,
    *,
    fine: bool = False,
    labels: Labels | None = None,
    places: str | Path | None = None,
    whole: dict[str, dict[str, Any]] | None = None,
    **sections: dict[str, Any] | None,
) -> dict[str, Any]:
    """The config document of a build of ``mission`` into ``out`` (see the module)."""
    doc: dict[str, Any] = {
        "inputs": mission_inputs(mission, labels=labels, places=places),
        **{name: dict(values) for name, values in (FINE if fine else CHEAP).items()},
        "output": {"dir": str(out)},
    }
    doc.update(whole or {})
    for name, values in sections.items():
        if values is None:
            doc.pop(name, None)
        else:
            doc[name] = {**doc.get(name, {}), **values}
    return doc


def build_config(
    mission: Path, out: Path, *, base: Path | None = None, **overrides: Any
) -> BuildConfig:
    """``config_doc(mission, out, **overrides)`` parsed (relative paths from ``base``, by
    default the mission)."""
    return parse_config(config_doc(mission, out, **overrides), base=base or mission)


def config_file(path: Path, mission: Path, out: Path, **overrides: Any) -> Path:
    """``config_doc(mission, out, **overrides)`` written as YAML to ``path``; returns ``path``."""
    path.write_text(yaml.safe_dump(config_doc(mission, out, **overrides)))
    return path
