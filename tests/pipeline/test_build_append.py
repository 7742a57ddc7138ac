"""``mars-pairs build --append``: a second release appended equals a single build of both
releases (manifest rows as a set, splits, failures, the leak check), never touching the
shards that exist; a changed config is refused naming the key; a killed append reruns to
the same dataset (issue 24)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import yaml

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.append import check_append_config, plan_append, snapshot_base
from mars_pairs.pipeline.builder.layout import stamp_path
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import BuildConfig, load_config
from mars_pairs.store.seal import chain_damage
from support.configs import config_file

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

DRIVER = Path(__file__).with_name("append_crash_driver.py")
#: manifest columns that name where a member lies: they differ between two layouts of chunks
LOCATION_SUFFIXES = ("_shard", "_offset")


def _releases(mission: Path, root: Path) -> tuple[list[str], list[str]]:
    """A copy of the mission's labels under ``root/labels`` as two releases: release 1 the
    labels of the first half of the stops (explicit paths) and a broken label, release 2 every
    label of the folder, which adds the other stops, a newer version of a release-1 product
    (the same product id under another name: a duplicate key) and another broken label."""
    labels = root / "labels"
    shutil.copytree(mission / "labels", labels)
    truth = pq.read_table(mission / "truth.parquet", columns=["label_path", "stop"]).to_pylist()
    stops = sorted({row["stop"] for row in truth})
    first = sorted(
        Path(row["label_path"]).name for row in truth if row["stop"] in stops[: len(stops) // 2]
    )
    assert first and len(first) < len(truth)
    (labels / "AAA_0000_broken.xml").write_text("not a label")
    (labels / "ZZZ_9999_broken.xml").write_text("not a label")
    newer = labels / first[0].replace("J01.xml", "J02.xml")
    assert newer.name != first[0]
    shutil.copyfile(labels / first[0], newer)
    release1 = [str(labels / name) for name in (*first, "AAA_0000_broken.xml")]
    return release1, [str(labels / "*.xml")]


def _config(
    path: Path, mission: Path, labels: list[str], out: Path, **sections: dict[str, Any]
) -> Path:
    """A cheap build config YAML: 8 m chips, 1 label a shard, a cross-area split holding
    out a 4 m box around the last stop (every stop is ~16 m from the next: both splits kept)."""
    truth = pq.read_table(mission / "truth.parquet", columns=["stop", "easting", "northing"])
    last = max(truth.to_pylist(), key=lambda row: row["stop"])
    x, y = last["easting"], last["northing"]
    splits = {
        "style": "cross-area",
        "areas": {"test": [[x - 2, y - 2, x + 2, y + 2]]},
        "guard": "chip",
        "buffer_m": 0,
    }
    base = {
        "geometry": {"radius": 200, "ray_stride": 64},
        "chips": {"size_m": 8, "size_px": 16},
        "output": {"shard_size": 1},
    }
    merged = {name: {**base.get(name, {}), **values} for name, values in sections.items()}
    return config_file(
        path, mission, out, labels=labels, whole={"splits": splits}, **{**base, **merged}
    )


def _rows(out: Path) -> list[dict[str, Any]]:
    """The manifest rows without the member locations (shard and offset), sorted by key."""
    table = pq.read_table(out / "manifest.parquet")
    keep = [c for c in table.column_names if not c.endswith(LOCATION_SUFFIXES)]
    return sorted(table.select(keep).to_pylist(), key=lambda row: row["key"])


def _failures(out: Path) -> list[tuple[Any, ...]]:
    rows = pq.read_table(out / "failures.parquet").to_pylist()
    return sorted(tuple(row.values()) for row in rows)


def _shards(out: Path) -> dict[str, tuple[int, bytes]]:
    """Each shard's mtime (ns) and bytes."""
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "shards").iterdir()}


def _build(path: Path, **kw: Any) -> Any:
    return run_build(load_config(path), progress=False, **kw)


@pytest.fixture
def releases(small_mission: Path, tmp_path: Path) -> tuple[Path, Path, Path]:
    """Configs of release 1 and release 2 into one folder, and its path."""
    release1, release2 = _releases(small_mission, tmp_path)
    out = tmp_path / "ds"
    one = _config(tmp_path / "one.yaml", small_mission, release1, out)
    two = _config(tmp_path / "two.yaml", small_mission, release2, out)
    return one, two, out


def test_an_append_equals_a_single_build_of_both_releases(
    releases: tuple[Path, Path, Path], small_mission: Path, tmp_path: Path
) -> None:
    one, two, out = releases
    _build(one)
    before = _shards(out)
    assert len(before) == 2  # the first stop's two images; the broken label failed

    summary = _build(two, append=True)

    after = _shards(out)
    assert {name: after[name] for name in before} == before  # bytes and mtimes kept
    assert len(after) == 4  # two new shards (the other stop); the duplicate wrote none
    # a single build of both releases
    single = tmp_path / "single"
    both = _config(tmp_path / "both.yaml", small_mission, load_config(two).inputs.labels, single)
    _build(both)
    assert _rows(out) == _rows(single)
    assert _failures(out) == _failures(single)
    splits = {r["key"]: r["split"] for r in _rows(out)}
    assert set(splits.values()) == {"train", "test"}  # the split of a single build, both kept
    doc = json.loads((out / "dataset.json").read_text())
    ref = json.loads((single / "dataset.json").read_text())
    assert doc["splits"] == ref["splits"]  # the leak check over the whole dataset
    assert doc["counts"] == ref["counts"]
    assert chain_damage(out) == []  # the append rewrote the folder's integrity chain
    assert sorted(doc["files"]) == sorted(ref["files"])
    assert doc["counts"]["failures"] == 3  # 2 broken labels and the duplicate key
    duplicate = [f for f in _failures(out) if "DuplicateKeyError" in f]
    assert len(duplicate) == 1 and "J02.xml" in duplicate[0][1]
    # the append is recorded; the skipped count is printed
    (record,) = doc["appends"]
    assert record["labels_seen"] == 4 + 1 + 2  # the images, the newer version, 2 broken
    assert record["labels_known"] == 3  # release 1's two images and its broken label
    assert record["labels_added"] == 4
    assert (record["samples"], record["failures"]) == (2, 2)
    assert record["labels"] == ["../labels/*.xml"] and len(record["previous_labels"]) == 3
    assert "7 labels matched, 3 already in the dataset (skipped), 4 new" in summary.format()
    # base chunks 0-2 (the broken label, the 2 images); new chunks 3-6 after them
    assert sorted({name[:12] for name in after}) == [f"shard-{k:06d}" for k in (1, 2, 4, 5)]
    assert not (out / "parts").exists()

    # the same release again: nothing new, nothing written
    files = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    again = _build(two, append=True)
    assert again.chunks_built == 0 and "0 new" in again.format()
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == files
    # a finished appended dataset is the finished build of its config: --resume does nothing
    assert _build(two, resume=True).chunks_built == 0
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == files


def _expect_refusal(config: BuildConfig, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        run_build(config, progress=False, append=True)


def test_append_refuses_a_changed_config_naming_the_key(
    releases: tuple[Path, Path, Path],
    small_mission: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    one, two, out = releases
    labels = load_config(two).inputs.labels
    with pytest.raises(ConfigError, match="--append adds to a finished dataset"):
        _build(two, append=True)  # nothing built yet
    _build(one)
    before = sorted((p, p.stat().st_mtime_ns) for p in out.rglob("*"))

    changed = _config(tmp_path / "c.yaml", small_mission, labels, out, chips={"size_px": 32})
    _expect_refusal(load_config(changed), r"^chips\.size_px: changed .*16 -> 32")
    blocks = _config(tmp_path / "s.yaml", small_mission, labels, out, splits={"seed": 5})
    _expect_refusal(load_config(blocks), r"^splits\.seed: changed")
    # the DEM's bytes (a copy elsewhere with the same bytes would do)
    dem = tmp_path / "dem.tif"
    dem.write_bytes((small_mission / "orbital" / "dem.tif").read_bytes() + b"\0")
    moved = _config(tmp_path / "d.yaml", small_mission, labels, out)
    doc = yaml.safe_load(moved.read_text())
    doc["inputs"]["dem"] = str(dem)
    moved.write_text(yaml.safe_dump(doc))
    _expect_refusal(load_config(moved), r"^inputs\.dem: .*changed since the dataset was built")
    # a release whose globs start elsewhere would move the labels root
    elsewhere = tmp_path / "elsewhere" / "labels"
    elsewhere.mkdir(parents=True)
    root = _config(tmp_path / "r.yaml", small_mission, [*labels, str(elsewhere / "*.xml")], out)
    _expect_refusal(load_config(root), r"^inputs\.labels: the labels root would move")
    # what an append does not support (the same in the dataset and the release)
    keep = _config(tmp_path / "k.yaml", small_mission, labels, out, output={"keep_parts": True})
    _expect_refusal(load_config(keep), r"^output\.keep_parts: true: .*cannot --append")
    drop = load_config(
        _config(tmp_path / "p.yaml", small_mission, labels, out, splits={"buffer_policy": "drop"})
    )
    built = json.loads((out / "dataset.json").read_text())
    built["config"]["splits"]["buffer_policy"] = "drop"
    with pytest.raises(ConfigError, match=r"^splits\.buffer_policy: drop: .*cannot --append"):
        check_append_config(drop, built)
    assert sorted((p, p.stat().st_mtime_ns) for p in out.rglob("*")) == before
    # a new PLACES table (the same rows here, another file) is accepted
    places = tmp_path / "places.csv"
    shutil.copyfile(small_mission / "places" / "best_interp.csv", places)
    doc = yaml.safe_load(two.read_text())
    doc["inputs"]["places"] = str(places)
    two.write_text(yaml.safe_dump(doc))
    assert plan_append(load_config(two)).labels_new == 4
    assert main(["build", "--config", str(two), "--append", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert "7 labels matched, 3 already in the dataset (skipped), 4 new" in printed
    assert "chunks: 3 kept, 4 new (chunks 3 to 6)" in printed
    assert sorted((p, p.stat().st_mtime_ns) for p in out.rglob("*")) == before
    # an append killed once its stamp is written: a plain --resume and an append of another
    # release are refused, naming what to do; the append itself then finishes
    snapshot_base(out)
    stamp_path(out).write_text(json.dumps(plan_append(load_config(two)).fingerprint))
    with pytest.raises(ConfigError, match="interrupted --append; rerun it with --append"):
        _build(two, resume=True)
    _expect_refusal(load_config(one), "an interrupted --append of another release")
    assert _build(two, append=True).chunks_built == 4


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="the driver forks its builds")
def test_a_killed_append_reruns_to_the_same_dataset(releases: tuple[Path, Path, Path]) -> None:
    one, two, _ = releases
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(
        [sys.executable, str(DRIVER), str(one), str(two), "0"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["mismatched"] == [], report["mismatched"]
    assert report["killed"] == len(report["points"])
    ops = [tuple(op) for op in report["ops"]]
    assert len(report["points"]) == 4
    # the append writes no shard of the base (the duplicate's chunk 3 is the append's own)
    assert not [
        p for o, p in ops if o == "unlink" and p.startswith("shards/") and p < "shards/shard-000003"
    ]
    assert ops[-1] == ("rmdir", "parts")


def _moved(config: Path, out: Path) -> Path:
    """``config`` writing into ``out`` instead."""
    doc = yaml.safe_load(config.read_text())
    doc["output"]["dir"] = str(out)
    path = config.with_name(f"{out.name}-{config.name}")
    path.write_text(yaml.safe_dump(doc))
    return path


def test_an_append_on_dask_gives_the_in_process_bytes(
    releases: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    """The append goes through the Engine contract: on a Dask cluster (its workers write the
    shards) the release-1 build and the append give the in-process files byte for byte."""
    distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")
    from mars_pairs.pipeline.builder.dask_engine import DaskEngine

    one, two, out = releases
    _build(one)
    _build(two, append=True)
    on_dask = tmp_path / "on-dask"
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
        host="127.0.0.1",
    ) as cluster:  # fmt: skip
        engine = DaskEngine(scheduler=cluster.scheduler_address, announce=False)
        _build(_moved(one, on_dask), engine=engine)
        _build(_moved(two, on_dask), append=True, engine=engine)

    def files(root: Path) -> dict[str, bytes]:
        names = ["manifest.parquet", "failures.parquet", *sorted(
            p.relative_to(root).as_posix() for p in (root / "shards").iterdir()
        )]  # fmt: skip
        return {name: (root / name).read_bytes() for name in names}

    assert files(on_dask) == files(out)
