"""Grid helpers shared by the kernels: DEM arrays with their affine, grid coordinates, bilinear.

Grid coordinates (u, v) = fractional (col, row) of a north-up raster, cell centres at integers:
x = c + a (u + 0.5), y = f + e (v + 0.5) in the raster's map units.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from affine import Affine
from numba import njit

from mars_pairs.errors import ArgumentError

#: a raster's affine: an ``Affine`` or its coefficients (a, b, c, d, e, f[, 0, 0, 1])
Transform = Affine | Sequence[float]


def as_grid(window: Any, transform: Transform | None = None) -> tuple[np.ndarray, Affine]:
    """(float32 C-contiguous DEM array, Affine) from a DemWindow, (array, transform) or array.

    ``transform`` may be a rasterio ``Affine`` or its six coefficients (a, b, c, d, e, f).
    Raises ArgumentError (a ValueError) for rotated/sheared transforms or a missing transform.
    """
    if hasattr(window, "data") and hasattr(window, "transform"):
        data, tr = window.data, window.transform
    elif isinstance(window, tuple) and len(window) == 2:
        data, tr = window
    else:
        data, tr = window, transform
    if tr is None:
        raise ArgumentError("a DEM array needs its affine transform (transform=...)")
    tr = _as_affine(tr)
    if tr.b != 0.0 or tr.d != 0.0:
        raise ArgumentError(f"rotated or sheared transforms are not supported: {tuple(tr)[:6]}")
    if tr.a == 0.0 or tr.e == 0.0:
        raise ArgumentError(f"degenerate transform (zero pixel size): {tuple(tr)[:6]}")
    arr = np.ascontiguousarray(data, dtype=np.float32)
    if arr.ndim != 2:
        raise ArgumentError(f"DEM window must be 2-D, got shape {arr.shape}")
    return arr, tr


def _as_affine(tr: Affine | Iterable[float]) -> Affine:
    """Affine from an Affine or a sequence of 6 (or 9) coefficients a, b, c, d, e, f."""
    if isinstance(tr, Affine):
        return tr
    coeffs = [float(v) for v in tr]
    if len(coeffs) not in (6, 9):
        raise ArgumentError(f"transform needs 6 coefficients (a, b, c, d, e, f), got {len(coeffs)}")
    return Affine(*coeffs[:6])


def xy_to_uv(tr: Affine, x: Any, y: Any) -> tuple[Any, Any]:
    """Map x, y -> grid (u, v) = fractional (col, row), cell centres at integers."""
    return (np.asarray(x) - tr.c) / tr.a - 0.5, (np.asarray(y) - tr.f) / tr.e - 0.5


@njit(cache=True)
def bilinear(dem: np.ndarray, u: float, v: float) -> float:
    """Bilinear DEM value (metres) at grid (u, v); NaN off the centre grid or next to nodata.

    Cells with zero weight are skipped, so points on grid lines/centres by nodata still work.
    """
    h, w = dem.shape
    if not (u >= 0.0 and v >= 0.0 and u <= w - 1 and v <= h - 1):
        return np.nan
    c0 = min(int(u), w - 2) if w > 1 else 0
    r0 = min(int(v), h - 2) if h > 1 else 0
    fu = u - c0
    fv = v - r0
    acc = 0.0
    for i in range(2):
        wv = fv if i == 1 else 1.0 - fv
        if wv == 0.0:
            continue
        for j in range(2):
            wu = fu if j == 1 else 1.0 - fu
            if wu == 0.0:
                continue
            acc += wv * wu * dem[r0 + i, c0 + j]
    return acc
