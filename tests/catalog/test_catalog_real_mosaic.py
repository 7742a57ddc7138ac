"""The study's check on real labels: the seven Mastcam-left frames of one sol-2663 mosaic
(``../shared/pds-samples/msl/2663ML01395500[2-8]1002*``) catalogued together come out as pairs
of one position, every frame paired with the frames beside it in the mosaic, and in each
frame's overlaps (ranked by IoU) its neighbours come before every other frame.

Where they stand is made up. No PLACES table here has the mosaic's position (site 78, drive
2858): ``../shared/real-gale/rover_positions.csv`` and ``Waypoints.csv`` end at sol 1782 (site
65) and ``real-archive/msl_localized_interp_head.csv`` holds site 1 only; and the real Gale DEM
crop covers sites 46-49 (latitude -4.6640 to -4.6697), north of where Curiosity was by sol 1782
(-4.7217) and later. So the frames are placed on a generated Curiosity mission's terrain: the
SITE 78 origin is put at the mission's site origin (made up), and each frame's rover position
and attitude are the label's own (its telemetry offset from the site origin and its rover
quaternion, the DESIGN fallback when PLACES has no ROVER row). The mosaic's geometry (its
cameras and pointing) is the real one; the ground under it is synthetic."""

from __future__ import annotations

import csv
import itertools
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import yaml

from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.pipeline.config import load_config
from mars_pairs.store.catalog import Catalog
from support.missions import MissionCache

#: a generated mission and a catalogue (~10 s)
pytestmark = pytest.mark.slow

MOSAIC = "msl/2663ML01395500[2-8]1002*.LBL"


@pytest.fixture(scope="module")
def mosaic(
    samples_dir: Path, missions: MissionCache, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """The catalogue folder of the seven frames on a generated Curiosity mission's terrain."""
    labels = sorted(samples_dir.glob(MOSAIC))
    if len(labels) != 7:
        pytest.skip(f"the sol-2663 mosaic's 7 labels not found in {samples_dir / 'msl'}")
    terrain = missions(seed=7, stops=1, images_per_stop=1, mission="msl")
    root = tmp_path_factory.mktemp("mosaic")
    with open(terrain / "places" / "localized_interp.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    site = {**next(r for r in rows if r["frame"] == "SITE"), "site": "78", "sol": "2663"}
    with open(root / "places.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerow(site)  # the made-up SITE 78 origin, and no ROVER row
    config = {
        "inputs": {
            "labels": str(samples_dir / MOSAIC),
            "places": str(root / "places.csv"),
            "dem": str(terrain / "orbital" / "dem.tif"),
            "ortho": str(terrain / "orbital" / "ortho.tif"),
        },
        "geometry": {"radius": 150.0},
        "output": {"dir": str(root / "unused")},
    }
    (root / "config.yaml").write_text(yaml.safe_dump(config))
    summary = run_catalog(load_config(root / "config.yaml"), root / "cat", progress=False)
    assert summary.failures == 0, summary.failures_by_reason
    assert summary.images == 7
    return root / "cat"


def _in_mosaic_order(folder: Path) -> list[dict[str, Any]]:
    """The catalogue's rows by the label's azimuth (the order of the frames in the mosaic)."""
    rows = pq.read_table(folder / "catalog.parquet").to_pylist()
    return sorted(rows, key=lambda r: float(r["label_azimuth_deg"]))


def test_frames_are_placed_by_their_labels(mosaic: Path) -> None:
    rows = _in_mosaic_order(mosaic)
    assert {r["localization"] for r in rows} == {"label"}
    assert len({(r["site"], r["drive"]) for r in rows}) == 1
    for r in rows:
        # the centre ray's azimuth against the label's own pointing (the subframe's centre is
        # ~0.5 degree off the camera axis), and ground in view
        assert abs(float(r["azimuth_deg"]) - float(r["label_azimuth_deg"])) < 1.0
        assert float(r["visible_area_m2"]) > 0.0


def test_neighbours_pair_and_come_before_non_neighbours(mosaic: Path) -> None:
    keys = [str(r["key"]) for r in _in_mosaic_order(mosaic)]
    pairs = pq.read_table(mosaic / "pairs.parquet").to_pylist()
    iou = {frozenset((p["key_a"], p["key_b"])): float(p["iou"]) for p in pairs}
    assert all(p["same_position"] for p in pairs)
    for a, b in itertools.pairwise(keys):
        assert iou.get(frozenset((a, b)), 0.0) > 0.0, (a, b)
    catalog = Catalog.open(mosaic)
    for i, key in enumerate(keys):
        neighbours = {keys[j] for j in (i - 1, i + 1) if 0 <= j < len(keys)}
        ranked = catalog.overlaps(key)["key"].to_pylist()
        assert set(ranked[: len(neighbours)]) == neighbours, (key, ranked)
