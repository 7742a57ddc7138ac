"""Dense range and depth on the real Gale DEM at the sol-1051 pose (the views of
``test_build_real_gale``), against the independent ray march of ``independent_truth``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from support import independent_truth as truth
from support.members import rows_by_key, sample_members, tiff_array
from support.real_gale import GALE, make_gale_labels

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

RADIUS_M = 90.0
STRIDE = 16


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not (GALE / "dem.tif").is_file():
        pytest.skip(f"real Gale terrain not found at {GALE} (../shared beside the checkout)")
    root = tmp_path_factory.mktemp("dense-gale")
    (root / "labels").mkdir()
    make_gale_labels(GALE, root / "labels")
    doc = {
        "inputs": {"labels": "labels/*.LBL", "places": str(GALE / "rover_positions.csv"),
                   "dem": str(GALE / "dem.tif"), "ortho": str(GALE / "ortho.tif")},
        "geometry": {"radius": RADIUS_M, "ray_stride": 8},
        "chips": {"size_m": 120, "size_px": 240},
        "output": {"dir": "dataset", "members": ["range", "depth"], "dense_stride": STRIDE},
    }  # fmt: skip
    summary = run_build(parse_config(doc, root), progress=False)
    assert summary.samples == 4 and summary.failures == 0, summary.failures_by_reason
    return root / "dataset"


def test_range_and_depth_on_real_gale(built: Path) -> None:
    rows = rows_by_key(built)
    labels = built / json.loads((built / "dataset.json").read_text())["labels_root"]
    arrays: dict[str, dict[str, np.ndarray]] = {}
    for key, members in sample_members(built).items():
        for name in ("range.tif", "depth.tif"):
            arrays.setdefault(key, {})[name] = tiff_array(members[name])
    er, ed = [], []
    for key, a in arrays.items():
        lab = truth.read_label_fields(labels / rows[key]["label_path"])  # relative to the root
        places, dem = GALE / "rover_positions.csv", GALE / "dem.tif"
        cam = truth.place_camera(lab, places, dem)
        px = truth.pixel_grid(lab.width, lab.height, STRIDE)
        hits = truth.ground_hits(lab, places, dem, radius_m=RADIUS_M, step_m=0.25, pixels=px)
        ok = np.isfinite(hits[:, 0])
        rel = np.full((len(hits), 3), np.nan)
        rel[ok] = cam.enu.from_map(hits[ok]) - cam.centre_enu
        t_range = np.linalg.norm(rel, axis=1)
        t_depth = rel @ (cam.rot @ (lab.a / np.linalg.norm(lab.a)))
        r = a["range.tif"].ravel().astype(np.float64)
        d = a["depth.tif"].ravel().astype(np.float64)
        both = np.isfinite(r) & np.isfinite(t_range) & (t_range < 0.9 * RADIUS_M)
        assert both.sum() >= 0.9 * (np.isfinite(t_range) & (t_range < 0.9 * RADIUS_M)).sum() - 5
        er.append(np.abs(r[both] - t_range[both]))
        ed.append(np.abs(d[both] - t_depth[both]))
    e_r, e_d = np.concatenate(er), np.concatenate(ed)
    assert len(e_r) > 300
    assert np.median(e_r) <= 0.05, np.median(e_r)
    assert np.median(e_d) <= 0.05, np.median(e_d)
