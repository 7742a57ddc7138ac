"""``ChipReader.read_points``: a raster's physical values at map points, on its own grid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

import mars_pairs.raster.chips as chips
from mars_pairs.geometry.frames import MSL_PLACES_CRS
from mars_pairs.raster.chips import ChipReader

W, H = 48, 40
LEFT, TOP = 1000.0, 2000.0  # map metres of the raster's top-left corner, 2 m pixels
NODATA_AT = (10, 30)  # (row, col) of the one pixel without data


def _raw() -> np.ndarray:
    """Raw values 3 col + 7 row (int16; bilinear reproduces any linear function)."""
    rows, cols = np.mgrid[0:H, 0:W]
    raw = (3 * cols + 7 * rows).astype(np.int16)
    raw[NODATA_AT] = -32768
    return raw


def _write(path: Path, *, south_up: bool = False) -> Path:
    raw = _raw()
    transform = Affine(2.0, 0.0, LEFT, 0.0, -2.0, TOP)
    if south_up:  # the same map stored bottom row first
        raw = raw[::-1]
        transform = Affine(2.0, 0.0, LEFT, 0.0, 2.0, TOP - 2.0 * H)
    profile = {
        "driver": "GTiff", "width": W, "height": H, "count": 1, "dtype": "int16",
        "crs": MSL_PLACES_CRS, "transform": transform, "nodata": -32768,
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(raw, 1)
        dst.scales, dst.offsets = (0.5,), (-10.0,)
    return path


def _expected(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Physical value of the linear raster at map (x, y): pixel centres at integers."""
    col = (x - LEFT) / 2.0 - 0.5
    row = (TOP - y) / 2.0 - 0.5
    return (3 * col + 7 * row) * 0.5 - 10.0


def _points() -> tuple[np.ndarray, np.ndarray]:
    """(10, 20) map points inside the centre grid, away from the nodata pixel."""
    rng = np.random.default_rng(1)
    col = rng.uniform(0.0, W - 1.0, size=400)
    row = rng.uniform(0.0, H - 1.0, size=400)
    far = (np.abs(row - NODATA_AT[0]) > 1.5) | (np.abs(col - NODATA_AT[1]) > 1.5)
    col, row = col[far][:200].reshape(10, 20), row[far][:200].reshape(10, 20)
    return LEFT + 2.0 * (col + 0.5), TOP - 2.0 * (row + 0.5)


@pytest.mark.parametrize("south_up", [False, True])
def test_values_scale_offset_and_nodata(tmp_path: Path, south_up: bool) -> None:
    path = _write(tmp_path / "r.tif", south_up=south_up)
    x, y = _points()
    with ChipReader(path) as reader:
        got = reader.read_points(x, y, MSL_PLACES_CRS)
        np.testing.assert_allclose(got, _expected(x, y), atol=1e-3)
        # NaN: a NaN point, one off the raster, one next to the pixel without data
        r, c = NODATA_AT
        odd = reader.read_points(
            np.array([np.nan, LEFT - 50.0, LEFT + 2.0 * (c + 0.8), LEFT + 10.0]),
            np.array([TOP - 10.0, TOP - 10.0, TOP - 2.0 * (r + 0.9), TOP - 10.0]),
            MSL_PLACES_CRS,
        )
    assert np.isnan(odd[:3]).all() and odd[3] == pytest.approx(_expected(LEFT + 10.0, TOP - 10.0))
    assert got.shape == x.shape and got.dtype == np.float32


def test_strips_give_the_same_values(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _write(tmp_path / "r.tif")
    x, y = _points()
    with ChipReader(path) as reader:
        whole = reader.read_points(x, y, MSL_PLACES_CRS)
        monkeypatch.setattr(chips, "POINT_STRIP_PIXELS", 3 * W)  # 3 rows a strip
        reads = []
        real = chips.NorthUp.read
        monkeypatch.setattr(chips.NorthUp, "read", lambda *a, **k: reads.append(a) or real(*a, **k))
        strips = reader.read_points(x, y, MSL_PLACES_CRS)
    assert len(reads) > 5
    np.testing.assert_array_equal(strips, whole)


def test_points_in_another_crs_are_reprojected(tmp_path: Path) -> None:
    path = _write(tmp_path / "r.tif")
    x, y = _points()
    shifted = MSL_PLACES_CRS.replace("+x_0=0", "+x_0=5000").replace("+y_0=0", "+y_0=-300")
    with ChipReader(path) as reader:
        got = reader.read_points(x + 5000.0, y - 300.0, shifted)
    np.testing.assert_allclose(got, _expected(x, y), atol=1e-3)


@pytest.mark.parametrize(
    ("dtype", "nodata"), [("uint8", 0), ("float32", -3.4028234663852886e38), ("float32", np.nan)]
)
def test_a_band_masked_by_its_nodata_reads_as_through_its_gdal_mask(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dtype: str, nodata: float
) -> None:
    """The band read as it is and its nodata checked at each point's 2 x 2 gives the values
    (NaN included) of the band read through GDAL's mask and converted to float32."""
    rng = np.random.default_rng(4)
    raw = rng.integers(1, 250, size=(H, W)).astype(dtype)
    raw[rng.random((H, W)) < 0.04] = nodata  # scattered holes
    raw[:, 0] = nodata  # and an edge column
    profile = {
        "driver": "GTiff", "width": W, "height": H, "count": 1, "dtype": dtype,
        "crs": MSL_PLACES_CRS, "transform": Affine(2.0, 0.0, LEFT, 0.0, -2.0, TOP),
        "nodata": nodata,
    }  # fmt: skip
    with rasterio.open(tmp_path / "holes.tif", "w", **profile) as dst:
        dst.write(raw, 1)
    col = np.concatenate([rng.uniform(-1.0, W, 3000), rng.integers(0, W, 500).astype(float)])
    row = np.concatenate([rng.uniform(-1.0, H, 3000), rng.integers(0, H, 500).astype(float)])
    x, y = LEFT + 2.0 * (col + 0.5), TOP - 2.0 * (row + 0.5)  # pixel centres among them
    with ChipReader(tmp_path / "holes.tif") as reader:
        assert reader._plain_nodata(1) is not None  # the fast path
        fast = reader.read_points(x, y, MSL_PLACES_CRS)
        monkeypatch.setattr(ChipReader, "_plain_nodata", lambda self, band: None)
        masked = reader.read_points(x, y, MSL_PLACES_CRS)
    assert 100 < np.isnan(fast).sum() < len(x) - 100
    np.testing.assert_array_equal(fast, masked)


def test_a_band_with_an_alpha_mask_reads_nan_next_to_a_masked_pixel(tmp_path: Path) -> None:
    raw = _raw().astype(np.uint8)
    alpha = np.full((H, W), 255, dtype=np.uint8)
    alpha[NODATA_AT] = 0
    profile = {
        "driver": "GTiff", "width": W, "height": H, "count": 2, "dtype": "uint8",
        "crs": MSL_PLACES_CRS, "transform": Affine(2.0, 0.0, LEFT, 0.0, -2.0, TOP),
        "photometric": "MINISBLACK", "alpha": "YES",
    }  # fmt: skip
    with rasterio.open(tmp_path / "alpha.tif", "w", **profile) as dst:
        dst.write(raw, 1)
        dst.write(alpha, 2)
    r, c = NODATA_AT
    with ChipReader(tmp_path / "alpha.tif") as reader:
        assert reader._plain_nodata(1) is None  # the mask is read
        got = reader.read_points(
            np.array([LEFT + 2.0 * (c + 0.8), LEFT + 10.0]),
            np.array([TOP - 2.0 * (r + 0.9), TOP - 10.0]),
            MSL_PLACES_CRS,
        )
    assert np.isnan(got[0]) and got[1] == pytest.approx(3 * 4.5 + 7 * 4.5)  # between 4 centres
