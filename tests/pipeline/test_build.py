"""The dataset build on a small synthetic mission: members, failures, workers, kill and resume."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import crc32c
import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely
import shapely.geometry
import yaml
from pyproj import CRS

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from mars_pairs.store.members import MEMBERS
from support.configs import config_file
from support.members import manifest_rows, tar_members
from support.missions import MissionCache

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mission(missions: MissionCache) -> Path:
    return missions(seed=3, stops=3, images_per_stop=2)


def write_config(
    path: Path,
    mission: Path,
    out: Path,
    labels: str | None = None,
    shard_size: int = 2,
    **geometry: object,
) -> Path:
    return config_file(
        path, mission, out, fine=True, labels=labels, geometry=geometry,
        output={"shard_size": shard_size},
    )  # fmt: skip


@pytest.fixture(scope="module")
def built(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("built")
    config = load_config(write_config(tmp / "c.yaml", mission, tmp / "ds"))
    summary = run_build(config, workers=1, progress=False)
    assert summary.failures == 0, pq.read_table(tmp / "ds" / "failures.parquet").to_pylist()
    return tmp / "ds"


def test_every_image_becomes_a_sample_with_all_members(mission: Path, built: Path) -> None:
    rows = manifest_rows(built)
    n_images = len(list((mission / "labels").glob("*.xml")))
    assert len(rows) == n_images
    assert len({r["key"] for r in rows}) == n_images
    members = tar_members(built)
    for row in rows:
        for name in MEMBERS:
            member = row["ground_member"] if name == "ground" else None
            assert row[f"{name}_shard"] is not None, (row["key"], name)
            if member:
                assert f"{row['key']}.{member}" in members
        meta = json.loads(members[f"{row['key']}.meta.json"])
        assert meta["product_id"] == row["product_id"]
        assert row["visible_cells"] > 0 and row["viewshed_area_m2"] > 0
        assert 0 < row["max_visible_range_m"] <= 600 * 1.01
        assert row["split"] in ("train", "val", "test", "buffer")


def test_every_offset_reads_back_the_tar_member(built: Path) -> None:
    members = tar_members(built)
    for row in manifest_rows(built):
        for name in MEMBERS:
            with open(built / row[f"{name}_shard"], "rb") as fh:
                fh.seek(row[f"{name}_offset"])
                data = fh.read(row[f"{name}_size"])
            fld = (
                row["ground_member"]
                if name == "ground"
                else {
                    "ortho": "ortho.png",
                    "dem": "dem.tif",
                    "viewshed": "viewshed.png",
                    "corr": "corr.npy",
                    "meta": "meta.json",
                }[name]
            )
            assert data == members[f"{row['key']}.{fld}"]
            assert row[f"{name}_crc32c"] == crc32c.crc32c(data)  # independent of the writer


def test_ground_member_is_the_original_image(mission: Path, built: Path) -> None:
    members = tar_members(built)
    row = manifest_rows(built)[0]
    original = (mission / "labels" / row["label_path"]).with_suffix(".jpg")  # labels root
    assert members[f"{row['key']}.{row['ground_member']}"] == original.read_bytes()


def test_geoparquet_metadata_and_dataset_json(built: Path) -> None:
    meta = pq.read_schema(built / "manifest.parquet").metadata
    geo = json.loads(meta[b"geo"])
    assert geo["primary_column"] == "footprint"
    crs = CRS.from_json_dict(geo["columns"]["footprint"]["crs"])
    params = {p.name: p.value for p in crs.coordinate_operation.params}
    assert params["Latitude of 1st standard parallel"] == 18.4663  # M2020 PLACES eqc
    assert crs.ellipsoid.semi_major_metre == 3396190.0
    doc = json.loads((built / "dataset.json").read_text())
    assert doc["counts"]["samples"] == len(manifest_rows(built))
    assert doc["chip"]["size_px"] == 128
    # GeoParquet 1.1: geopandas reads it; the bbox holds every footprint (not only the chips)
    import geopandas

    gdf = geopandas.read_parquet(built / "manifest.parquet")
    box = shapely.box(*geo["columns"]["footprint"]["bbox"])
    assert gdf.geometry.notna().all() and all(box.covers(g) for g in gdf.geometry)
    assert list(box.bounds) == pytest.approx(list(gdf.total_bounds))
    # the splits: the buffer covers the footprints' reach, nothing crosses splits
    splits = doc["splits"]
    assert splits["guard"] == "footprint" and splits["guaranteed"]
    assert splits["buffer_m"] >= splits["reach_m"] >= 600
    assert set(splits["intersections_between_splits"].values()) == {0}
    reach = [
        shapely.Point(r["easting"], r["northing"]).hausdorff_distance(g)
        for r, g in zip(gdf.to_dict("records"), gdf.geometry, strict=True)
    ]
    assert max(reach) <= splits["reach_m"]  # the footprints stay within the assumed reach


def test_buffer_samples_can_be_dropped_and_are_counted(
    mission: Path, built: Path, tmp_path: Path
) -> None:
    path = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds")
    doc = yaml.safe_load(path.read_text())
    x, y = manifest_rows(built)[0]["easting"], manifest_rows(built)[0]["northing"]
    test_area = [[x - 5.0, y - 5.0, x + 5.0, y + 5.0]]  # one stop; the others are in its buffer
    doc["splits"] = {"style": "cross-area", "areas": {"test": test_area}}
    doc["splits"].update(guard="chip", buffer_policy="drop")
    path.write_text(yaml.safe_dump(doc))
    summary = run_build(load_config(path), progress=False)
    splits = json.loads((tmp_path / "ds" / "dataset.json").read_text())["splits"]
    rows = manifest_rows(tmp_path / "ds")
    n_images = len(list((mission / "labels").glob("*.xml")))
    assert splits["dropped_in_buffer"] == splits["in_buffer"] == n_images - len(rows) > 0
    assert summary.samples == len(rows) > 0
    assert {r["split"] for r in rows} == {"test"}
    assert splits["buffer_m"] == 128 and splits["intersections_between_splits"]["chip_chip"] == 0


def test_corr_points_land_on_the_chip_where_the_viewshed_is(built: Path) -> None:
    import io

    from PIL import Image

    members = tar_members(built)
    inside = agree = 0
    for row in manifest_rows(built):
        corr = np.load(io.BytesIO(members[f"{row['key']}.corr.npy"]))
        vis = np.asarray(Image.open(io.BytesIO(members[f"{row['key']}.viewshed.png"]))) > 0
        if vis.sum() < 25:
            # the mask holds the pixels whose centre the image saw: a zoom looking down sees
            # less than a pixel or a few, so its hits lie in pixels whose centres it missed
            continue
        # a hit may sit in a cell whose centre is hidden: allow one chip pixel (1 m)
        padded = np.pad(vis, 1)
        vis = np.max(
            [
                padded[i : i + vis.shape[0], j : j + vis.shape[1]]
                for i in range(3)
                for j in range(3)
            ],
            axis=0,
        )
        pts = corr.reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        col, line = np.floor(pts[:, 0]).astype(int), np.floor(pts[:, 1]).astype(int)
        ok = (col >= 0) & (line >= 0) & (col < vis.shape[1]) & (line < vis.shape[0])
        inside += int(ok.sum())
        agree += int(vis[line[ok], col[ok]].sum())
    assert inside > 100
    assert agree / inside >= 0.95


def test_broken_labels_become_failure_rows(mission: Path, tmp_path: Path) -> None:
    labels = tmp_path / "labels"
    shutil.copytree(mission / "labels", labels)
    good = sorted(labels.glob("*.xml"))
    text = good[0].read_text()
    (labels / "ZZ_truncated.xml").write_text(text[: len(text) // 2])
    (labels / "ZZ_random.xml").write_bytes(os.urandom(300))
    no_model = text.replace("geom:Vector_Axis", "geom:Vector_Axe")
    (labels / "ZZ_no_axis.xml").write_text(no_model)
    config = load_config(
        write_config(tmp_path / "c.yaml", mission, tmp_path / "ds", labels=str(labels / "*.xml"))
    )
    summary = run_build(config, progress=False)
    assert summary.samples == len(good)
    failures = pq.read_table(tmp_path / "ds" / "failures.parquet").to_pylist()
    assert {Path(f["path"]).name for f in failures} == {
        "ZZ_truncated.xml",
        "ZZ_random.xml",
        "ZZ_no_axis.xml",
    }
    assert all(f["stage"] == "label" and f["error_type"] == "LabelError" for f in failures)
    assert any("Vector_Axis" in f["message"] for f in failures)
    # --strict stops at the first failure with one line and status 2
    code = main(
        [
            "build",
            "--config",
            str(tmp_path / "c.yaml"),
            "--strict",
            "--quiet",
            "--out",
            str(tmp_path / "strict"),
        ]
    )
    assert code == 2


def test_two_workers_give_the_same_output(mission: Path, built: Path, tmp_path: Path) -> None:
    config = load_config(write_config(tmp_path / "c.yaml", mission, tmp_path / "ds2"))
    run_build(config, workers=2, progress=False)
    assert manifest_rows(tmp_path / "ds2") == manifest_rows(built)
    assert tar_members(tmp_path / "ds2") == tar_members(built)


def _kill_when(cmd: list[str], ready: Callable[[], bool], timeout: float = 60.0) -> bool:
    """Start ``cmd``, SIGKILL it as soon as ``ready()``; False if it finished first."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        if ready():
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            return True
        time.sleep(0.005)
    proc.wait()
    return False


def test_killed_build_resumes_to_the_same_dataset(
    mission: Path, built: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    config_path = write_config(tmp_path / "c.yaml", mission, out, shard_size=1)
    reference = tmp_path / "reference"
    ref_config = write_config(tmp_path / "r.yaml", mission, reference, shard_size=1)
    run_build(load_config(ref_config), progress=False)
    cmd = [
        sys.executable,
        "-m",
        "mars_pairs.cli",
        "build",
        "--config",
        str(config_path),
        "--quiet",
        "--resume",
    ]

    def parts() -> int:
        return len(list((out / "parts").glob("manifest-*.parquet")))

    # killed while writing its first shards, then again two chunks later: never finished
    assert _kill_when(cmd, lambda: parts() >= 1 or bool(list(out.glob("shards/.*.tmp-*"))))
    first = parts()
    assert first < 5
    assert _kill_when(cmd, lambda: parts() >= first + 1)
    assert first < parts() < 6
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert " resumed" in done.stdout and "0 built" not in done.stdout
    assert manifest_rows(out) == manifest_rows(reference)
    assert tar_members(out) == tar_members(reference)
    assert {r["key"] for r in manifest_rows(out)} == {r["key"] for r in manifest_rows(built)}
    assert not list(out.rglob(".*.tmp-*"))


def test_resume_refuses_a_changed_config(mission: Path, tmp_path: Path) -> None:
    path = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds")
    run_build(load_config(path), progress=False, limit=2)
    write_config(path, mission, tmp_path / "ds", radius=400)
    assert main(["build", "--config", str(path), "--resume", "--quiet", "--limit", "2"]) == 2


def test_inspect_counts(built: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(built)]) == 0
    out = capsys.readouterr().out
    assert f"samples: {len(manifest_rows(built))}" in out and "m2020" in out
    assert main(["inspect", str(built / "nope")]) == 2


def test_query_cli_formats(built: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = manifest_rows(built)
    lat = sum(r["latitude"] for r in rows) / len(rows)
    lon = sum(r["longitude"] for r in rows) / len(rows)
    assert main(["query", str(built), "--near", str(lon), str(lat), "5000", "--format", "csv"]) == 0
    csv_lines = capsys.readouterr().out.strip().splitlines()
    assert len(csv_lines) == len(rows) + 1 and csv_lines[0].startswith('"key"')
    assert main(["query", str(built), "--bbox", "0", "0", "1", "1"]) == 0
    assert "(0 rows)" in capsys.readouterr().out
    out = tmp_path / "q.geojson"
    assert (
        main(
            [
                "query",
                str(built),
                "--bbox",
                "-180",
                "-90",
                "180",
                "90",
                "--format",
                "geojson",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    doc = json.loads(out.read_text())
    features = doc["features"]
    assert {f["properties"]["key"] for f in features} == {r["key"] for r in rows}
    assert all(f["geometry"]["type"] == "Polygon" for f in features)
    # longitude/latitude degrees on the Mars sphere: each footprint (the visible cells' hull
    # and the camera centre) reaches its rover position, within the ~1 m mast offset
    assert doc["crs"]["properties"]["name"] == "IAU_2015:49900"
    for f in features:
        footprint = shapely.geometry.shape(f["geometry"])
        rover = shapely.Point(f["properties"]["longitude"], f["properties"]["latitude"])
        assert footprint.distance(rover) < 2.0 / 3396190 * 180 / math.pi / 0.95  # < 2 m
    pyogrio = pytest.importorskip("pyogrio")
    crs = CRS.from_user_input(pyogrio.read_info(out)["crs"])
    assert crs.is_geographic and crs.ellipsoid.semi_major_metre == 3396190.0
    parquet = tmp_path / "q.parquet"
    assert (
        main(
            [
                "query",
                str(built),
                "--polygon",
                "POLYGON((0 0, 1 0, 1 1, 0 0))",
                "--format",
                "parquet",
                "--out",
                str(parquet),
            ]
        )
        == 0
    )
    assert pq.read_table(parquet).num_rows == 0
    assert main(["query", str(built), "--polygon", "not wkt"]) == 2


def test_heading_up_chips_put_the_view_above_the_rover(mission: Path, tmp_path: Path) -> None:
    import io

    from PIL import Image

    path = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds")
    doc = yaml.safe_load(path.read_text())
    doc["chips"]["orientation"] = "heading-up"
    path.write_text(yaml.safe_dump(doc))
    run_build(load_config(path), progress=False)
    members = tar_members(tmp_path / "ds")
    above = total = 0
    for row in manifest_rows(tmp_path / "ds"):
        assert row["chip_rotation_deg"] != 0.0
        vis = np.asarray(Image.open(io.BytesIO(members[f"{row['key']}.viewshed.png"]))) > 0
        rows_visible = np.nonzero(vis)[0]
        above += int((rows_visible < vis.shape[0] / 2).sum())
        total += len(rows_visible)
    assert total > 0 and above / total > 0.95  # the camera looks up the chip


@pytest.mark.parametrize("key", ["dem", "ortho", "places", "labels"])
def test_missing_inputs_exit_2_naming_the_key(
    mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], key: str
) -> None:
    path = write_config(tmp_path / "c.yaml", mission, tmp_path / "ds")
    doc = yaml.safe_load(path.read_text())
    doc["inputs"][key] = str(tmp_path / "absent" / "x.tif")
    path.write_text(yaml.safe_dump(doc))
    assert main(["build", "--config", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"inputs.{key}" in err[0]
    assert not (tmp_path / "ds").exists()  # nothing written


def test_inspect_sorts_sols_as_numbers_and_lists_them_as_runs() -> None:
    from mars_pairs.store.inspect import format_facts, sol_ranges

    assert sol_ranges([100, 9, 10, 11, 99, 13, 9]) == [(9, 11), (13, 13), (99, 100)]
    facts = {
        "dataset": "d", "samples": 3, "by_mission": {"m2020": 3}, "by_instrument": {"X": 3},
        "by_split": {
            "train": {"samples": 2, "share": 2 / 3}, "val": {"samples": 1, "share": 1 / 3},
        },
        "sols": {"distinct": 3, "first": 9, "last": 100, "ranges": ["9-11", "100"]},
        "view_coverage": {"median": 0.05, "by_instrument": {"X": 0.05}, "missing_the_chip": 1},
        "warnings": [], "size_bytes": 10**6,
    }  # fmt: skip
    text = format_facts(facts)
    assert "sols: 3 from 9 to 100, 2 runs of consecutive sols:\n  9-11, 100" in text
    assert "train                           2   66.7 %" in text
    assert "median 5.0 % (X 5.0 %); 1 views miss their chip" in text


def test_inspect_json_holds_the_split_shares_and_view_coverage(
    built: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["inspect", str(built), "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    rows = manifest_rows(built)
    assert facts["samples"] == len(rows)
    assert sum(v["samples"] for v in facts["by_split"].values()) == len(rows)
    assert abs(sum(v["share"] for v in facts["by_split"].values()) - 1) < 1e-3
    sols = [int(k) for k in facts["sols"]["by_sol"]]
    assert sols == sorted(sols) and sum(facts["sols"]["by_sol"].values()) == len(rows)
    cover = facts["view_coverage"]
    assert 0 < cover["median"] <= 1 and set(cover["by_instrument"]) == {
        r["instrument"] for r in rows
    }
