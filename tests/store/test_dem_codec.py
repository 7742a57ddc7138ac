"""The DEM chip's quantized TIFF: precision against the float32 chip, no data, GDAL's reading
of the same bytes, the version-1 ``.npy`` still read, bad bytes named."""

from __future__ import annotations

import io

import numpy as np
import pytest

from mars_pairs.store.dem_codec import (
    FINEST_SCALE_M,
    NODATA,
    decode_dem,
    decode_dem_values,
    dem_chip,
    dem_encoding,
    dem_member,
    encode_dem,
    quantize,
)
from mars_pairs.store.float_tiff import decode_float_tiff, encode_float_tiff
from mars_pairs.torch.decode import decode_member, decode_raw
from support.members import dem_metres, tiff_array


def _chip(seed: int = 0, size: int = 64, base: float = -2571.4, relief: float = 40.0) -> np.ndarray:
    """A float32 chip of smooth terrain (metres) with rough noise and a no-data corner."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    z = base + relief * np.sin(3 * x) * np.cos(2 * y) + rng.normal(0, 0.05, (size, size))
    chip = z.astype(np.float32)
    chip[:5, :9] = np.nan
    return chip


def _max_error(decoded: np.ndarray, chip: np.ndarray) -> float:
    finite = np.isfinite(chip)
    return float(np.abs(decoded[finite].astype(np.float64) - chip[finite]).max())


@pytest.mark.parametrize(
    ("base", "relief", "scale"),
    [(-2571.37, 40.0, FINEST_SCALE_M), (-4480.9, 300.0, FINEST_SCALE_M),
     (1234.5, 700.0, 2 * FINEST_SCALE_M), (-8000.2, 4000.0, 16 * FINEST_SCALE_M)],
)  # fmt: skip
def test_a_chip_decodes_within_half_its_quantum_and_nan_where_nan(
    base: float, relief: float, scale: float
) -> None:
    chip = _chip(1, base=base, relief=relief)
    data, enc = encode_dem(chip)
    decoded = decode_dem(data)
    assert enc.scale_m == scale and enc.offset_m == np.floor(np.nanmin(chip))
    assert decoded.dtype == np.float32 and decoded.shape == chip.shape
    assert np.array_equal(np.isnan(decoded), np.isnan(chip))
    assert _max_error(decoded, chip) <= enc.max_error_m == scale / 2
    # the error reaches the bound: the quantum is what it says, not finer by luck
    assert _max_error(decoded, chip) > 0.9 * enc.max_error_m


def test_gdal_reads_the_same_metres_from_the_file() -> None:
    chip = _chip(2)
    data, enc = encode_dem(chip)
    gdal = dem_metres(data)  # GDAL applies the file's scale, offset and no-data value
    np.testing.assert_array_equal(gdal, decode_dem(data).astype(np.float64))
    assert _max_error(gdal, chip) <= FINEST_SCALE_M / 2
    values, read = decode_dem_values(data)
    assert read == enc and values.dtype == np.uint16
    assert (values == NODATA).sum() == np.isnan(chip).sum()


def test_infinities_and_an_empty_chip_are_no_data() -> None:
    chip = _chip(3)
    chip[10, 10], chip[11, 11] = np.inf, -np.inf
    decoded = decode_dem(encode_dem(chip)[0])
    assert np.isnan(decoded[10, 10]) and np.isnan(decoded[11, 11])
    empty = np.full((8, 8), np.nan, dtype=np.float32)
    assert np.isnan(decode_dem(encode_dem(empty)[0])).all()


def test_the_version_1_npy_chip_still_decodes_bit_for_bit() -> None:
    chip = _chip(4)
    buf = io.BytesIO()
    np.save(buf, chip, allow_pickle=False)
    old = decode_raw("dem", bytearray(buf.getvalue()))
    np.testing.assert_array_equal(old, chip)
    new = decode_member("dem", encode_dem(chip)[0])
    assert new.shape == (1, *chip.shape) and _max_error(new[0].numpy(), chip) <= FINEST_SCALE_M / 2
    assert (dem_member(1), dem_member(2)) == ("dem.npy", "dem.tif")


@pytest.mark.parametrize(
    "damage", [lambda b: b"GIF89a" + b[6:], lambda b: b[:200], lambda b: b[:-40] + bytes(40)]
)
def test_bytes_that_are_no_dem_chip_are_a_value_error(damage: object) -> None:
    data, _ = encode_dem(_chip(5))
    with pytest.raises(ValueError):
        decode_dem(damage(data))  # type: ignore[operator]


def test_a_float_member_round_trips_bit_for_bit_and_gdal_reads_it() -> None:
    rng = np.random.default_rng(6)
    px = rng.uniform(-0.5, 1647.5, (32, 40, 2)).astype(np.float32)
    px[rng.random((32, 40)) < 0.7] = np.nan
    data = encode_float_tiff(px)
    np.testing.assert_array_equal(decode_float_tiff(data), px)  # NaN where NaN, bit for bit
    np.testing.assert_array_equal(tiff_array(data), px)
    one = px[..., 0]
    np.testing.assert_array_equal(decode_float_tiff(encode_float_tiff(one)), one)
    with pytest.raises(ValueError, match="float32"):
        decode_float_tiff(encode_dem(_chip(7))[0])


def test_dem_chip_reads_either_format() -> None:
    chip = _chip(8)
    buf = io.BytesIO()
    np.save(buf, chip, allow_pickle=False)
    np.testing.assert_array_equal(dem_chip(buf.getvalue()), chip)
    assert _max_error(dem_chip(encode_dem(chip)[0]), chip) <= FINEST_SCALE_M / 2


def test_quantize_is_the_rounded_clipped_float64_steps_with_nodata():
    rng = np.random.default_rng(4)
    for spread in (0.01, 1.0, 60.0, 500.0):
        dem = (-2500.0 + rng.normal(0.0, spread, (37, 53))).astype(np.float32)
        dem[rng.random(dem.shape) < 0.1] = np.nan
        dem[0, :3] = (np.inf, -np.inf, np.nan)
        dem[1, :8] = np.round(dem[1, :8] * 256) / 256  # halfway steps: round half to even
        enc = dem_encoding(dem)
        steps = np.rint((dem.astype(np.float64) - enc.offset_m) / enc.scale_m)
        expected = np.where(np.isfinite(dem), np.clip(steps, 0, 65534), enc.nodata)
        got = quantize(dem, enc)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, expected.astype(np.uint16))
