"""Datasets built from a generated mission with ``support.configs``'s builder, for the tests of
a finished folder."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.store.seal import FILES_KEY, seal
from support.configs import build_config, config_doc, config_file

# the small build of the store and CLI tests: 64 m chips of 32 px, 2 samples a shard
SMALL: dict[str, dict[str, Any]] = {"chips": {"size_px": 32}, "output": {"shard_size": 2}}


def build(mission: Path, out: Path, *, resume: bool = False, **overrides: Any) -> Path:
    """Build ``mission`` into ``out`` with one worker (``overrides`` as for
    ``support.configs.config_doc``); asserts no failure row; returns ``out``."""
    config = build_config(mission, out, **overrides)
    summary = run_build(config, workers=1, progress=False, resume=resume)
    assert summary.failures == 0
    return out


def small_sections(**sections: dict[str, Any] | None) -> dict[str, Any]:
    """``SMALL`` updated by ``sections`` (key by key), as keyword overrides."""
    merged: dict[str, Any] = {k: dict(v) for k, v in SMALL.items()}
    for name, values in sections.items():
        merged[name] = None if values is None else {**merged.get(name, {}), **values}
    return merged


def small_doc(mission: Path, out: Path, **sections: Any) -> dict[str, Any]:
    """The config document of the small build (``SMALL``, updated by ``sections``)."""
    return config_doc(mission, out, **small_sections(**sections))


def build_small(mission: Path, out: Path, resume: bool = False, **sections: Any) -> Path:
    """The small build (``SMALL``, updated by ``sections``) of ``mission`` into ``out``."""
    return build(mission, out, resume=resume, **small_sections(**sections))


def cli_built_dataset(base: Path, mission: Path) -> Path:
    """A 4-sample dataset of ``mission`` (2 stops x 2 images) built once per test run by
    ``mars-pairs build`` (its stdout in ``../build.out``): cross-area splits holding out a
    20 m box around the last stop (``test``), the first stop within the buffer zone, so no
    sample is ``train``."""
    work = base / "first-minutes"
    root = work / "ds"
    if (root / "dataset.json").is_file():
        return root
    work.mkdir(exist_ok=True)
    truth = pq.read_table(mission / "truth.parquet").to_pylist()
    last = max(truth, key=lambda r: r["stop"])
    first = min(truth, key=lambda r: r["stop"])
    x, y = last["easting"], last["northing"]
    apart = ((x - first["easting"]) ** 2 + (y - first["northing"]) ** 2) ** 0.5
    splits = {
        "style": "cross-area",
        "guard": "chip",
        "buffer_m": max(5.0, apart),
        "areas": {"test": [[x - 10, y - 10, x + 10, y + 10]]},
    }
    config = config_file(
        work / "c.yaml", mission, root, fine=True, geometry={"radius": 400},
        output={"shard_size": 2}, whole={"splits": splits},
    )  # fmt: skip
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["build", "--config", str(config), "--quiet"]) == 0
    (work / "build.out").write_text(out.getvalue())
    return root


def reseal(root: Path) -> None:
    """Record the folder's files as they are now in its dataset.json and SHA256SUMS (as a
    build does), for tests that damage a manifest on purpose to exercise the member checks
    behind the folder's integrity chain. A folder without dataset.json is left as it is."""
    path = root / "dataset.json"
    if path.is_file():
        doc = json.loads(path.read_bytes())
        doc.pop(FILES_KEY, None)
        seal(root, doc)
