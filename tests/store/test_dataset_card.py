"""A finished dataset folder explains itself: a README dataset card (sources, licence, counts,
columns, members, loading), relative paths only, no ``parts/`` left, and it still loads and
verifies when moved; Hugging Face ``datasets`` loads its shards and manifest offline."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.store.manifest import MANIFEST_SCHEMA
from mars_pairs.store.verify import verify_dataset
from support.builds import build_small, small_sections
from support.configs import build_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_small(small_mission, tmp_path_factory.mktemp("card") / "ds")


def test_a_finished_build_leaves_the_card_and_no_parts(built: Path) -> None:
    names = sorted(p.relative_to(built).as_posix() for p in built.rglob("*"))
    assert not (built / "parts").exists()
    assert not [n for n in names if ".tmp-" in n]
    for name in ("README.md", "croissant.json", "dataset.json", "manifest.parquet"):
        assert name in names
    card = (built / "README.md").read_text()
    info = json.loads((built / "dataset.json").read_text())
    samples = pq.read_metadata(built / "manifest.parquet").num_rows
    assert f"{samples} samples, 0 failures" in card
    for split, n in info["counts"]["by_split"].items():
        assert f"| {split} | {n} |" in card
    # every column of the schema, typed, and every member
    for f in MANIFEST_SCHEMA:
        if not f.name.endswith(("_shard", "_offset", "_size", "_crc32c")):
            assert f"`{f.name}` | " in card, f.name
    for member in ("ground.jpg", "ortho.png", "dem.tif", "viewshed.png", "corr.npy", "meta.json"):
        assert member in card
    # sources with their DOIs, the licence (public domain for PDS data), how to load it
    assert "doi:10.17189/bs6b-4782" in card  # the Perseverance samples' data set, alone
    assert "doi:10.17189/1520328" not in card
    assert info["license"] == "CC0-1.0" and "public domain" in card
    assert "MarsPairsDataset" in card and 'load_dataset(os.path.abspath("."))' in card
    assert "shards-train.txt" in card and "shardindex-train.json" in card
    assert 'load_dataset("parquet", data_files="manifest.parquet"' in card
    assert "gpd.read_parquet" in card
    assert info["crs_name"] in card and "unknown" not in info["crs_name"]


def test_no_absolute_path_of_the_building_machine_is_written(
    built: Path, small_mission: Path
) -> None:
    root = str(small_mission)
    for name in ("README.md", "croissant.json", "dataset.json"):
        assert root not in (built / name).read_text(), name
    config = json.loads((built / "dataset.json").read_text())["config"]
    assert config["output"]["dir"] == "."
    # relative to the dataset folder: they resolve to the inputs from where it was built
    assert (built / config["inputs"]["dem"]).resolve() == (small_mission / "orbital/dem.tif")
    assert (built / json.loads((built / "dataset.json").read_text())["labels_root"]).resolve() == (
        small_mission / "labels"
    )
    labels = pq.read_table(built / "manifest.parquet", columns=["label_path"])
    for path in labels["label_path"].to_pylist():
        assert not Path(path).is_absolute()
        assert (small_mission / "labels" / path).is_file()  # relative to the labels root
    for shard in (built / "shards").glob("*.tar"):
        assert root.encode() not in shard.read_bytes()  # meta.json members too


def test_the_moved_folder_loads_and_verifies(built: Path, tmp_path: Path) -> None:
    from mars_pairs.torch import MarsPairsDataset

    moved = tmp_path / "elsewhere" / "copy"
    shutil.copytree(built, moved)
    report = verify_dataset(moved)
    assert report.damage == [] and report.members > 0
    with MarsPairsDataset(moved) as ds:
        assert len(ds) == pq.read_metadata(built / "manifest.parquet").num_rows
        sample = ds[0]
        assert sample["ortho"].shape[-1] == 32


def test_license_from_the_config(small_mission: Path, tmp_path: Path) -> None:
    out = build_small(small_mission, tmp_path / "ds", output={"license": "CC-BY-4.0"})
    assert json.loads((out / "dataset.json").read_text())["license"] == "CC-BY-4.0"
    assert "`CC-BY-4.0`" in (out / "README.md").read_text()
    assert json.loads((out / "croissant.json").read_text())["license"] == "CC-BY-4.0"
    with pytest.raises(ConfigError, match=r"output\.license"):
        inputs = {"labels": "*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"}
        parse_config({"inputs": inputs, "output": {"dir": "x", "license": 3}}, base=tmp_path)


def test_resume_and_rebuild_over_a_finished_build(small_mission: Path, tmp_path: Path) -> None:
    out = build_small(small_mission, tmp_path / "ds")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    # --resume over the same finished build: nothing to do, nothing written
    config = build_config(small_mission, out, **small_sections())
    summary = run_build(config, resume=True, progress=False)
    assert (summary.chunks_built, summary.chunks_resumed) == (0, 2)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    # another config: --resume refuses, a rebuild clears the finished build's files
    other = build_config(small_mission, out, **small_sections(output={"shard_size": 4}))
    with pytest.raises(ConfigError, match="cannot resume"):
        run_build(other, resume=True, progress=False)
    run_build(other, progress=False)
    assert {p.name[:12] for p in (out / "shards").iterdir()} == {"shard-000000"}
    assert not (out / "parts").exists()
    # output.keep_parts keeps them (a deleted part then redoes its chunk alone)
    kept = build_config(small_mission, out, **small_sections(output={"keep_parts": True}))
    run_build(kept, progress=False)
    assert (out / "parts" / "build.json").is_file()


def test_hugging_face_datasets_load_the_shards_and_the_manifest(
    built: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    from datasets import load_dataset

    shards = sorted(str(p) for p in (built / "shards").glob("*.tar"))
    cache = str(tmp_path / "cache")
    pairs = load_dataset("webdataset", data_files={"train": shards}, split="train", cache_dir=cache)
    keys = pq.read_table(built / "manifest.parquet", columns=["key"])["key"].to_pylist()
    assert sorted(pairs["__key__"]) == sorted(keys)
    assert {"ground.jpg", "ortho.png", "dem.tif", "viewshed.png", "meta.json"} <= set(
        pairs.column_names
    )
    rows = load_dataset(
        "parquet", data_files=str(built / "manifest.parquet"), split="train", cache_dir=cache
    )
    assert rows.num_rows == len(keys) and rows["key"] == keys


def test_the_sources_cited_follow_the_missions() -> None:
    from mars_pairs.store.card import SOURCES_SYNTHETIC, sources

    msl = "\n".join(sources(False, ["msl"]))
    assert "doi:10.17189/1520328" in msl and "bs6b-4782" not in msl
    assert "PLACES" in msl and "HiRISE" in msl
    both = "\n".join(sources(False, []))  # no mission known: every data set
    assert "1520328" in both and "bs6b-4782" in both
    assert sources(True, ["m2020"]) == SOURCES_SYNTHETIC
