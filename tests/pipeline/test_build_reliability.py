"""Bad build inputs (issue 17): one bad label, PLACES cell or duplicate costs one failure row,
worker start-up failures fail once whatever the worker count, limits and counts are checked."""

from __future__ import annotations

import errno
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError, StageError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.builder.worker import check_record
from mars_pairs.pipeline.config import load_config
from mars_pairs.pipeline.sample.build_sample import Sample
from mars_pairs.store.atomic import atomic_write_bytes, write_parquet_atomic
from mars_pairs.store.manifest import FAILURE_SCHEMA, rows_to_table
from mars_pairs.store.shards import ShardWriter
from support.configs import build_config, config_file
from support.members import sample_members, tar_members

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mission(small_mission: Path) -> Path:
    return small_mission


def write_config(path: Path, mission: Path, out: Path, labels: Path, places: Path) -> Path:
    return config_file(
        path, mission, out, labels=labels / "*.xml", places=places, chips={"size_px": 32},
        output={"shard_size": 2, "keep_parts": True},  # a part is deleted
    )  # fmt: skip


def copy_labels(mission: Path, dest: Path) -> list[Path]:
    """The mission's labels and images copied into ``dest`` (sorted label paths)."""
    dest.mkdir(parents=True, exist_ok=True)
    for f in (mission / "labels").iterdir():
        shutil.copy(f, dest / f.name)
    return sorted(dest.glob("*.xml"))


def variant(label: Path, name: str, old: str, new: str) -> Path:
    """A copy of ``label`` named ``name`` with ``old`` replaced by ``new`` (the image is the
    original's: the label points to it by name)."""
    text = label.read_text()
    assert old in text, old
    out = label.with_name(name)
    out.write_text(text.replace(old, new, 1))
    return out


def alternate_id(label: Path) -> str:
    found = re.search(r"<alternate_id>([^<]+)</alternate_id>", label.read_text())
    assert found
    return found.group(1)


def failures(out: Path) -> dict[str, dict]:
    return {Path(r["path"]).name: r for r in pq.read_table(out / "failures.parquet").to_pylist()}


@pytest.fixture(scope="module")
def bad_labels_build(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A build over the 4 good labels plus: a sol too large for int32, an alternate_id with
    '/', an id too long for a tar member name, and a second label with a good one's id."""
    tmp = tmp_path_factory.mktemp("bad")
    labels = copy_labels(mission, tmp / "labels")
    first, pid = labels[0], alternate_id(labels[0])
    variant(
        first, "a_huge_sol.xml", "<mars2020:sol_number>52<", "<mars2020:sol_number>99999999999<"
    )
    variant(first, "b_slash.xml", f"<alternate_id>{pid}<", f"<alternate_id>{pid[:8]}/{pid[9:]}<")
    variant(first, "c_long.xml", f"<alternate_id>{pid}<", f"<alternate_id>{pid * 5}<")
    variant(first, "zz_duplicate.xml", "<mars2020:sol_number>52<", "<mars2020:sol_number>52<")
    places = mission / "places" / "best_interp.csv"
    config = load_config(write_config(tmp / "c.yaml", mission, tmp / "ds", tmp / "labels", places))
    summary = run_build(config, progress=False)
    assert summary.samples == 4
    return tmp / "ds"


def test_a_sol_too_large_for_the_manifest_is_a_failure_row(bad_labels_build: Path) -> None:
    row = failures(bad_labels_build)["a_huge_sol.xml"]
    assert row["stage"] == "label" and "sol_number" in row["message"], row
    assert "99999999999" in row["message"]


def test_an_alternate_id_with_a_slash_is_a_failure_row(bad_labels_build: Path) -> None:
    row = failures(bad_labels_build)["b_slash.xml"]
    assert row["stage"] == "label" and "alternate_id" in row["message"], row


def test_an_id_too_long_for_tar_is_a_failure_row(bad_labels_build: Path) -> None:
    row = failures(bad_labels_build)["c_long.xml"]
    assert row["stage"] == "label" and "alternate_id: longer than" in row["message"], row


@pytest.mark.parametrize(
    ("key", "row", "needle"),
    [
        ("a/b", {}, "must be 1 to 80 characters of a-z"),
        ("a.b", {}, "must be 1 to 80 characters of a-z"),
        ("k" * 81, {}, "must be 1 to 80 characters of a-z"),
        ("ok", {"sol": 2**40}, "sol"),
        ("ok", {"latitude": "north"}, "latitude"),
    ],
)
def test_rows_the_shard_or_manifest_cannot_hold_fail_at_record(
    key: str, row: dict, needle: str
) -> None:
    """Whatever a label reader lets through, a key tar cannot name or a value the manifest
    cannot hold is a 'record' failure of that sample, not a crashed chunk."""
    with pytest.raises(StageError) as exc:
        check_record(Sample(key, {"key": key, **row}))
    assert exc.value.stage == "record" and needle in str(exc.value.error)
    check_record(Sample("m2020_ok-1", {"key": "m2020_ok-1", "sol": 52}))


def test_a_duplicate_product_id_is_a_failure_row_naming_the_first(bad_labels_build: Path) -> None:
    row = failures(bad_labels_build)["zz_duplicate.xml"]
    assert row["stage"] == "record" and row["error_type"] == "DuplicateKeyError", row
    assert "already built from" in row["message"] and "ZLF_0052" in row["message"]
    keys = pq.read_table(bad_labels_build / "manifest.parquet")["key"].to_pylist()
    assert len(keys) == len(set(keys)) == 4
    assert len(tar_members(bad_labels_build)) == 4 * 6  # (it asserts each name once)


def test_resume_over_bad_labels_finishes(bad_labels_build: Path) -> None:
    config = load_config(bad_labels_build.parent / "c.yaml")
    (bad_labels_build / "parts" / "manifest-000003.parquet").unlink()  # the last chunk redone
    summary = run_build(config, resume=True, progress=False)
    assert (summary.samples, summary.failures, summary.chunks_resumed) == (4, 4, 3)
    assert set(failures(bad_labels_build)) == {
        "a_huge_sol.xml",
        "b_slash.xml",
        "c_long.xml",
        "zz_duplicate.xml",
    }


# -- PLACES -------------------------------------------------------------------------------------
def _places_variant(mission: Path, dest: Path, edit: object) -> Path:
    lines = (mission / "places" / "best_interp.csv").read_text().splitlines()
    dest.write_text("\n".join(edit(lines)) + "\n")  # type: ignore[operator]
    return dest


def _drop_column(lines: list[str], name: str) -> list[str]:
    header = lines[0].split(",")
    i = header.index(name)
    return [",".join(c for j, c in enumerate(line.split(",")) if j != i) for line in lines]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_places_table_without_a_column_fails_once_whatever_the_workers(
    mission: Path, tmp_path: Path, workers: int
) -> None:
    places = _places_variant(mission, tmp_path / "p.csv", lambda ls: _drop_column(ls, "drive"))
    config = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", mission / "labels", places)
    cmd = [sys.executable, "-m", "mars_pairs.cli", "build", "--config", str(config), "--quiet"]
    done = subprocess.run(
        [*cmd, "--workers", str(workers)], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert lines == [f"mars-pairs build: {places}: missing column(s) drive"], done.stderr


def test_non_numeric_places_cells_are_failure_rows_or_one_line(
    mission: Path, tmp_path: Path
) -> None:
    def text_easting(lines: list[str]) -> list[str]:
        i = lines[0].split(",").index("easting")
        out = list(lines)
        for k, line in enumerate(out[1:], start=1):
            cells = line.split(",")
            if cells[0] == "ROVER":
                cells[i] = "x"
                out[k] = ",".join(cells)
        return out

    places = _places_variant(mission, tmp_path / "p.csv", text_easting)
    config = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", mission / "labels", places)
    summary = run_build(load_config(config), progress=False)
    assert summary.samples == 0 and summary.failures == 4
    for row in failures(tmp_path / "ds").values():
        assert row["stage"] == "locate" and "easting: expected a number, got 'x'" in row["message"]

    def empty_drive(lines: list[str]) -> list[str]:
        i = lines[0].split(",").index("drive")
        cells = lines[2].split(",")
        cells[i] = ""
        return [lines[0], lines[1], ",".join(cells), *lines[3:]]

    places = _places_variant(mission, tmp_path / "p2.csv", empty_drive)
    config = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", mission / "labels", places)
    assert main(["build", "--config", str(config), "--quiet"]) == 2


def test_conflicting_rover_rows_are_failure_rows(mission: Path, tmp_path: Path) -> None:
    def moved_duplicate(lines: list[str]) -> list[str]:
        header = lines[0].split(",")
        rover = next(line for line in lines[1:] if line.startswith("ROVER"))
        cells = rover.split(",")
        e = header.index("easting")
        cells[e] = f"{float(cells[e]) + 118.0:.4f}"
        return [*lines, ",".join(cells)]

    places = _places_variant(mission, tmp_path / "p.csv", moved_duplicate)
    config = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", mission / "labels", places)
    summary = run_build(load_config(config), progress=False)
    rows = list(failures(tmp_path / "ds").values())
    assert summary.failures == len(rows) >= 1 and summary.samples == 4 - len(rows)
    assert all(
        "conflicting ROVER rows" in r["message"] and "118.000 m" in r["message"] for r in rows
    )


# -- limits and counts --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "value"),
    [("--limit", "-1"), ("--limit", "0"), ("--workers", "-3"), ("--workers", "0")],
)
def test_nonpositive_limit_and_workers_are_refused(
    mission: Path, tmp_path: Path, option: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    config = write_config(
        tmp_path / "c.yaml",
        mission,
        tmp_path / "ds",
        mission / "labels",
        mission / "places" / "best_interp.csv",
    )
    with pytest.raises(SystemExit) as exc:
        main(["build", "--config", str(config), "--quiet", option, value])
    assert exc.value.code == 2
    assert f"argument {option}: expected an integer >= 1" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
    with pytest.raises(ConfigError, match=option):
        run_build(load_config(config), **{option[2:]: int(value)}, progress=False)


# -- a full disk --------------------------------------------------------------------------------
def _full_disk_at(path: Path) -> None:
    """Make the temporary file of ``path`` (this process) a link to /dev/full: ENOSPC."""
    path.parent.mkdir(parents=True, exist_ok=True)
    os.symlink("/dev/full", path.with_name(f".{path.name}.tmp-{os.getpid()}"))


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_disk_names_the_file(tmp_path: Path) -> None:
    _full_disk_at(tmp_path / "shards" / "s.tar")
    full = r"No space left on device: '.*shards/s\.tar'"
    with pytest.raises(OSError, match=full) as exc, ShardWriter(tmp_path, "shards/s.tar") as shard:
        shard.add("k", {"x.bin": os.urandom(1 << 16)})
    assert exc.value.errno == errno.ENOSPC
    _full_disk_at(tmp_path / "dataset.json")
    with pytest.raises(OSError, match=r"No space left on device: '.*dataset\.json'"):
        atomic_write_bytes(tmp_path / "dataset.json", b"{}" * 10000)
    _full_disk_at(tmp_path / "failures.parquet")
    with pytest.raises(OSError, match=r"failures\.parquet"):
        write_parquet_atomic(rows_to_table([], FAILURE_SCHEMA), tmp_path / "failures.parquet")
    assert not (tmp_path / "failures.parquet").exists()


# -- orthos of other data types, FIFO labels ------------------------------------------------
@pytest.mark.parametrize(("dtype", "scale"), [("float32", 1 / 255), ("uint16", 16.0)])
def test_orthos_of_any_dtype_give_the_same_chips(
    mission: Path, tmp_path: Path, dtype: str, scale: float
) -> None:
    """The mission's 8-bit ortho as float32 in [0, 1] (all black before) and as 12-bit uint16
    (all white before) gives chips equal to the 8-bit ones up to the range stretch."""
    import io
    import json

    import numpy as np
    import rasterio
    from PIL import Image

    src = mission / "orbital" / "ortho.tif"
    ortho = tmp_path / f"ortho-{dtype}.tif"
    with rasterio.open(src) as ds:
        profile = {**ds.profile, "dtype": dtype, "nodata": None}
        data = ds.read(1)
    with rasterio.open(ortho, "w", **profile) as dst:
        dst.write((data * scale).astype(dtype), 1)
    low, high = float(data.min()), float(data.max())
    places = mission / "places" / "best_interp.csv"
    chips = {}
    for name, raster in (("u8", src), (dtype, ortho)):
        config = build_config(
            mission, tmp_path / name, labels=mission / "labels" / "ZLF*.xml", places=places,
            inputs={"ortho": str(raster)}, chips={"size_px": 32}, output={"shard_size": 2},
        )  # fmt: skip
        assert run_build(config, progress=False).samples == 2
        first = next(iter(sample_members(tmp_path / name).values()))  # in the first shard
        chips[name] = np.asarray(Image.open(io.BytesIO(first["ortho.png"])))
        ranges = json.loads(first["meta.json"])["ortho_range"]
        if name != "u8":
            assert ranges["source"] == "measured"
            assert (ranges["low"], ranges["high"]) == pytest.approx((low * scale, high * scale))
    u8, other = chips["u8"].astype(float), chips[dtype].astype(float)
    assert other.std() > 10 and 20 < other.mean() < 235  # neither all black nor all white
    stretched = (u8 - low) * 255.0 / (high - low)  # the truth, from the 8-bit chip
    assert np.abs(other - stretched).max() <= 2.0


def test_a_fifo_among_the_labels_is_a_failure_row(mission: Path, tmp_path: Path) -> None:
    labels = tmp_path / "labels"
    copy_labels(mission, labels)
    os.mkfifo(labels / "a_fifo.xml")
    places = mission / "places" / "best_interp.csv"
    config = load_config(
        write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", labels, places)
    )
    summary = run_build(config, progress=False)
    assert (summary.samples, summary.failures) == (4, 1)
    row = failures(tmp_path / "ds")["a_fifo.xml"]
    assert row["stage"] == "label" and "not a regular file" in row["message"]


def test_symlink_loops_and_dangling_links_among_the_labels_are_failure_rows(
    mission: Path, tmp_path: Path
) -> None:
    labels = tmp_path / "labels"
    copy_labels(mission, labels)
    (labels / "self.xml").symlink_to(labels / "self.xml")
    (labels / "dangling.xml").symlink_to(labels / "nowhere.xml")
    places = mission / "places" / "best_interp.csv"
    config = load_config(
        write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", labels, places)
    )
    summary = run_build(config, progress=False)
    assert (summary.samples, summary.failures) == (4, 2)
    rows = failures(tmp_path / "ds")
    for name in ("self.xml", "dangling.xml"):
        assert rows[name]["stage"] == "label", rows[name]
        assert str(labels / name) in rows[name]["message"], rows[name]
    assert "symbolic links" in rows["self.xml"]["message"]
