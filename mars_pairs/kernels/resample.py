"""Numba resampling of a raster window at arbitrary (affine-mapped) pixel positions."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def sample_affine(
    src: np.ndarray,
    a: float,
    b: float,
    c: float,
    d: float,
    e: float,
    f: float,
    rows: int,
    cols: int,
    nearest: bool,
) -> np.ndarray:
    """Sample ``src`` (2-D float32, NaN = no data) at the positions of an output grid.

    Output pixel (row, col) has its centre at source pixel coordinates
    u = a (col + 0.5) + b (row + 0.5) + c, v = d (col + 0.5) + e (row + 0.5) + f, where source
    pixel centres lie at half-integers (rasterio's pixel-corner convention). Bilinear (or
    nearest) interpolation; NaN outside the source or where a needed sample is NaN.
    """
    h, w = src.shape
    out = np.empty((rows, cols), dtype=np.float32)
    for r in prange(rows):
        for q in range(cols):
            u = a * (q + 0.5) + b * (r + 0.5) + c - 0.5
            v = d * (q + 0.5) + e * (r + 0.5) + f - 0.5
            if nearest:
                i, j = math.floor(v + 0.5), math.floor(u + 0.5)
                out[r, q] = src[i, j] if 0 <= i < h and 0 <= j < w else np.nan
                continue
            if u < -0.5 or v < -0.5 or u > w - 0.5 or v > h - 0.5:
                out[r, q] = np.nan
                continue
            u = min(max(u, 0.0), w - 1.0)
            v = min(max(v, 0.0), h - 1.0)
            j0, i0 = min(int(u), w - 2) if w > 1 else 0, min(int(v), h - 2) if h > 1 else 0
            tu, tv = u - j0, v - i0
            j1, i1 = min(j0 + 1, w - 1), min(i0 + 1, h - 1)
            top = src[i0, j0] * (1 - tu) + src[i0, j1] * tu
            bottom = src[i1, j0] * (1 - tu) + src[i1, j1] * tu
            out[r, q] = top * (1 - tv) + bottom * tv
    return out
