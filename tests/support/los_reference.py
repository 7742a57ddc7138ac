"""Exact line-of-sight reference for viewshed tests and the benchmark, written from the definition.

Frames and units: the DEM grid, (u, v) = fractional (col, row), cell centres at integers; map
pixel sizes ``a`` (x per column) and ``e`` (y per row) in metres; elevations in metres.

Definition: the terrain is the bilinear surface through the cell centres, lowered by d^2 / (2R)
at horizontal distance d (metres) from the observer. A cell (col, row) is visible from the eye
(grid point (u0, v0), elevation ``eye``) when the straight segment from the eye to the cell's
surface point (DEM value + target height, lowered by its own d^2 / (2R)) stays on or above that
terrain everywhere along it. Along the segment the bilinear terrain is a quadratic of the
segment parameter inside each grid quad, so the test is exact: every piece between two grid-line
crossings is checked at its ends and at its stationary point. Quads with a nodata corner never
block; a nodata cell is never visible. No band limits: callers mask by azimuth/elevation bands.
Nothing here is shared with ``mars_pairs.kernels``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

TOL_M = 1e-6  # metres the terrain may rise above the segment (rounding at the target itself)


@njit(cache=True)
def _piece_max(dem, i, j, u0, v0, du, dv, ta, tb, q2c, eye, slope):
    """Max over t in [ta, tb] of terrain - segment height, inside the quad (col i, row j)."""
    z00 = dem[j, i]
    z10 = dem[j, i + 1]
    z01 = dem[j + 1, i]
    z11 = dem[j + 1, i + 1]
    if not (z00 == z00 and z10 == z10 and z01 == z01 and z11 == z11):
        return -np.inf
    fu0 = u0 - i
    fv0 = v0 - j
    ca = z10 - z00
    cb = z01 - z00
    cc = z00 - z10 - z01 + z11
    q2 = cc * du * dv - q2c
    q1 = ca * du + cb * dv + cc * (fu0 * dv + fv0 * du) - slope
    q0 = z00 + ca * fu0 + cb * fv0 + cc * fu0 * fv0 - eye
    best = max(q0 + ta * (q1 + ta * q2), q0 + tb * (q1 + tb * q2))
    if q2 < 0.0:
        tv = -q1 / (2.0 * q2)
        if ta < tv < tb:
            best = max(best, q0 + tv * (q1 + tv * q2))
    return best


@njit(cache=True)
def segment_clear(dem, u0, v0, eye, col, row, a, e, th, inv2r):
    """Is cell (col, row) visible from grid point (u0, v0) at elevation ``eye`` (see module)?"""
    h, w = dem.shape
    zc = dem[row, col]
    if zc != zc:
        return False
    du = col - u0
    dv = row - v0
    dc2 = (du * a) ** 2 + (dv * e) ** 2
    zt = zc + th - dc2 * inv2r
    slope = zt - eye  # segment height = eye + t * slope
    q2c = dc2 * inv2r
    # grid-line crossings, t in (0, 1), merged in order
    tu_step = 1.0 / abs(du) if du != 0.0 else np.inf
    tv_step = 1.0 / abs(dv) if dv != 0.0 else np.inf
    if du > 0.0:
        tu = (math.floor(u0) + 1.0 - u0) / du
    elif du < 0.0:
        tu = (math.ceil(u0) - 1.0 - u0) / du
    else:
        tu = np.inf
    if dv > 0.0:
        tv = (math.floor(v0) + 1.0 - v0) / dv
    elif dv < 0.0:
        tv = (math.ceil(v0) - 1.0 - v0) / dv
    else:
        tv = np.inf
    ta = 0.0
    while ta < 1.0:
        tb = min(tu, tv, 1.0)
        tm = 0.5 * (ta + tb)
        um = u0 + tm * du
        vm = v0 + tm * dv
        i = min(max(math.floor(um), 0), w - 2)
        j = min(max(math.floor(vm), 0), h - 2)
        inside = 0.0 <= um <= w - 1 and 0.0 <= vm <= h - 1
        if inside and _piece_max(dem, i, j, u0, v0, du, dv, ta, tb, q2c, eye, slope) > TOL_M:
            return False
        if tb == tu:
            tu += tu_step
        if tb == tv:
            tv += tv_step
        ta = tb
    return True


@njit(cache=True, parallel=True)
def _reference(dem, u0, v0, eye, radius, a, e, th, inv2r, rows, cols):
    out = np.zeros(rows.size, dtype=np.uint8)
    for k in prange(rows.size):
        out[k] = segment_clear(dem, u0, v0, eye, cols[k], rows[k], a, e, th, inv2r)
    return out


def exact_viewshed(
    dem: np.ndarray,
    u0: float,
    v0: float,
    eye: float,
    radius: float,
    *,
    a: float = 1.0,
    e: float = -1.0,
    th: float = 0.0,
    planet_radius: float = 0.0,
    cells: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """uint8 exact visibility of every cell within ``radius`` metres (or of ``cells`` = (rows,
    cols) only: then a 1-D array in their order). Observer at grid (u0, v0), eye in metres."""
    dem = np.ascontiguousarray(dem, dtype=np.float64)
    inv2r = 0.0 if not planet_radius else 0.5 / planet_radius
    if cells is not None:
        rows, cols = (np.ascontiguousarray(c, dtype=np.int64) for c in cells)
        return _reference(dem, u0, v0, eye, radius, a, e, th, inv2r, rows, cols)
    h, w = dem.shape
    rr, cc = np.mgrid[0:h, 0:w]
    d2 = ((cc - u0) * a) ** 2 + ((rr - v0) * e) ** 2
    sel = d2 <= radius * radius
    out = np.zeros((h, w), np.uint8)
    out[sel] = _reference(dem, u0, v0, eye, radius, a, e, th, inv2r, rr[sel], cc[sel])
    return out


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = a.astype(bool), b.astype(bool)
    union = (a | b).sum()
    return 1.0 if union == 0 else float((a & b).sum() / union)
