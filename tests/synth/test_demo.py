"""The demo preset: its traverse and configs/demo.yaml's splits, its pointing, its wide camera,
and the render window (generated data only)."""

from __future__ import annotations

import itertools
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from affine import Affine
from PIL import Image
from rasterio.crs import CRS as RioCRS

from mars_pairs.pds import read_observation
from mars_pairs.pipeline.config import load_config
from mars_pairs.pipeline.splitting import split_rule
from mars_pairs.synth import generate_mission
from mars_pairs.synth.cameras import (
    NAVCAM_HFOV_DEG,
    ZOOM_STOPS_MM,
    mission_cameras,
    wide_camera,
    zoom_focal_mm,
    zoom_hfov_deg,
)
from mars_pairs.synth.mission import (
    SIZES,
    SPECS,
    _survey_stop,
    _window,
    mission_traverse,
)
from mars_pairs.synth.render import DemGrid, block_ranges
from mars_pairs.synth.traverse import directed_path

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

DEMO_YAML = Path(__file__).resolve().parents[2] / "configs" / "demo.yaml"


def test_demo_config_splits_hold_most_samples_in_train() -> None:
    """configs/demo.yaml's held-out boxes against the traverse the demo generates: every
    split non-empty, >= 60 % of the samples in train, >= 200 samples."""
    cfg = load_config(DEMO_YAML)
    syn = cfg.inputs.synthetic
    assert syn is not None and syn.size == "demo" and cfg.splits.guard == "footprint"
    trav = mission_traverse(syn.seed, syn.mission, syn.size, syn.stops)
    n = SIZES[syn.size].dem_cells
    left, top = SPECS[syn.mission].centre_xy[0] - n / 2, SPECS[syn.mission].centre_xy[1] + n / 2
    rule = split_rule(
        cfg, RioCRS.from_user_input(SPECS[syn.mission].crs).to_wkt(),
        (left, top - n, left + n, top), (1.0, 1.0),
    )  # fmt: skip
    per_stop = Counter(rule.assign(s.x, s.y) for s in trav.stops)
    samples = {k: v * syn.images_per_stop for k, v in per_stop.items()}
    total = sum(samples.values())
    assert total >= 200
    assert samples["train"] >= 0.6 * total, samples
    assert per_stop["val"] >= 8 and per_stop["test"] >= 8, per_stop
    # the traverse is multi-kilometre and heads across the DEM
    xy = np.array([(s.x, s.y) for s in trav.stops])
    length = np.hypot(*np.diff(xy, axis=0).T).sum()
    assert length > 3000 and np.hypot(*(xy[-1] - xy[0])) > 0.7 * length


def test_directed_path_heads_across_inside_bounds() -> None:
    bounds = (100.0, 200.0, 2100.0, 2200.0)
    for seed in range(4):
        path = directed_path(np.random.default_rng(seed), bounds, 2500.0)
        assert path.shape == (2501, 2)
        assert (path[:, 0] >= 100).all() and (path[:, 0] <= 2100).all()
        assert (path[:, 1] >= 200).all() and (path[:, 1] <= 2200).all()
        steps = np.hypot(*np.diff(path, axis=0).T)
        assert np.allclose(steps[steps > 0.999], 1.0)
        assert np.hypot(*(path[-1] - path[0])) > 0.7 * 2500  # makes good most of its length
        assert (path[-1] - path[0] > 0).all()  # south-west -> north-east


def test_survey_pointing_is_mission_like() -> None:
    """Wide frame first (45 deg, looking down -25..-5), mast frames mostly near the horizon
    (-15..+5), Mastcam-Z zoom stops, some looks down, panoramas stepping in azimuth."""
    rng = np.random.default_rng(1)
    cams, wide = mission_cameras("m2020", "demo"), wide_camera("m2020", "demo")
    assert wide is not None and wide.instrument == "NAVCAM_LEFT"
    mast_el, steps, index = [], [], 0
    for _ in range(300):
        point = _survey_stop(rng, 30.0, cams, wide)
        shots = []
        for j in range(4):
            shots.append(point(j, index))
            index += 1
        cam0, az0, el0, hfov0 = shots[0]
        assert cam0 is wide and hfov0 == NAVCAM_HFOV_DEG and -25 <= el0 <= -5
        assert abs((az0 - 30.0 + 180) % 360 - 180) <= 90
        for cam, az, el, hfov in shots[1:]:
            assert cam.instrument in ("MCZ_LEFT", "MCZ_RIGHT") and 0 <= az < 360
            assert zoom_focal_mm(hfov) in ZOOM_STOPS_MM
            mast_el.append(el)
        d_az = [(b[1] - a[1]) % 360 for a, b in itertools.pairwise(shots[1:])]
        steps.append(all(abs(d - 0.85 * shots[1][3]) < 1e-9 for d in d_az))
    mast_el = np.array(mast_el)
    near_horizon = np.mean((mast_el >= -15) & (mast_el <= 5))
    assert near_horizon > 0.75 and np.mean(mast_el <= -20) > 0.08 and mast_el.max() <= 5
    assert 0.3 < np.mean(steps) < 0.6  # panorama stops: ~45 %
    # the small/default presets have no wide camera
    assert wide_camera("m2020", "small") is None and wide_camera("msl", "demo") is None
    assert math.isclose(zoom_hfov_deg(110), 6.2, abs_tol=0.01)


def test_window_is_the_whole_dem_cut_on_block_edges() -> None:
    """A render window's z ranges equal block_ranges of the cut DEM (NaN nodata included)."""
    rng = np.random.default_rng(2)
    z = rng.random((700, 650))
    z[:40, :50] = np.nan
    grid = DemGrid(z, Affine(1.0, 0.0, 1000.0, 0.0, -1.0, 9000.0))
    blocks = block_ranges(z)
    ortho = np.zeros((1400, 1300), np.uint8)
    for cx, cy, half in ((1300, 8600, 120), (1010, 8990, 200), (1640, 8310, 90), (1300, 8600, 5e3)):
        centre = np.array([cx, cy, 0.0])
        sub, sub_blocks, sub_ortho, _ = _window(grid, blocks, ortho, 2, centre, half)
        for a, b in zip(sub_blocks, block_ranges(sub.z), strict=True):
            np.testing.assert_array_equal(a, b)
        assert sub_ortho.shape == (2 * sub.z.shape[0], 2 * sub.z.shape[1])
        col, row = ~sub.transform * (cx, cy)
        assert 0 <= col < sub.z.shape[1] and 0 <= row < sub.z.shape[0]
        assert (sub.z.shape[0] - 1) % 16 == 0 or sub.transform.f - sub.z.shape[0] == 9000 - 700


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo") / "m"
    generate_mission(out, seed=4, mission="m2020", stops=2, images_per_stop=3, size="demo")
    return out


def test_demo_mission_labels_read_back_with_the_wide_camera(demo_run: Path) -> None:
    truth = pq.read_table(demo_run / "truth.parquet").to_pylist()
    per_stop = [sorted(t["instrument"] for t in truth if t["stop"] == k) for k in (0, 1)]
    assert per_stop == [["MCZ_LEFT", "MCZ_RIGHT", "NAVCAM_LEFT"]] * 2
    assert truth[0]["instrument"] == truth[3]["instrument"] == "NAVCAM_LEFT"
    with rasterio.open(demo_run / "orbital" / "ortho.tif") as src:
        assert src.res == (0.5, 0.5) and src.width == 6144
    for t in truth:
        obs = read_observation(demo_run / t["label_path"])
        assert obs.instrument == t["instrument"] and obs.product_id == Path(t["label_path"]).stem
        image = Image.open(demo_run / t["image_path"])
        assert image.size == (obs.width, obs.height)
        if t["instrument"] == "NAVCAM_LEFT":
            assert obs.product_id.startswith("NLF_") and "NCAM" in obs.product_id
            assert (obs.width, obs.height) == (384, 384)
            assert abs(obs.hfov_deg - 45.0) < 1.0
        else:
            assert (obs.width, obs.height) == (384, 280)
        np.testing.assert_allclose(obs.camera.c, t["camera_c"], atol=1e-9)
        pixels = np.asarray(image)
        assert pixels.std() > 5  # terrain, not a blank frame
