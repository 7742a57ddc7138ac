"""First contact with the real archive: fetch, then build, from the replica of its real files.

The replica (``replica_archive.py``) serves the real labels, inventory rows and PLACES tables of
``../shared`` in their archive paths on a loopback server, with GDAL-written VICAR and PDS4
orbital maps in the PLACES bundles' paths. A user's two commands run as subprocesses, as a
user runs them: ``mars-pairs fetch all --config C`` then ``mars-pairs build --config C``.
Every real label is fetched, located and built; what the filters leave out is named in the
dry run and in ``fetch_skipped.parquet``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

from mars_pairs.geometry.places import Places
from mars_pairs.pds import read_observation
from support import replica_archive as replica
from support.fetch_server import ArchiveServer

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> replica.Replica:
    why = replica.available()
    if why is not None:
        pytest.skip(f"replica archive needs ../shared: {why}")
    return replica.shared_replica(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def server(archive):
    with ArchiveServer(archive.root, slow_s=1.0) as srv:
        yield srv


def _config(work: Path, url: str, mission: str) -> Path:
    """A user's config for one mission of the replica: fetch section + inputs in the cache."""
    if mission == "msl":
        root = f"{url}/msl"
        products = {"mission": "msl", "archive": root, "sols": [1429, 1429],
                    "product_types": ["DRCL"]}  # fmt: skip
        places = replica.MSL_PLACES_CURRENT
        maps = f"{root}/{replica.MSL_MAPS}/msl_orbital_"
        labels = "cache/MSLMST_*/DATA/RDR/SURFACE/**/*.LBL"
    else:
        root = f"{url}/mars2020"
        products = {"mission": "m2020", "archive": root, "bundle": replica.M2020_BUNDLE,
                    "collection": replica.M2020_COLLECTION, "sols": [52, 79],
                    "product_types": ["RAD"]}  # fmt: skip
        places = replica.M2020_PLACES
        maps = f"{root}/{replica.M2020_MAPS}/m20_orbital_"
        labels = f"cache/{replica.M2020_BUNDLE}/data/sol/**/*.xml"
    doc = {
        "inputs": {"labels": labels, "places": f"cache/{places}",
                   "dem": "cache/orbital/dem.vrt", "ortho": "cache/orbital/ortho.vrt"},
        "geometry": {"radius": 200, "ray_stride": 8},
        "chips": {"size_m": 128, "size_px": 256},
        "output": {"dir": "dataset", "shard_size": 8},
        "splits": {"style": "same-area", "block_m": 1000, "seed": 0, "guard": "chip",
                   "ratios": {"train": 0.8, "val": 0.1, "test": 0.1}},
        "fetch": {"cache": "cache", "retries": 1, "backoff_s": 0.01, "timeout_s": 20,
                  "workers": 2, "products": products,
                  "places": {"archive": root, "path": places},
                  "orbital": {"dem": f"{maps}dem.img", "ortho": f"{maps}map.img"}},
    }  # fmt: skip
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"{mission}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "mars_pairs.cli", *args],
        capture_output=True, text=True, env=env, timeout=300, check=False,
    )  # fmt: skip


def _fetch_and_build(work: Path, url: str, mission: str) -> dict[str, str]:
    config = str(_config(work, url, mission))
    out = {}
    for name, args in (
        ("dry", ("fetch", "all", "--config", config, "--dry-run", "--quiet")),
        ("fetch", ("fetch", "all", "--config", config, "--quiet")),
        ("build", ("build", "--config", config, "--workers", "1")),
    ):
        done = _cli(*args)
        assert done.returncode == 0, f"{name}: {done.stdout[-2000:]}\n{done.stderr[-2000:]}"
        out[name] = done.stdout
    return out


def _positions(csv_path: Path, keys: set[tuple[int, int, int]]) -> dict[tuple, tuple]:
    """(easting, northing) of PLACES ROVER rows by (site, drive, pose), read with the csv
    module (not the package)."""
    import csv

    found = {}
    with open(csv_path, newline="") as fh:
        for row in csv.DictReader(fh):
            key = (int(row["site"]), int(row["drive"]), int(row["pose"]))
            if row["frame"] == "ROVER" and key in keys:
                found[key] = (float(row["easting"]), float(row["northing"]))
    return found


def test_curiosity_fetch_and_build(archive, server, tmp_path) -> None:
    out = _fetch_and_build(tmp_path, server.url, "msl")
    # the dry run names what it leaves out: the sol-1429 product listed again in MSLMST_0015
    assert "4 products" in out["dry"] and "same product in a newer volume" in out["dry"]
    assert "accepted" in out["dry"] and "REJECTED" not in out["dry"]
    cache = tmp_path / "cache"
    skipped = pq.read_table(cache / "fetch_skipped.parquet").to_pylist()
    assert [s["reason"] for s in skipped] == ["same product in a newer volume"]
    assert pq.read_table(cache / "fetch_failures.parquet").num_rows == 0
    # every real sol-1429 label fetched from the volumes the sol-range table names, built
    rows = pq.read_table(tmp_path / "dataset" / "manifest.parquet").to_pylist()
    assert pq.read_table(tmp_path / "dataset" / "failures.parquet").num_rows == 0
    want = sorted(Path(p).stem for p in archive.msl_labels)
    assert sorted(r["product_id"] for r in rows) == want
    # located at the PLACES row of the labels' (site, drive, pose): 56, 1632, pose 8
    # (the table's pose-0 row for it lies 0.5 m away, turned 3 degrees: a wrong choice shows)
    (x, y) = _positions(cache / replica.MSL_PLACES_CURRENT, {(56, 1632, 8)})[(56, 1632, 8)]
    for r in rows:
        assert (r["site"], r["drive"], r["pose"]) == (56, 1632, 8)
        assert (r["places_match"], r["places_pose"]) == ("site-drive-pose", 8)
        assert abs(r["easting"] - x) < 0.01 and abs(r["northing"] - y) < 0.01
        assert r["ortho_coverage"] == 1.0 and r["dem_coverage"] == 1.0
        # Curiosity's label pointing is the camera axis: the centre ray is within 0.1 deg
        assert abs((r["azimuth_deg"] - r["label_azimuth_deg"] + 180) % 360 - 180) < 0.1
        assert abs(r["elevation_deg"] - r["label_elevation_deg"]) < 0.1


def test_curiosity_pds3_era_places_from_the_archive(archive, server, tmp_path) -> None:
    """The 22-column upper-case table, fetched, places the labels as the current one does."""
    from mars_pairs.fetch.config import RemoteSpec, load_fetch_config
    from mars_pairs.fetch.run import fetch_remote

    cfg = load_fetch_config(_config(tmp_path, server.url, "msl"))
    old = fetch_remote(cfg, RemoteSpec(f"{server.url}/msl", replica.MSL_PLACES_PDS3),
                       kind="places", mutable=True)  # fmt: skip
    new = fetch_remote(cfg, RemoteSpec(f"{server.url}/msl", replica.MSL_PLACES_CURRENT),
                       kind="places", mutable=True)  # fmt: skip
    assert old.read_text().splitlines()[0].startswith("FRAME,SITE,DRIVE,POSE")
    a, b = Places.from_csv(old), Places.from_csv(new)
    for rel in archive.msl_labels:
        obs = read_observation(archive.msl / rel)
        pa, pb = a.locate(obs), b.locate(obs)
        assert abs(pa.easting - pb.easting) < 0.01 and abs(pa.northing - pb.northing) < 0.01
        dot = abs(float(np.dot(pa.quaternion, pb.quaternion)))
        assert np.degrees(2 * np.arccos(min(1.0, dot))) < 0.5


def test_perseverance_fetch_and_build(archive, server, tmp_path) -> None:
    out = _fetch_and_build(tmp_path, server.url, "m2020")
    # the real inventory rows of other sols are named, not dropped
    assert "2 products" in out["dry"] and "skipped 4: sol outside [52, 79]" in out["dry"]
    cache = tmp_path / "cache"
    assert pq.read_table(cache / "fetch_failures.parquet").num_rows == 0
    # file names from LID + VID: ...110085j::1.0 -> J01, ::3.0 -> J03, fetched whole
    for rel in archive.m2020_labels:
        got = cache / rel
        assert got.read_bytes() == (archive.m2020 / rel).read_bytes()
        assert (
            got.with_suffix(".IMG").stat().st_size
            == (archive.m2020 / rel).with_suffix(".IMG").stat().st_size
        )
    rows = pq.read_table(tmp_path / "dataset" / "manifest.parquet").to_pylist()
    assert pq.read_table(tmp_path / "dataset" / "failures.parquet").num_rows == 0
    assert sorted(r["product_id"] for r in rows) == sorted(
        Path(p).stem for p in archive.m2020_labels
    )
    places = _positions(cache / replica.M2020_PLACES, {(3, 1950, -1), (3, 2430, -1)})
    for r in rows:
        x, y = places[(r["site"], r["drive"], -1)]
        assert abs(r["easting"] - x) < 0.01 and abs(r["northing"] - y) < 0.01
        # best_interp.csv gives these (site, drive) with pose -1: a match for every pose
        assert r["places_match"] == "site-drive" and r["places_pose"] == -1
        # full frames: the label's pointing is the image centre's ray
        assert abs((r["azimuth_deg"] - r["label_azimuth_deg"] + 180) % 360 - 180) < 0.1
        assert abs(r["elevation_deg"] - r["label_elevation_deg"]) < 0.1


def test_a_cut_image_in_the_cache_is_fetched_again(archive, server, tmp_path) -> None:
    """An .IMG shorter than its label's arrays (a cut download kept by an older release) is
    not taken as cached: the next fetch replaces it, whole."""
    config = str(_config(tmp_path, server.url, "m2020"))
    assert _cli("fetch", "products", "--config", config, "--quiet").returncode == 0
    image = (tmp_path / "cache" / archive.m2020_labels[1]).with_suffix(".IMG")
    whole = image.read_bytes()
    image.write_bytes(whole[: len(whole) // 2])
    again = _cli("fetch", "products", "--config", config, "--quiet")
    assert again.returncode == 0, again.stderr
    assert "1 files downloaded" in again.stdout
    assert image.read_bytes() == whole
