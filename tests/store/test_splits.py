"""Leak-free splits, checked by brute force over generated traverses with shapely.

Every sample gets a chip (a square of side S around its rover, north-up or turned) and a
footprint (a view wedge of range up to R from a camera centre a metre or two off the rover,
its corners a DEM cell further). Every pair of kept samples of different splits is then
tested for intersection, independently of the rule that assigned them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import shapely
from pyproj import CRS

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import parse_config
from mars_pairs.store.leakage import chip_polygons, leak_report
from mars_pairs.store.splits import (
    BUFFER,
    TRAIN,
    SplitRule,
    footprint_reach,
    make_rule,
    map_scale_bound,
)

S = 256.0  # chip side, map units
R = 600.0  # view radius
CELL = math.hypot(1.0, 1.0)  # DEM cell diagonal


def random_walk(seed: int, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Rover positions of a traverse: steps of 5-80 m, heading turning a little each stop,
    with dwell (repeated positions) like a real rover's several images per stop."""
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.normal(0.0, 0.5, n)) + rng.uniform(0, 2 * math.pi)
    step = rng.uniform(5.0, 80.0, n) * (rng.random(n) > 0.3)
    x = 1000.0 * seed + np.cumsum(step * np.cos(heading))
    y = -500.0 * seed + np.cumsum(step * np.sin(heading))
    return x, y


def wedges(x: np.ndarray, y: np.ndarray, seed: int, reach: float) -> np.ndarray:
    """Footprints: wedges of random azimuth/width and range up to ``reach`` from a camera
    centre <= 2 m off the rover, widened by half a DEM cell diagonal (the cell corners)."""
    rng = np.random.default_rng(seed + 1000)
    out = []
    for xi, yi in zip(x, y, strict=True):
        cx, cy = xi + rng.uniform(-1.4, 1.4), yi + rng.uniform(-1.4, 1.4)
        az, half = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(5, 30))
        far = reach * (1.0 if rng.random() < 0.5 else rng.uniform(0.05, 1.0))
        t = np.linspace(az - half, az + half, 9)
        ring = [(cx, cy), *zip(cx + far * np.sin(t), cy + far * np.cos(t), strict=True)]
        out.append(shapely.Polygon(ring).buffer(CELL / 2, quad_segs=2))
    return np.array(out, dtype=object)


def leaks(split: np.ndarray, a: np.ndarray, b: np.ndarray) -> int:
    """Pairs (i, j), i != j, of kept samples of different splits whose a[i] meets b[j]."""
    keep = np.flatnonzero(split != BUFFER)
    hits = shapely.intersects(a[keep][:, None], b[keep][None, :])
    differ = split[keep][:, None] != split[keep][None, :]
    return int(np.count_nonzero(hits & differ))


def traverse_case(seed: int, rule: SplitRule, heading_up: bool) -> dict[str, Any]:
    x, y = random_walk(seed)
    rng = np.random.default_rng(seed + 7)
    rot = rng.uniform(0, 360, len(x)) if heading_up else np.zeros(len(x))
    split = np.array([rule.assign(a, b) for a, b in zip(x, y, strict=True)], dtype=object)
    return {
        "x": x,
        "y": y,
        "rot": rot,
        "split": split,
        "chips": chip_polygons(x, y, S, rot),
        "feet": wedges(x, y, seed, R),
    }


def rule_for(guard: str, style: str, buffer_m: float | None = None, **kw: Any) -> SplitRule:
    cfg = parse_config(
        {
            "inputs": {"labels": "l/*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"},
            "output": {"dir": "out"},
            "splits": {"style": style, "guard": guard, "buffer_m": buffer_m, **kw},
        },
        Path("/tmp"),
    )
    return make_rule(cfg.splits, S, R, 1.0, CELL)


CROSS = {
    "areas": {
        "test": [[-3000, -3000, 800, 800], [1500, 2000, 4000, 5000]],
        "val": [[3500, -3500, 4800, -2000]],
    }
}
CASES = [
    ("chip", "same-area", {"block_m": 1500.0, "seed": 2}),
    ("footprint", "same-area", {"block_m": 4000.0, "seed": 5}),
    ("chip", "cross-area", CROSS),
    ("footprint", "cross-area", CROSS),
]


@pytest.mark.parametrize(("guard", "style", "kw"), CASES)
@pytest.mark.parametrize("heading_up", [False, True])
def test_no_extent_meets_another_splits_on_random_traverses(
    guard: str, style: str, kw: dict[str, Any], heading_up: bool
) -> None:
    rule = rule_for(guard, style, **dict(kw))
    assert rule.guaranteed and rule.buffer_m >= S
    seen: set[str] = set()
    for seed in range(6):
        case = traverse_case(seed, rule, heading_up)
        seen |= set(case["split"])
        chips, feet, split = case["chips"], case["feet"], case["split"]
        assert leaks(split, chips, chips) == 0
        if guard == "footprint":
            assert leaks(split, feet, feet) == 0
            assert leaks(split, chips, feet) == 0
    # the traverses cross every held-out region and keep samples on both sides
    assert seen == {TRAIN, BUFFER, "val", "test"}, seen


@pytest.mark.parametrize(("guard", "style", "kw"), CASES[:3])
def test_without_the_buffer_the_same_traverses_leak(
    guard: str, style: str, kw: dict[str, Any]
) -> None:
    """The check can fail: no buffer (the old block split) lets chips cross splits."""
    rule = rule_for(guard, style, buffer_m=0.0, **dict(kw))
    rule = SplitRule(**{**rule.__dict__, "reach": 0.0})
    total = 0
    for seed in range(6):
        case = traverse_case(seed, rule, False)
        total += leaks(case["split"], case["chips"], case["chips"])
    assert total > 0


def test_leak_report_counts_what_brute_force_counts() -> None:
    for buffer_m in (0.0, None):
        rule = rule_for("chip", "same-area", buffer_m=buffer_m, block_m=1500.0, seed=2)
        if buffer_m == 0.0:
            rule = SplitRule(**{**rule.__dict__, "reach": 0.0})
        case = traverse_case(3, rule, True)
        table = pa.table(
            {
                "split": case["split"].tolist(),
                "easting": case["x"],
                "northing": case["y"],
                "chip_rotation_deg": case["rot"],
                "footprint": [shapely.to_wkb(f) for f in case["feet"]],
            }
        )
        report = leak_report(table, S)
        split, chips, feet = case["split"], case["chips"], case["feet"]
        counts = report["intersections_between_splits"]
        assert counts["chip_chip"] == leaks(split, chips, chips) // 2
        assert counts["footprint_footprint"] == leaks(split, feet, feet) // 2
        assert counts["chip_footprint"] == leaks(split, chips, feet)
        held = (split != TRAIN) & (split != BUFFER)
        train = split == TRAIN
        d = np.hypot(
            case["x"][held][:, None] - case["x"][train][None, :],
            case["y"][held][:, None] - case["y"][train][None, :],
        )
        assert report["min_rover_distance_held_out_to_train_m"] == pytest.approx(d.min(), abs=1e-3)
        if buffer_m is None:
            assert counts["chip_chip"] == 0
            assert d.min() > rule.reach + rule.buffer_m


def test_chip_polygons_match_the_chip_grid() -> None:
    from mars_pairs.raster.chips import ChipGrid

    for rot in (0.0, 30.0, 200.0):
        grid = ChipGrid.around(100.0, -50.0, S, 64, "EPSG:32633", rotation_deg=rot)
        expected = shapely.Polygon(grid.corners())
        got = chip_polygons(np.array([100.0]), np.array([-50.0]), S, np.array([rot]))[0]
        assert got.symmetric_difference(expected).area < 1e-6


# -- the rule itself ------------------------------------------------------------------------------
def test_buffer_is_exactly_the_zone_around_other_held_out_blocks() -> None:
    """Against shapely: a sample is buffer iff its rover lies within reach + buffer of a
    held-out block (the block hash's) of a split other than its own."""
    rule = rule_for("chip", "same-area", block_m=500.0, seed=4)
    zone, b = rule.reach + rule.buffer_m, rule.block_m
    rng = np.random.default_rng(9)
    kinds = set()
    for x, y in rng.uniform(-3000, 3000, (400, 2)):
        own, rover = rule.home(x, y), shapely.Point(x, y)
        gap = math.inf
        for bx in range(math.floor(x / b) - 3, math.floor(x / b) + 4):
            for by in range(math.floor(y / b) - 3, math.floor(y / b) + 4):
                if rule.home(bx * b + b / 2, by * b + b / 2) not in (own, TRAIN):
                    block = shapely.box(bx * b, by * b, bx * b + b, by * b + b)
                    gap = min(gap, block.distance(rover))
        got = rule.assign(x, y)
        assert got == (BUFFER if gap <= zone else own)
        kinds.add((own, got))
    assert {("train", "buffer"), ("train", "train"), ("val", "val"), ("test", "test")} <= kinds


def test_a_split_depends_on_the_position_alone() -> None:
    rule = rule_for("footprint", "same-area", block_m=3000.0, seed=1)
    x, y = random_walk(2)
    whole = [rule.assign(a, b) for a, b in zip(x, y, strict=True)]
    order = np.random.default_rng(0).permutation(len(x))[:50]
    fresh = rule_for("footprint", "same-area", block_m=3000.0, seed=1)
    assert [fresh.assign(x[i], y[i]) for i in order] == [whole[i] for i in order]
    other = rule_for("footprint", "same-area", block_m=3000.0, seed=2)
    assert [other.assign(a, b) for a, b in zip(x, y, strict=True)] != whole


def test_cross_area_holds_out_whole_areas() -> None:
    rule = rule_for("chip", "cross-area", **CROSS)
    assert rule.assign(0.0, 0.0) == "test" and rule.assign(2000.0, 3000.0) == "test"
    assert rule.assign(4000.0, -3000.0) == "val"
    assert rule.assign(-40000.0, 40000.0) == TRAIN
    zone = rule.reach + rule.buffer_m
    assert rule.assign(-3000.0 - zone + 1.0, 0.0) == BUFFER  # train, just inside the zone
    assert rule.assign(-3000.0 - zone - 1.0, 0.0) == TRAIN
    assert rule.assign(-2999.0, 0.0) == "test"  # held out: stays, the buffer is outside


def test_reach_and_default_buffer_follow_the_guard() -> None:
    chip = rule_for("chip", "same-area")
    assert chip.reach == pytest.approx(S / math.sqrt(2)) and chip.buffer_m == S
    foot = rule_for("footprint", "same-area")
    assert foot.reach == pytest.approx(R + CELL + 3.0) and foot.buffer_m >= foot.reach
    assert not rule_for("footprint", "same-area", buffer_m=300.0).guaranteed
    with pytest.raises(ConfigError, match=r"splits\.block_m"):
        rule_for("footprint", "same-area", block_m=2.0)  # 1209 m zones over 2 m blocks


def test_map_scale_bound_is_the_projections_own_scale() -> None:
    """eqc with lat_ts = 0 stretches east-west by 1 / cos(lat): the reach grows with it."""
    mars = "+proj=eqc +lat_ts=0 +R=3396190 +units=m +no_defs"
    lat = 18.4
    y = math.radians(lat) * 3396190
    x = math.radians(77.4) * 3396190
    scale = map_scale_bound(CRS.from_proj4(mars).to_wkt(), (x - 500, y - 500, x + 500, y + 500))
    assert scale == pytest.approx(1.0 / math.cos(math.radians(lat + 500 / 3396190 * 57.3)), 2e-3)
    assert footprint_reach(1000.0, scale, CELL) > 1050.0
    assert footprint_reach(1000.0, 0.5, CELL) == pytest.approx(1000.0 + CELL + 3.0)


# -- config ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("splits", "key"),
    [
        ({"style": "nearby"}, "splits.style"),
        ({"style": "cross-area"}, "splits.areas"),
        (
            {"style": "cross-area", "areas": {"test": [[0, 0, 1, 1]]}, "block_m": 5},
            "splits.block_m",
        ),
        ({"areas": {"test": [[0, 0, 1, 1]]}}, "splits.areas"),
        ({"style": "cross-area", "areas": {"test": [[0, 0, -1, 1]]}}, "splits.areas.test"),
        ({"style": "cross-area", "areas": {"train": [[0, 0, 1, 1]]}}, "splits.areas.train"),
        (
            {"style": "cross-area", "areas": {"test": [[0, 0, 2, 2]], "val": [[1, 1, 3, 3]]}},
            "overlaps",
        ),
        ({"ratios": {"train": 0.5, "buffer": 0.5}}, "reserved"),
        ({"buffer_m": -1}, "splits.buffer_m"),
        ({"guard": "all"}, "splits.guard"),
        ({"buffer_policy": "keep"}, "splits.buffer_policy"),
    ],
)
def test_bad_split_configs_name_the_key(splits: dict[str, Any], key: str) -> None:
    doc = {
        "inputs": {"labels": "l/*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"},
        "output": {"dir": "out"},
        "splits": splits,
    }
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        parse_config(doc, Path("/tmp"))
