"""Any axis-aligned raster reads as its north-up twin; rotated grids are refused at open;
chip pixels without data (nodata, alpha 0, off the raster) are NaN and count against coverage."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.errors import WindowError
from rasterio.windows import Window, from_bounds

from mars_pairs.errors import TerrainError
from mars_pairs.raster.chips import ChipGrid, ChipReader, coverage
from mars_pairs.raster.grid import NorthUp
from mars_pairs.raster.terrain import Terrain

EQC0 = "+proj=eqc +lat_ts=0 +lon_0=0 +R=3396190 +units=m +no_defs"
EQC18 = "+proj=eqc +lat_ts=18.4663 +lon_0=0 +R=3396190 +units=m +no_defs"
X0, Y0 = 4351200.0, 1095210.0  # map offsets in the millions, as real Mars maps have
ROWS, COLS, RES = 90, 120, 0.5


def write(path: Path, data: np.ndarray, tr: Affine, crs: str = EQC0, **extra: object) -> Path:
    arr = data if data.ndim == 3 else data[None]
    profile = {
        "driver": "GTiff", "width": arr.shape[2], "height": arr.shape[1], "count": arr.shape[0],
        "dtype": arr.dtype.name, "crs": crs, "transform": tr, **extra,
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(arr)
    return path


def terrain_values() -> np.ndarray:
    rng = np.random.default_rng(5)
    z = rng.normal(-2500.0, 3.0, (ROWS, COLS)).astype(np.float32)
    z[:4, :6] = np.nan  # a nodata corner, north-west
    return z


NORTH_UP = Affine(RES, 0.0, X0, 0.0, -RES, Y0)
# the same grid stored in the other pixel orders: (name, transform, how the array is stored)
ORDERS = {
    "south-up": (Affine(RES, 0.0, X0, 0.0, RES, Y0 - RES * ROWS), lambda a: a[..., ::-1, :]),
    "east-left": (Affine(-RES, 0.0, X0 + RES * COLS, 0.0, -RES, Y0), lambda a: a[..., ::-1]),
    "upside-down": (
        Affine(-RES, 0.0, X0 + RES * COLS, 0.0, RES, Y0 - RES * ROWS),
        lambda a: a[..., ::-1, ::-1],
    ),
}


@pytest.fixture
def twins(tmp_path: Path, request: pytest.FixtureRequest) -> tuple[Path, Path]:
    """A north-up DEM and the same DEM stored in the order ``request.param``."""
    tr, store = ORDERS[request.param]
    z = terrain_values()
    north = write(tmp_path / "north.tif", z, NORTH_UP, nodata=np.nan)
    other = write(tmp_path / f"{request.param}.tif", np.ascontiguousarray(store(z)), tr)
    with rasterio.open(other) as ds:  # the file really is stored that way
        assert (ds.transform.a < 0, ds.transform.e > 0) == {
            "south-up": (False, True),
            "east-left": (True, False),
            "upside-down": (True, True),
        }[request.param]
    return north, other


@pytest.mark.parametrize("twins", list(ORDERS), indirect=True)
def test_chips_of_any_axis_order_equal_the_north_up_ones(twins):
    north, other = twins
    grids = [
        ChipGrid.around(X0 + 20.3, Y0 - 17.9, 16.0, 40, EQC0),  # north-up, inside
        ChipGrid.around(X0 + 30.1, Y0 - 22.4, 20.0, 48, EQC0, rotation_deg=33.0),  # heading-up
        ChipGrid.around(X0 + 2.2, Y0 - 1.7, 12.0, 24, EQC0),  # over the nodata corner and edge
        ChipGrid.around(X0 * math.cos(0.3223) + 25.0, Y0 - 25.0, 16.0, 32, EQC18),  # warped
    ]
    with ChipReader(north) as a, ChipReader(other) as b:
        assert b.bounds == a.bounds == (X0, Y0 - RES * ROWS, X0 + RES * COLS, Y0)
        for grid in grids:
            for nearest in (False, True):
                want, got = a.read(grid, nearest=nearest), b.read(grid, nearest=nearest)
                assert np.isfinite(want).any()
                np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("twins", list(ORDERS), indirect=True)
def test_terrain_of_any_axis_order_equals_the_north_up_one(twins):
    north, other = twins
    with Terrain.open(north) as a, Terrain.open(other) as b:
        assert b.transform == a.transform and b.bounds == a.bounds
        for x, y in [(X0 + 20.3, Y0 - 17.9), (X0 + 1.1, Y0 - 40.0), (X0 + 59.7, Y0 - 44.8)]:
            wa, wb = a.read_dem_window(x, y, 6.0), b.read_dem_window(x, y, 6.0)
            assert wb.transform == wa.transform and wb.transform.e < 0
            np.testing.assert_array_equal(wb.data, wa.data)
            assert b.elevation_at(x, y) == a.elevation_at(x, y)
        # off the DEM and on nodata: the same errors
        with pytest.raises(TerrainError, match="outside the DEM"):
            b.elevation_at(X0 - 1.0, Y0 - 1.0)
        with pytest.raises(TerrainError, match="no data"):
            b.elevation_at(X0 + 0.6, Y0 - 0.6)


@pytest.mark.parametrize("twins", ["south-up", "upside-down"], indirect=True)
def test_terrain_ortho_of_any_axis_order_equals_the_north_up_one(twins):
    north, other = twins
    box = (X0 + 10.0, Y0 - 30.0, X0 + 40.0, Y0 - 5.0)
    with Terrain.open(north, ortho=north) as a, Terrain.open(north, ortho=other) as b:
        for shape in (None, (20, 24)):
            oa, ob = a.read_ortho_window(box, shape), b.read_ortho_window(box, shape)
            np.testing.assert_array_equal(ob.valid, oa.valid)
            np.testing.assert_array_equal(ob.data, oa.data)


@pytest.mark.parametrize(
    "tr",
    [
        Affine.translation(X0, Y0) * Affine.rotation(10.0) * Affine.scale(RES, -RES),
        Affine(RES, 0.1, X0, 0.0, -RES, Y0),  # sheared
        Affine(0.0, RES, X0, RES, 0.0, Y0),  # transposed: columns run north
    ],
    ids=["rotated", "sheared", "transposed"],
)
def test_rotated_grids_are_refused_at_open_naming_the_file_and_the_fix(tmp_path, tr):
    path = write(tmp_path / "turned.tif", terrain_values(), tr)
    with pytest.raises(TerrainError, match=r"turned\.tif: DEM grid is rotated.*gdalwarp"):
        Terrain.open(path)
    with pytest.raises(TerrainError, match=r"turned\.tif: orthoimage grid is rotated.*gdalwarp"):
        Terrain.open(write(tmp_path / "dem.tif", terrain_values(), NORTH_UP), ortho=path)
    with pytest.raises(TerrainError, match=r"turned\.tif: raster grid is rotated.*gdalwarp"):
        ChipReader(path)


def rgba_ortho(path: Path, tr: Affine, crs: str = EQC0) -> Path:
    """An RGBA ortho, alpha 0 on its western 30 columns, value 90 everywhere."""
    rgba = np.full((4, ROWS, COLS), 90, np.uint8)
    rgba[3] = 255
    rgba[3, :, :30] = 0
    return write(path, rgba, tr, crs, photometric="RGB", alpha="YES")


@pytest.mark.parametrize("crs", [EQC0, EQC18])
def test_alpha_zero_and_off_raster_pixels_have_no_data(tmp_path, crs):
    # the chip grid (EQC0) straddles the alpha edge (x = X0 + 15) and the northern edge (Y0)
    path = rgba_ortho(tmp_path / "rgba.tif", NORTH_UP, EQC0)
    if crs == EQC18:  # the same ortho seen from a CRS where x is scaled by cos(18.4663 deg)
        k = math.cos(math.radians(18.4663))
        path = rgba_ortho(tmp_path / "rgba18.tif", Affine(RES * k, 0, X0 * k, 0, -RES, Y0), crs)
    size_m, size_px = 20.0, 40
    cx, cy = X0 + 20.1, Y0 - 5.1  # no chip pixel centre on an edge below
    grid = ChipGrid.around(cx, cy, size_m, size_px, EQC0)
    with ChipReader(path) as reader:
        chip = reader.read(grid)
    # independently: a chip pixel has data when its centre lies east of the first opaque
    # pixel's centre (x > X0 + 15.25: bilinear needs both neighbours) and on the raster
    # (y < Y0); warped through another CRS, one pixel column of slack
    col = (np.arange(size_px) + 0.5) * (size_m / size_px) + cx - size_m / 2
    row = cy + size_m / 2 - (np.arange(size_px) + 0.5) * (size_m / size_px)
    inside = (col[None, :] > X0 + 15.25) & (row[:, None] < Y0)
    slack = 1.0 / size_px if crs == EQC18 else 0.0
    assert coverage(chip) == pytest.approx(inside.mean(), abs=slack)
    assert 0.3 < coverage(chip) < 0.6
    assert np.all(chip[np.isfinite(chip)] == 90.0)
    if crs == EQC0:
        np.testing.assert_array_equal(np.isfinite(chip), inside)


def test_coverage_of_nothing_and_of_everything():
    assert coverage(np.full((4, 4), np.nan, np.float32)) == 0.0
    assert coverage(np.zeros((4, 4), np.float32)) == 1.0
    assert coverage(np.zeros((0, 0), np.float32)) == 0.0


# values at and around each nodata value, some inside GDAL's float32 tolerance of it and,
# near -FLT_MAX, where the tolerance's sum overflows
_NEAR = [-9999.0, -9999.001, -9998.99, 0.0, 1e-30, -3.4e38, -3.0e38, -1e32, -1e30, 5.0, 255.0]
_NODATA_CASES = [
    ("float32", -9999.0), ("float32", 0.0), ("float32", -3.4028234663852886e38),
    ("float32", math.nan), ("uint8", 0.0), ("uint8", 255.0), ("uint8", 1.5),
    ("int16", -32768.0), ("uint16", 7.0), ("float64", -9999.0), ("uint8", None),
]  # fmt: skip


@pytest.mark.parametrize(("dtype", "nodata"), _NODATA_CASES)
def test_read_nan_equals_the_masked_read_filled_with_nan(tmp_path, dtype, nodata):
    values = np.array([*_NEAR, math.nan, -math.inf, 1.0, 7.0, 2.0], dtype=np.float64)
    if np.issubdtype(np.dtype(dtype), np.integer):
        info = np.iinfo(dtype)
        values = np.clip(np.nan_to_num(values, nan=1.0, neginf=info.min), info.min, info.max)
    data = np.tile(values.astype(dtype), (3, 1))
    extra = {} if nodata is None else {"nodata": nodata}
    path = write(tmp_path / "nd.tif", data, NORTH_UP, **extra)
    with rasterio.open(path) as ds:
        grid = NorthUp.of(ds, str(path), "raster")
        window = Window(2, 1, data.shape[1] - 3, 2)
        expected = grid.read(ds, 1, window, masked=True).astype(np.float32).filled(np.nan)
        got = grid.read_nan(ds, 1, window)
        no_infinity = grid.read_nan(ds, 1, window, nonfinite=True)
    assert got.dtype == no_infinity.dtype == np.float32
    finite_expected = np.where(np.isfinite(expected), expected, np.float32(np.nan))
    np.testing.assert_array_equal(no_infinity, finite_expected)
    np.testing.assert_array_equal(got, expected)  # NaN where NaN, the same values elsewhere
    if nodata is not None and not math.isnan(nodata) and dtype != "uint8":
        assert np.isnan(got).any()  # the test reads some masked cells


def test_a_chip_reader_over_an_open_dataset_reads_it_and_leaves_it_open(tmp_path):
    path = write(tmp_path / "dem.tif", terrain_values(), NORTH_UP, nodata=np.nan)
    grid = ChipGrid.around(X0 + 30.0, Y0 - 20.0, 10.0, 16, EQC0)
    with ChipReader(path) as own:
        expected = own.read(grid)
    with rasterio.open(path) as ds:
        shared = ChipReader(path, ds)
        np.testing.assert_array_equal(shared.read(grid), expected)
        shared.close()
        assert not ds.closed


@pytest.mark.parametrize("tr", [NORTH_UP, Affine(0.3, 0.0, 123.456, 0.0, -0.7, -98765.4321)])
def test_window_of_a_box_is_rasterios_from_bounds(tr):
    grid = NorthUp(tr, COLS, ROWS, False, False)
    rng = np.random.default_rng(6)
    for i in range(2000):
        x0 = tr.c + rng.uniform(-20.0, COLS + 20.0) * tr.a
        y0 = tr.f + rng.uniform(-20.0, ROWS + 20.0) * tr.e
        w, h = (0.0, 0.0) if i % 100 == 0 else rng.uniform(0.0, 80.0, 2)
        box = (x0, y0 - h, x0 + w, y0)
        expected = from_bounds(*box, transform=tr)
        got = grid.window_of(*box)
        assert (got.col_off, got.row_off, got.width, got.height) == (
            expected.col_off, expected.row_off, expected.width, expected.height,
        )  # fmt: skip
    with pytest.raises(WindowError):
        grid.window_of(X0 + 5.0, Y0 - 5.0, X0, Y0)  # right of left
