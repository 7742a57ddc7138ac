"""Numba: a float32 raster block with NaN for its nodata value, in one pass (``raster.grid``)."""

from __future__ import annotations

import numpy as np
from numba import njit

_EPS32 = np.float32(np.finfo(np.float32).eps)
_TWO32 = np.float32(2.0)


@njit(cache=True)
def float32_nodata_nan(data: np.ndarray, nodata: np.float32, every_nonfinite: bool) -> np.ndarray:
    """A float32 copy of ``data`` (2-D float32) with NaN where it equals ``nodata`` as GDAL's
    nodata mask tests it (``a == b or |a - b| < eps * |a + b| * 2``, in float32), and with
    ``every_nonfinite`` also where it is infinite. ``nodata`` not NaN."""
    rows, cols = data.shape
    out = np.empty((rows, cols), dtype=np.float32)
    nan = np.float32(np.nan)
    for r in range(rows):
        for q in range(cols):
            z = data[r, q]
            masked = z == nodata or abs(z - nodata) < _EPS32 * abs(z + nodata) * _TWO32
            out[r, q] = nan if masked or (every_nonfinite and not np.isfinite(z)) else z
    return out


@njit(cache=True)
def uint8_nodata_nan(data: np.ndarray, nodata: int) -> np.ndarray:
    """A float32 copy of ``data`` (2-D uint8) with NaN where it equals ``nodata`` (0..255)."""
    rows, cols = data.shape
    out = np.empty((rows, cols), dtype=np.float32)
    nan = np.float32(np.nan)
    for r in range(rows):
        for q in range(cols):
            z = data[r, q]
            out[r, q] = nan if z == nodata else np.float32(z)
    return out
