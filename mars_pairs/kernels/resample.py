"""Numba resampling of a raster window at arbitrary (affine-mapped) pixel positions."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True)
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
    An axis-aligned map (b = d = 0: every north-up chip of a north-up raster) takes each
    column's and each row's source position once (``_sample_separable``, the same values).
    """
    if b == 0.0 and d == 0.0:
        return _sample_separable(src, a, b, c, d, e, f, rows, cols, nearest)
    return _sample_general(src, a, b, c, d, e, f, rows, cols, nearest)


@njit(cache=True, parallel=True)
def _sample_general(
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
    """``sample_affine`` for any affine map, each pixel's source position on its own."""
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


@njit(cache=True)
def _axis(
    scale: float, zero: float, shift: float, n: int, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One axis of an axis-aligned ``sample_affine``: for each output index k its source
    position t = scale (k + 0.5) + zero 0.5 + shift - 0.5 (``zero``: the other axis's
    coefficient, 0 or -0, so the sum is ``sample_affine``'s bit for bit), whether it lies on
    the source (``inside``), the nearest source index, and the bilinear pair (k0, k1) with
    weight w of k1 and 1 - w of k0."""
    inside = np.empty(n, dtype=np.bool_)
    near = np.empty(n, dtype=np.int64)
    k0 = np.empty(n, dtype=np.int64)
    k1 = np.empty(n, dtype=np.int64)
    wt = np.empty(n, dtype=np.float64)
    for k in range(n):
        t = scale * (k + 0.5) + zero * 0.5 + shift - 0.5
        near[k] = math.floor(t + 0.5)
        inside[k] = not (t < -0.5 or t > size - 0.5)
        t = min(max(t, 0.0), size - 1.0)
        lo = min(int(t), size - 2) if size > 1 else 0
        k0[k], k1[k], wt[k] = lo, min(lo + 1, size - 1), t - lo
    return inside, near, k0, k1, wt


@njit(cache=True, parallel=True)
def _sample_separable(
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
    """``sample_affine`` for b = d = 0: the same values, each column's and row's source
    position computed once."""
    h, w = src.shape
    out = np.empty((rows, cols), dtype=np.float32)
    in_u, near_u, j0s, j1s, tus = _axis(a, b, c, cols, w)
    in_v, near_v, i0s, i1s, tvs = _axis(e, d, f, rows, h)
    for r in prange(rows):
        if nearest:
            i = near_v[r]
            row_ok = 0 <= i < h
            for q in range(cols):
                j = near_u[q]
                out[r, q] = src[i, j] if row_ok and 0 <= j < w else np.nan
            continue
        if not in_v[r]:
            out[r, :] = np.nan
            continue
        i0, i1, tv = i0s[r], i1s[r], tvs[r]
        for q in range(cols):
            if not in_u[q]:
                out[r, q] = np.nan
                continue
            j0, j1, tu = j0s[q], j1s[q], tus[q]
            top = src[i0, j0] * (1 - tu) + src[i0, j1] * tu
            bottom = src[i1, j0] * (1 - tu) + src[i1, j1] * tu
            out[r, q] = top * (1 - tv) + bottom * tv
    return out
