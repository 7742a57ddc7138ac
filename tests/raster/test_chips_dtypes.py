"""Ortho chips of any data type scale by the ortho's range; DEM chips apply scale/offset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from mars_pairs.geometry.frames import MSL_PLACES_CRS
from mars_pairs.raster.chips import ChipGrid, ChipReader

N = 64


def write_raster(path: Path, data: np.ndarray, **extra: object) -> Path:
    profile = {
        "driver": "GTiff",
        "width": N,
        "height": N,
        "count": 1,
        "dtype": str(data.dtype),
        "crs": MSL_PLACES_CRS,
        "transform": from_origin(0.0, float(N), 1.0, 1.0),
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)
        if "scale" in extra:
            dst.scales, dst.offsets = (extra["scale"],), (extra["offset"],)
        if "tags" in extra:
            dst.update_tags(1, **extra["tags"])  # type: ignore[arg-type]
    return path


def ramp() -> np.ndarray:
    """0..1 along the columns (left to right), the same on every row."""
    return np.tile(np.linspace(0.0, 1.0, N), (N, 1))


def grid() -> ChipGrid:
    # the whole raster, pixel for pixel (pixel centres on the source's)
    return ChipGrid.around(N / 2, N / 2, float(N), N, MSL_PLACES_CRS)


def test_a_float_ortho_in_0_1_spans_the_bytes(tmp_path: Path) -> None:
    path = write_raster(tmp_path / "o.tif", ramp().astype(np.float32))
    with ChipReader(path) as reader:
        chip = reader.read_uint8(grid())
        vr = reader.value_range()
    assert (vr.low, vr.high, vr.source) == (0.0, 1.0, "measured")
    expected = np.rint(ramp() * 255).astype(np.uint8)  # the truth, not the reader's code
    assert np.abs(chip.astype(int) - expected).max() <= 1
    assert chip.min() == 0 and chip.max() == 255


def test_a_12_bit_uint16_ortho_is_not_all_white(tmp_path: Path) -> None:
    path = write_raster(tmp_path / "o.tif", np.rint(ramp() * 4000 + 95).astype(np.uint16))
    with ChipReader(path) as reader:
        chip = reader.read_uint8(grid())
        assert reader.value_range().to_dict() == {"low": 95.0, "high": 4095.0, "source": "measured"}
    assert np.abs(chip.astype(int) - np.rint(ramp() * 255)).max() <= 1
    assert (chip == 255).mean() < 0.05


def test_a_declared_range_wins_over_the_measured_one(tmp_path: Path) -> None:
    data = np.rint(ramp() * 1000).astype(np.uint16)
    tags = {"STATISTICS_MINIMUM": "0", "STATISTICS_MAXIMUM": "2000"}
    path = write_raster(tmp_path / "o.tif", data, tags=tags)
    with ChipReader(path) as reader:
        chip = reader.read_uint8(grid())
        assert reader.value_range().source == "declared"
    assert chip.max() == pytest.approx(128, abs=1)


def test_uint8_orthos_are_kept_as_they_are(tmp_path: Path) -> None:
    data = np.rint(ramp() * 200).astype(np.uint8)
    path = write_raster(tmp_path / "o.tif", data)
    with ChipReader(path) as reader:
        assert np.array_equal(reader.read_uint8(grid()), data)
        assert reader.value_range().source == "dtype"


def test_dem_chips_apply_scale_and_offset(tmp_path: Path) -> None:
    raw = np.rint(ramp() * 1000).astype(np.int16)
    path = write_raster(tmp_path / "d.tif", raw, scale=0.5, offset=-2500.0)
    with ChipReader(path) as reader:
        chip = reader.read(grid())
    np.testing.assert_allclose(chip, raw * 0.5 - 2500.0, atol=1e-3)
