"""The orbital window planner: clusters, DEM vs ortho reach, the limit key, shipped configs."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from mars_pairs.errors import FetchError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.orbital import rover_positions
from mars_pairs.fetch.windows import (
    MAX_CELLS_KEY,
    RasterGrid,
    dem_reach_m,
    ortho_reach_m,
    plan_windows,
    position_boxes,
)
from mars_pairs.geometry.places import M2020_PLACES_CRS, MSL_PLACES_CRS

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
CONFIGS = ROOT / "configs"
EQC0 = "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"


def _grid(crs, x0, y0, res, width, height):
    return RasterGrid(crs, Affine(res, 0, x0, 0, -res, y0), width, height)


# A 1 m DEM and a 25 cm ortho over Gale (the Curiosity PLACES CRS), 40 x 40 km.
GALE_DEM = _grid(MSL_PLACES_CRS, 8_130_000.0, -260_000.0, 1.0, 40_000, 40_000)
GALE_ORTHO = _grid(MSL_PLACES_CRS, 8_130_000.0, -260_000.0, 0.25, 160_000, 160_000)
X0, Y0 = 8_140_000.0, -280_000.0


def _covers(plan, boxes, grid):
    """Every position's box (clipped to the raster) lies inside some window (pixels)."""
    boxes = np.clip(boxes, 0, [grid.width, grid.height, grid.width, grid.height])
    for c0, r0, c1, r1 in boxes:
        assert any(
            w.col_off <= c0
            and w.row_off <= r0
            and w.col_off + w.width >= c1
            and w.row_off + w.height >= r1
            for w in plan.windows
        ), (c0, r0, c1, r1)


def test_positions_far_apart_get_one_window_each_close_ones_share():
    x = np.array([X0, X0 + 30.0, X0 + 12_000.0, X0 + 12_020.0])
    y = np.array([Y0, Y0 + 10.0, Y0 - 9_000.0, Y0 - 9_000.0])
    reach = ortho_reach_m(512, 10)
    plan = plan_windows(x, y, MSL_PLACES_CRS, GALE_ORTHO, reach, kind="ortho", source="o.tif")
    assert len(plan.windows) == 2 and [w.positions for w in plan.windows] == [2, 2]
    assert plan.accepted and plan.off_raster == ()
    boxes = np.floor(position_boxes(x, y, MSL_PLACES_CRS, GALE_ORTHO, reach))
    _covers(plan, boxes, GALE_ORTHO)
    # each window is about the chip's reach around its pair, not the 12 x 9 km bounding box
    for w in plan.windows:
        assert w.cells < 4000 * 4000


def test_a_long_winding_traverse_is_a_chain_of_windows_not_one_bbox():
    """20 km diagonal drive, a position every 25 m: windows along it, far below the bbox."""
    s = np.arange(0, 20_000, 25.0)
    x = X0 + s / math.sqrt(2) + 300 * np.sin(s / 900)
    y = Y0 - s / math.sqrt(2)
    reach = dem_reach_m(1000, 512, 10)
    plan = plan_windows(x, y, MSL_PLACES_CRS, GALE_DEM, reach, kind="dem", source="d.tif")
    boxes = np.floor(position_boxes(x, y, MSL_PLACES_CRS, GALE_DEM, reach))
    _covers(plan, boxes, GALE_DEM)
    bbox = (boxes[:, 2].max() - boxes[:, 0].min()) * (boxes[:, 3].max() - boxes[:, 1].min())
    total = sum(w.cells for w in plan.windows)
    print(f"{len(plan.windows)} windows, {total} cells vs bbox {bbox:.0f}")
    assert len(plan.windows) > 2
    assert total < 0.6 * bbox
    assert sum(w.positions for w in plan.windows) == len(x)


def test_a_straight_drive_is_one_window():
    x = X0 + np.arange(0, 3000, 20.0)
    y = np.full_like(x, Y0)
    plan = plan_windows(x, y, MSL_PLACES_CRS, GALE_DEM, 500.0, kind="dem", source="d.tif")
    assert len(plan.windows) == 1 and plan.windows[0].positions == len(x)


def test_dem_reaches_the_view_radius_and_ortho_the_chip():
    """radius 5000 m on a 25 cm ortho was one 44,001 x 44,001 window; the chip needs ~3,000."""
    x, y = np.array([X0]), np.array([Y0])
    dem = plan_windows(
        x, y, MSL_PLACES_CRS, GALE_DEM, dem_reach_m(5000, 512, 10), kind="dem", source="d.tif"
    )
    ortho = plan_windows(
        x, y, MSL_PLACES_CRS, GALE_ORTHO, ortho_reach_m(512, 10), kind="ortho", source="o.tif"
    )
    (d,), (o,) = dem.windows, ortho.windows
    k = 1 / math.cos(math.radians(4.72))  # east scale of eqc lat_ts=0 at Gale
    half_dem = (5010 * k + 3) / 1.0
    assert abs(d.width - 2 * half_dem) <= 2 and d.accepted
    half_ortho = ((512 * math.sqrt(0.5) + 10) * k + 3 * 0.25) / 0.25
    assert abs(o.width - 2 * half_ortho) <= 2 and o.accepted
    assert 2900 < o.width < 3000
    # the DEM's reach on the 25 cm ortho: refused, and the error names the key to change
    wide = plan_windows(
        x, y, MSL_PLACES_CRS, GALE_ORTHO, dem_reach_m(5000, 512, 10), kind="ortho", source="o.tif"
    )
    assert not wide.accepted and not wide.windows[0].accepted
    assert "REJECTED" in wide.windows[0].describe()
    with pytest.raises(FetchError, match=MAX_CELLS_KEY.replace(".", r"\.")) as err:
        wide.check()
    assert "narrow the sols" not in str(err.value)
    raised = plan_windows(
        x,
        y,
        MSL_PLACES_CRS,
        GALE_ORTHO,
        dem_reach_m(5000, 512, 10),
        kind="ortho",
        source="o.tif",
        max_cells=2_000_000_000,
    )
    raised.check()


def test_windows_are_cut_in_the_raster_crs_with_its_scale():
    """Perseverance PLACES (lat_ts=18.4663) positions on a USGS-style eqc lat_ts=0 DEM."""
    x, y = np.array([4_354_494.086]), np.array([1_093_299.695])  # best_interp.csv SITE 1
    usgs = _grid(EQC0, 4_585_000.0, 1_097_000.0, 1.0, 10_000, 10_000)
    (w,) = plan_windows(x, y, M2020_PLACES_CRS, usgs, 1000.0, kind="dem", source="j.tif").windows
    lon, lat = 77.450885729, 18.444627146
    ex = 3_396_190 * math.radians(lon)  # the same point in lat_ts=0 eastings: 5 % further east
    left, bottom, right, top = w.bounds
    assert left < ex < right and abs((left + right) / 2 - ex) < 2
    assert bottom < 1_093_299.695 < top  # northing is the same in both CRS
    assert abs((right - left) / 2 - (1000 / math.cos(math.radians(lat)) + 3)) < 2


def test_positions_off_the_raster_are_counted_and_all_off_is_an_error():
    x = np.array([X0, X0 + 100_000.0])
    y = np.array([Y0, Y0])
    plan = plan_windows(x, y, MSL_PLACES_CRS, GALE_DEM, 200.0, kind="dem", source="d.tif")
    assert plan.off_raster == (1,) and len(plan.windows) == 1
    with pytest.raises(FetchError, match="off the dem raster"):
        plan_windows(x[1:], y[1:], MSL_PLACES_CRS, GALE_DEM, 200.0, kind="dem", source="d.tif")


# -- the shipped configs against real positions and the real maps' grids ----------------------
# Grids of the PLACES maps (stand-ins: no pixel data, only the grid):
# Perseverance: m20_orbital_dem.img 14800 x 5480 at 1 m from x 4340890, y 1097070 (public code
#   reading it; the real-archive README gives the upper left); m20_orbital_map.img at 0.25 m
#   over the same extent (the 4:1 ratio of best_interp.csv's map_pixel/dem_pixel columns).
# Curiosity: msl_orbital_dem.img x 8141036.5..8147777.5, y -282743.1..-271512.1 (README), 1 m;
#   msl_orbital_map.img 0.25 m (the 4:1 ratio of localized_interp.csv's pixel columns).
REAL_GRIDS = {
    "m2020_jezero.yaml": {
        "dem": _grid(M2020_PLACES_CRS, 4_340_890.0, 1_097_070.0, 1.0, 14_800, 5_480),
        "ortho": _grid(M2020_PLACES_CRS, 4_340_890.0, 1_097_070.0, 0.25, 59_200, 21_920),
    },
    "msl_gale.yaml": {
        "dem": _grid(MSL_PLACES_CRS, 8_141_036.5, -271_512.1, 1.0, 6_741, 11_231),
        "ortho": _grid(MSL_PLACES_CRS, 8_141_036.5, -271_512.1, 0.25, 26_964, 44_924),
    },
}
REAL_PLACES = {
    "m2020_jezero.yaml": SHARED / "pds-samples" / "m2020" / "best_interp.csv",
    "msl_gale.yaml": SHARED / "real-gale" / "rover_positions.csv",
}


def test_the_map_pixel_columns_fit_the_stand_in_grids():
    """best_interp.csv's map_pixel/dem_pixel columns: 0.25 m map, 1 m DEM (4:1)."""
    path = REAL_PLACES["m2020_jezero.yaml"]
    if not path.is_file():
        pytest.skip(f"{path} absent (real PLACES table)")
    import pyarrow.csv as pacsv

    t = pacsv.read_csv(path).to_pydict()
    keep = [i for i, v in enumerate(t["map_pixel_sample"]) if v > -9000]
    e = np.array([t["easting"][i] for i in keep])
    ms = np.array([t["map_pixel_sample"][i] for i in keep])
    ds = np.array([t["dem_pixel_sample"][i] for i in keep])
    assert abs(np.polyfit(ms, e, 1)[0] - 0.25) < 1e-6
    assert abs(np.polyfit(ds, e, 1)[0] - 1.0) < 1e-6


@pytest.mark.parametrize("name", sorted(REAL_GRIDS))
def test_shipped_configs_plan_windows_the_limits_accept(name):
    places = REAL_PLACES[name]
    if not places.is_file():
        pytest.skip(f"{places} absent (real PLACES positions)")
    cfg = load_fetch_config(CONFIGS / name)
    assert cfg.products is not None and cfg.orbital is not None
    pos = rover_positions(places, sols=cfg.products.filters.sols)
    reach = {
        "dem": dem_reach_m(cfg.radius_m, cfg.chip_size_m, cfg.orbital.margin_m),
        "ortho": ortho_reach_m(cfg.chip_size_m, cfg.orbital.margin_m),
    }
    for kind, grid in REAL_GRIDS[name].items():
        plan = plan_windows(
            pos.x,
            pos.y,
            pos.crs,
            grid,
            reach[kind],
            kind=kind,
            source=getattr(cfg.orbital, kind),
            max_cells=cfg.orbital.max_cells,
        )
        for w in plan.windows:
            print(w.describe())
        assert plan.accepted and plan.off_raster == ()
        plan.check()
        _covers(plan, np.floor(position_boxes(pos.x, pos.y, pos.crs, grid, reach[kind])), grid)


def test_sol_1429_stands_where_sol_1428_ended():
    """No ROVER row has sol 1429: the rover stood at site 56 drive 1632 (sol 1428's row),
    the site/drive of the real sol-1429 Mastcam labels."""
    path = REAL_PLACES["msl_gale.yaml"]
    if not path.is_file():
        pytest.skip(f"{path} absent (real Curiosity positions)")
    pos = rover_positions(path, sols=(1429, 1429))
    assert pos.names == ("site 56 drive 1632 (sol 1428)",)
    assert (pos.x[0], pos.y[0]) == (8141618.407, -277875.774)
    # eqc lat_ts ~0 (infer_places_crs reads 0.0015 deg from this table's 7-digit longitudes:
    # eastings 3e-10 apart, harmless)
    lat_ts = re.search(r"\+lat_ts=([0-9.]+)", pos.crs)
    assert pos.crs.startswith("+proj=eqc") and lat_ts and float(lat_ts.group(1)) < 0.01
    two = rover_positions(path, sols=(1428, 1431))
    assert two.names[0] == "site 56 drive 1326 (sol 1427)" and len(two.names) == 3


def test_upper_case_pds3_era_columns_are_read(tmp_path):
    """The PDS3-era localized_interp.csv has upper-case column names."""
    csv = tmp_path / "localized_interp.csv"
    csv.write_text(
        "FRAME,SITE,DRIVE,NORTHING,EASTING,LONGITUDE,SOL\n"
        "SITE,1,-1,-272039.268,8146811.223,137.441632997,-1\n"
        "ROVER,1,0,-272039.268,8146811.223,137.441632997,0\n"
    )
    pos = rover_positions(csv)
    assert pos.crs == MSL_PLACES_CRS and pos.names == ("site 1 drive 0 (sol 0)",)


def test_the_dem_grid_of_a_real_crop_plans_a_window_of_its_own_pixels():
    """A real Gale DEM crop (../shared/real-gale/dem.tif) as the grid: pixel-aligned window."""
    path = SHARED / "real-gale" / "dem.tif"
    if not path.is_file():
        pytest.skip(f"{path} absent (real Gale DEM crop)")
    with rasterio.open(path) as ds:
        grid = RasterGrid(ds.crs.to_wkt(), ds.transform, ds.width, ds.height)
    x, y = np.array([8142579.427]), np.array([-276693.318])  # sol 1051, inside the crop
    (w,) = plan_windows(x, y, MSL_PLACES_CRS, grid, 50.0, kind="dem", source=str(path)).windows
    assert w.bounds[0] == grid.transform.c + w.col_off
    assert 100 <= w.width <= 112 and 100 <= w.height <= 112
