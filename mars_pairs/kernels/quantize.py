"""Numba: a float32 DEM chip's uint16 quantization in one pass (``store.dem_codec``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def quantize_steps(
    dem: np.ndarray, offset: float, scale: float, max_step: int, nodata: int
) -> np.ndarray:
    """uint16 (H, W): ``rint((float64(z) - offset) / scale)`` clipped to [0, ``max_step``]
    (round half to even, as ``np.rint``), ``nodata`` where z is not finite; ``dem`` float32
    (H, W) metres."""
    rows, cols = dem.shape
    out = np.empty((rows, cols), dtype=np.uint16)
    top = float(max_step)
    for r in range(rows):
        for q in range(cols):
            z = np.float64(dem[r, q])
            if not math.isfinite(z):
                out[r, q] = nodata
                continue
            step = np.rint((z - offset) / scale)
            out[r, q] = min(max(step, 0.0), top)
    return out
