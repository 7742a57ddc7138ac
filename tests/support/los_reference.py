"""Exact line-of-sight reference for viewshed tests and the benchmark, written from the definition.

Frames and units: the DEM grid, (u, v) = fractional (col, row), cell centres at integers; map
pixel sizes ``a`` (x per column) and ``e`` (y per row) in metres; elevations in metres.

Definition: the terrain is the bilinear surface through the cell centres, lowered by d^2 / (2R)
at horizontal distance d (metres) from the observer. A cell (col, row) is visible from the eye
(grid point (u0, v0), elevation ``eye``) when the straight segment from the eye to the cell's
surface point (DEM value + target height, lowered by its own d^2 / (2R)) stays on or above that
terrain everywhere along it. Quads with a nodata corner never block; a nodata cell is never
visible. No band limits: callers mask by azimuth/elevation bands.

Method (derived here, sharing no formula with ``mars_pairs.kernels``): the segment is cut at
every grid line it crosses (all crossing parameters listed, then sorted). Inside one quad,
terrain minus segment is a polynomial of degree <= 2 of the segment parameter (bilinear along a
line: degree 2; curvature drop: degree 2; segment: degree 1), so it is known exactly from its
values at the piece's two ends and middle, each computed by evaluating the quad's bilinear
interpolant directly; the maximum of that parabola over the piece is taken in closed form.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

TOL_M = 1e-6  # metres the terrain may rise above the segment (rounding at the target itself)


@njit(cache=True)
def _integers_between(p0: float, dp: float, out: np.ndarray, n: int) -> int:
    """Write to ``out[n:]`` the t where p0 + t dp is an integer strictly between p0 and
    p0 + dp; returns the new count."""
    if dp == 0.0:
        return n
    lo, hi = min(p0, p0 + dp), max(p0, p0 + dp)
    k = math.floor(lo) + 1.0
    while k < hi:
        out[n] = (k - p0) / dp
        n += 1
        k += 1.0
    return n


@njit(cache=True)
def _crossings(u0: float, du: float, v0: float, dv: float) -> np.ndarray:
    """Sorted segment parameters in [0, 1]: 0, 1 and every t where u0 + t du or v0 + t dv is
    an integer strictly between the segment's ends."""
    ts = np.empty(int(abs(du)) + int(abs(dv)) + 4)
    ts[0], ts[1] = 0.0, 1.0
    n = _integers_between(u0, du, ts, 2)
    n = _integers_between(v0, dv, ts, n)
    return np.sort(ts[:n])


@njit(cache=True)
def _interp(dem, i, j, u, v):
    """The bilinear interpolant of quad (col i, row j) at grid point (u, v), metres."""
    fu = u - i
    fv = v - j
    return (dem[j, i] * (1.0 - fu) * (1.0 - fv) + dem[j, i + 1] * fu * (1.0 - fv)
            + dem[j + 1, i] * (1.0 - fu) * fv + dem[j + 1, i + 1] * fu * fv)  # fmt: skip


@njit(cache=True)
def _gap(dem, i, j, u0, v0, du, dv, t, eye, zt, drop):
    """Terrain (quad i, j; lowered by t^2 ``drop``) minus segment height at parameter t."""
    return _interp(dem, i, j, u0 + t * du, v0 + t * dv) - t * t * drop - (eye + t * (zt - eye))


@njit(cache=True)
def segment_clear(dem, u0, v0, eye, col, row, a, e, th, inv2r):
    """Is cell (col, row) visible from grid point (u0, v0) at elevation ``eye`` (see module)?"""
    h, w = dem.shape
    zc = dem[row, col]
    if zc != zc:
        return False
    du = col - u0
    dv = row - v0
    drop = ((du * a) ** 2 + (dv * e) ** 2) * inv2r  # curvature drop at the target, metres
    zt = zc + th - drop
    ts = _crossings(u0, du, v0, dv)
    for k in range(ts.size - 1):
        ta, tb = ts[k], ts[k + 1]
        if not tb > ta:
            continue
        tm = 0.5 * (ta + tb)
        um, vm = u0 + tm * du, v0 + tm * dv
        if not (0.0 <= um <= w - 1 and 0.0 <= vm <= h - 1):
            continue  # off the DEM: nothing to block
        i = min(math.floor(um), w - 2)
        j = min(math.floor(vm), h - 2)
        corners = dem[j, i] + dem[j, i + 1] + dem[j + 1, i] + dem[j + 1, i + 1]
        if corners != corners:
            continue  # a nodata corner: the quad never blocks
        ga = _gap(dem, i, j, u0, v0, du, dv, ta, eye, zt, drop)
        gm = _gap(dem, i, j, u0, v0, du, dv, tm, eye, zt, drop)
        gb = _gap(dem, i, j, u0, v0, du, dv, tb, eye, zt, drop)
        # the parabola through the three samples, in s = (t - tm) / ((tb - ta) / 2) in [-1, 1]:
        # gm + c1 s + c2 s^2; an interior maximum only when it opens downwards
        c1 = 0.5 * (gb - ga)
        c2 = 0.5 * (ga + gb) - gm
        best = max(ga, gb)
        if c2 < 0.0 and abs(c1) < -2.0 * c2:
            best = max(best, gm - c1 * c1 / (4.0 * c2))
        if best > TOL_M:
            return False
    return True


@njit(cache=True, parallel=True)
def _reference(dem, u0, v0, eye, a, e, th, inv2r, rows, cols):
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
    cols) only: then a 1-D array in their order). Observer at grid (u0, v0), eye in metres;
    ``planet_radius`` 0 = no curvature."""
    dem = np.ascontiguousarray(dem, dtype=np.float64)
    inv2r = 0.0 if not planet_radius else 0.5 / planet_radius
    u0, v0 = float(u0), float(v0)
    if cells is not None:
        rows, cols = (np.ascontiguousarray(c, dtype=np.int64) for c in cells)
        return _reference(dem, u0, v0, eye, a, e, th, inv2r, rows, cols)
    h, w = dem.shape
    rr, cc = np.mgrid[0:h, 0:w]
    d2 = ((cc - u0) * a) ** 2 + ((rr - v0) * e) ** 2
    sel = d2 <= radius * radius
    out = np.zeros((h, w), np.uint8)
    out[sel] = _reference(dem, u0, v0, eye, a, e, th, inv2r, rr[sel], cc[sel])
    return out


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = a.astype(bool), b.astype(bool)
    union = (a | b).sum()
    return 1.0 if union == 0 else float((a & b).sum() / union)
