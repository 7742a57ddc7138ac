"""``output.pairs``: the build writes pairs.parquet between samples (keys, splits,
``cross_split``), sealed in dataset.json, the same bytes on a rerun and a resume; without
the key there is none."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import shapely

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder import run as build_run
from mars_pairs.store.seal import chain_damage
from support.builds import build_small


def _splits(mission: Path) -> dict[str, Any]:
    """Cross-area splits holding out a box around the last stop (``test``), the others in
    the buffer zone or train: pairs within a stop and across the boundary."""
    truth = pq.read_table(mission / "truth.parquet").to_pylist()
    last = max(truth, key=lambda r: r["stop"])
    x, y = last["easting"], last["northing"]
    return {
        "style": "cross-area",
        "guard": "chip",
        "buffer_m": 5.0,
        "areas": {"test": [[x - 10, y - 10, x + 10, y + 10]]},
    }


@pytest.fixture(scope="module")
def mission(missions: Any) -> Path:
    return missions(seed=5, stops=3, images_per_stop=3)  # type: ignore[no-any-return]


@pytest.fixture(scope="module")
def with_pairs(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pairs") / "ds"
    return build_small(mission, out, output={"pairs": True}, whole={"splits": _splits(mission)})


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_pairs_hold_the_samples_splits_and_cross_split(with_pairs: Path) -> None:
    """Every pair of manifest samples whose footprints overlap (an all-pairs loop over the
    manifest), each with both samples' splits from the manifest, cross_split where they
    differ; sealed in dataset.json, counted in counts.pairs."""
    manifest = pq.read_table(with_pairs / "manifest.parquet").to_pylist()
    pairs = pq.read_table(with_pairs / "pairs.parquet").to_pylist()
    split = {r["key"]: r["split"] for r in manifest}
    geom = {r["key"]: r["footprint"] and shapely.from_wkb(r["footprint"]) for r in manifest}
    keys = sorted(geom)
    brute = {
        (a, b)
        for i, a in enumerate(keys)
        for b in keys[i + 1 :]
        if geom[a] is not None and geom[b] is not None and geom[a].intersection(geom[b]).area > 0
    }
    assert {(p["key_a"], p["key_b"]) for p in pairs} == brute
    for p in pairs:
        assert (p["split_a"], p["split_b"]) == (split[p["key_a"]], split[p["key_b"]])
        assert p["cross_split"] == (p["split_a"] != p["split_b"])
    assert {p["cross_split"] for p in pairs} == {True, False}
    doc = json.loads((with_pairs / "dataset.json").read_text())
    assert "pairs.parquet" in doc["files"] and doc["counts"]["pairs"] == len(pairs)
    assert doc["config"]["output"]["pairs"] is True
    assert chain_damage(with_pairs) == []


def test_pairs_are_the_same_bytes_on_a_rebuild_and_a_resume(
    mission: Path, with_pairs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A build killed as it comes to write pairs.parquet (every chunk committed), resumed;
    then built again over the same folder: pairs.parquet is the first build's, byte for
    byte, and the folder verifies."""
    sections = {"output": {"pairs": True}, "whole": {"splits": _splits(mission)}}
    out = tmp_path / "ds"

    def killed(*args: object) -> None:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(build_run, "write_dataset_pairs", killed)
        with pytest.raises(KeyboardInterrupt):
            build_small(mission, out, **sections)
    assert not (out / "pairs.parquet").exists() and (out / "parts").is_dir()
    want = _digest(with_pairs / "pairs.parquet")
    build_small(mission, out, resume=True, **sections)
    assert _digest(out / "pairs.parquet") == want
    build_small(mission, out, **sections)
    assert _digest(out / "pairs.parquet") == want
    assert main(["verify", str(out)]) == 0


def test_no_pairs_without_the_key(mission: Path, tmp_path: Path) -> None:
    """Nor after a build with pairs is built again over the same folder without them."""
    out = build_small(mission, tmp_path / "ds", whole={"splits": _splits(mission)})
    assert not (out / "pairs.parquet").exists()
    build_small(mission, out, output={"pairs": True}, whole={"splits": _splits(mission)})
    assert (out / "pairs.parquet").is_file()
    build_small(mission, out, whole={"splits": _splits(mission)})
    assert not (out / "pairs.parquet").exists()
    doc = json.loads((out / "dataset.json").read_text())
    assert "pairs.parquet" not in doc["files"] and "pairs" not in doc["counts"]
    assert "pairs.parquet" not in (out / "README.md").read_text()


def test_the_format_pages_within_train_example_runs(
    with_pairs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """docs/format.md's pyarrow/pandas example of within-train positives, as written."""
    page = (Path(__file__).resolve().parents[2] / "docs" / "format.md").read_text()
    code = page.split("## `pairs.parquet`", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(code.replace("out/demo/dataset", str(with_pairs)), "format.md", "exec"), {})
    arrow, pandas = capsys.readouterr().out.split()
    assert arrow == pandas


def test_the_card_names_pairs_parquet(with_pairs: Path) -> None:
    count = pq.read_metadata(with_pairs / "pairs.parquet").num_rows
    assert f"- `pairs.parquet`: the {count} pairs" in (with_pairs / "README.md").read_text()
