"""The ``inputs`` section of a build config over a generated mission's folders."""

from __future__ import annotations

from pathlib import Path


def mission_inputs(
    mission: Path, *, labels: str | Path | None = None, places: str | Path | None = None
) -> dict[str, str]:
    """Labels, PLACES table, DEM and ortho of ``mission`` (``synth.generate_mission``'s
    layout); ``labels`` (a glob) and ``places`` replace the mission's own."""
    return {
        "labels": str(labels if labels is not None else mission / "labels" / "*.xml"),
        "places": str(places if places is not None else mission / "places" / "best_interp.csv"),
        "dem": str(mission / "orbital" / "dem.tif"),
        "ortho": str(mission / "orbital" / "ortho.tif"),
    }
