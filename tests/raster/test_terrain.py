"""Terrain: windowed DEM/ortho reads, nodata, CRS handling and errors on generated GeoTIFFs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from mars_pairs.errors import TerrainError
from mars_pairs.geometry.frames import MARS_RADIUS_M
from mars_pairs.raster.terrain import Terrain

EQC0 = "+proj=eqc +lat_ts=0 +lon_0=0 +R=3396190 +units=m +no_defs"
EQC18 = "+proj=eqc +lat_ts=18.4663 +lon_0=0 +R=3396190 +units=m +no_defs"
X0, Y0 = 4351200.0, 1095210.0
ROWS, COLS = 150, 200


def _write(path: Path, data: np.ndarray, crs: str | None, tr: Affine, nodata=None) -> Path:
    """Write a single- or multi-band GeoTIFF."""
    arr = data if data.ndim == 3 else data[None]
    with rasterio.open(
        path, "w", driver="GTiff", width=arr.shape[2], height=arr.shape[1], count=arr.shape[0],
        dtype=arr.dtype, crs=crs, transform=tr, nodata=nodata,
    ) as ds:  # fmt: skip
        ds.write(arr)
    return path


@pytest.fixture
def dem_values() -> np.ndarray:
    rows, cols = np.mgrid[0:ROWS, 0:COLS]
    return (rows * 100.0 + cols - 5000.0).astype(np.float32)  # m: inside the Mars range


@pytest.fixture
def dem_path(tmp_path: Path, dem_values: np.ndarray) -> Path:
    return _write(tmp_path / "dem.tif", dem_values, EQC0, Affine(2.0, 0, X0, 0, -2.0, Y0))


def test_window_read_returns_sub_array_and_transform(dem_path, dem_values):
    with Terrain.open(dem_path) as t:
        x, y = X0 + 2.0 * 100.5, Y0 - 2.0 * 70.5  # centre of cell (row 70, col 100)
        win = t.read_dem_window(x, y, 20.0)
        col0 = round((win.transform.c - X0) / 2.0)
        row0 = round((Y0 - win.transform.f) / 2.0)
        assert win.transform.a == 2.0 and win.transform.e == -2.0
        rows, cols = win.shape
        np.testing.assert_array_equal(win.data, dem_values[row0 : row0 + rows, col0 : col0 + cols])
        assert win.data.dtype == np.float32
        left, bottom, right, top = win.bounds
        assert left <= x - 20 and right >= x + 20 and bottom <= y - 20 and top >= y + 20
        assert rows <= 24 and cols <= 24  # only the needed window
        assert win.crs == t.crs


def test_window_is_clipped_at_the_dem_edge(dem_path, dem_values):
    with Terrain.open(dem_path) as t:
        win = t.read_dem_window(X0 + 1.0, Y0 - 1.0, 30.0)
        assert win.transform.c == X0 and win.transform.f == Y0
        np.testing.assert_array_equal(win.data, dem_values[: win.shape[0], : win.shape[1]])


def test_nodata_becomes_nan_and_observer_on_nodata_raises(tmp_path):
    data = np.full((50, 60), 7.0, np.float32)
    data[10:20, 10:20] = -9999.0
    path = _write(tmp_path / "nd.tif", data, EQC0, Affine(1, 0, X0, 0, -1, Y0), nodata=-9999.0)
    with Terrain.open(path) as t:
        win = t.read_dem_window(X0 + 30.5, Y0 - 30.5, 25.0)
        assert np.isnan(win.data).sum() == 100
        assert np.nanmax(win.data) == 7.0
        with pytest.raises(TerrainError, match=r"nd\.tif.*no data under the observer"):
            t.read_dem_window(X0 + 15.5, Y0 - 15.5, 5.0)
        with pytest.raises(TerrainError, match="no data"):
            t.elevation_at(X0 + 15.5, Y0 - 15.5)


def test_integer_dem_nodata(tmp_path):
    data = np.full((20, 20), 120, np.int16)
    data[0, 0] = -32768
    path = _write(tmp_path / "i16.tif", data, EQC0, Affine(1, 0, X0, 0, -1, Y0), nodata=-32768)
    with Terrain.open(path) as t:
        win = t.read_dem_window(X0 + 10, Y0 - 10, 15.0)
        assert win.data.dtype == np.float32 and np.isnan(win.data[0, 0])
        assert np.nanmin(win.data) == 120.0


def test_dem_without_crs_raises(tmp_path):
    path = _write(tmp_path / "nocrs.tif", np.zeros((8, 8), np.float32), None,
                  Affine(1, 0, 0, 0, -1, 8))  # fmt: skip
    with pytest.raises(TerrainError, match=r"nocrs\.tif.*no CRS"):
        Terrain.open(path)


def test_missing_file_raises(tmp_path):
    with pytest.raises(TerrainError, match=r"absent\.tif"):
        Terrain.open(tmp_path / "absent.tif")


def test_observer_outside_raises(dem_path):
    with Terrain.open(dem_path) as t:
        with pytest.raises(TerrainError, match=r"dem\.tif.*outside the DEM"):
            t.read_dem_window(X0 - 100.0, Y0 - 10.0, 50.0)
        with pytest.raises(TerrainError, match="outside the DEM"):
            t.elevation_at(X0 + 10.0, Y0 + 5.0)


def test_elevation_at_is_bilinear(tmp_path):
    rows, cols = np.mgrid[0:40, 0:50]
    xs, ys = X0 + 0.5 * (cols + 0.5), Y0 - 0.5 * (rows + 0.5)
    plane = (100.0 + 0.3 * (xs - X0) - 0.2 * (Y0 - ys)).astype(np.float64)
    path = _write(tmp_path / "plane.tif", plane, EQC0, Affine(0.5, 0, X0, 0, -0.5, Y0))
    with Terrain.open(path) as t:
        for x, y in [(X0 + 3.13, Y0 - 7.77), (X0 + 10.0, Y0 - 10.0), (X0 + 24.6, Y0 - 19.6)]:
            assert t.elevation_at(x, y) == pytest.approx(100.0 + 0.3 * (x - X0) - 0.2 * (Y0 - y))


def test_lonlat_round_trip_and_eqc_formula(dem_path):
    with Terrain.open(dem_path) as t:
        lon, lat = t.to_lonlat(X0 + 100.0, Y0 - 50.0)
        assert lat == pytest.approx(math.degrees((Y0 - 50.0) / MARS_RADIUS_M))
        assert lon == pytest.approx(math.degrees((X0 + 100.0) / MARS_RADIUS_M))
        x, y = t.from_lonlat(lon, lat)
        assert (x, y) == pytest.approx((X0 + 100.0, Y0 - 50.0), abs=1e-6)
        xs, ys = t.from_lonlat(np.array([77.4, 77.5]), np.array([18.4, 18.5]))
        assert xs.shape == (2,)
        lons, lats = t.to_lonlat(xs, ys)
        np.testing.assert_allclose(lons, [77.4, 77.5])
        np.testing.assert_allclose(lats, [18.4, 18.5])


def test_places_crs_to_raster_crs(dem_path):
    # the same point has different eastings in lat_ts=18.4663 (PLACES) and lat_ts=0 (mosaics)
    with Terrain.open(dem_path) as t:
        e18, n18 = 4353000.0, 1094000.0
        x, y = t.to_raster_crs(e18, n18, EQC18)
        assert y == pytest.approx(n18)
        assert x == pytest.approx(e18 / math.cos(math.radians(18.4663)))
        back = t.from_raster_crs(x, y, EQC18)
        assert back == pytest.approx((e18, n18))


def test_ortho_same_crs_and_reprojected(tmp_path, dem_path):
    rgb = np.zeros((3, 300, 400), np.uint8)
    rgb[0] = (np.arange(400) % 256)[None, :]
    rgb[1] = 200
    same = _write(tmp_path / "ortho.tif", rgb, EQC0, Affine(1.0, 0, X0, 0, -1.0, Y0))
    bounds = (X0 + 50.0, Y0 - 80.0, X0 + 90.0, Y0 - 40.0)
    with Terrain.open(dem_path, ortho=same) as t:
        ow = t.read_ortho_window(bounds)
        assert ow.data.shape == (3, 40, 40) and ow.valid.all()
        np.testing.assert_array_equal(ow.data[0, 0], np.arange(50, 90))
        small = t.read_ortho_window(bounds, out_shape=(20, 20))
        assert small.data.shape == (3, 20, 20)
        edge = t.read_ortho_window((X0 - 10.0, Y0 - 10.0, X0 + 10.0, Y0 + 10.0))
        assert not edge.valid.all() and edge.valid.any()
    # the same image in the lat_ts=18.4663 CRS: x scaled by cos(18.4663 deg)
    k = math.cos(math.radians(18.4663))
    other = _write(tmp_path / "ortho18.tif", rgb, EQC18, Affine(k, 0, X0 * k, 0, -1.0, Y0))
    with Terrain.open(dem_path, ortho=other) as t:
        ow = t.read_ortho_window(bounds, out_shape=(40, 40))
        assert ow.valid[2:-2, 2:-2].all()
        assert np.abs(ow.data[1, 2:-2, 2:-2].astype(int) - 200).max() == 0
        np.testing.assert_allclose(ow.data[0, 5, 2:-2], np.arange(52, 88), atol=1)


def test_no_ortho_raises_and_context_closes(dem_path):
    with Terrain.open(dem_path) as t:
        with pytest.raises(TerrainError, match="no orthoimage"):
            t.read_ortho_window((X0, Y0 - 10, X0 + 10, Y0))
        ds = t._dem
    assert ds.closed


def test_elevation_from_a_window_is_the_read_value(dem_path):
    """The ground taken from a window the DEM read equals the DEM's own 2 x 2 read, bit for
    bit, inside the window, at its edge and off it (where the DEM is read again)."""
    rng = np.random.default_rng(5)
    with Terrain.open(dem_path) as t:
        window = t.read_dem_window(X0 + 200.0, Y0 - 150.0, 40.0)
        left, bottom, right, top = window.bounds
        xs = np.concatenate([rng.uniform(left - 30, right + 30, 200), [left + 0.1, right - 0.1]])
        ys = np.concatenate([rng.uniform(bottom - 30, top + 30, 200), [top - 0.1, bottom + 0.1]])
        for x, y in zip(xs, ys, strict=True):
            assert t.elevation_at(x, y, within=window) == t.elevation_at(x, y)
