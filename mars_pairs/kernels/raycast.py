"""Numba ray casting onto a DEM window: first terrain hit of each ray.

Frames and units: the DEM window's projected map frame. Ray origins and hits are (x, y, z) with
x, y in map units (~metres) and z metres of elevation; directions are unit vectors in that frame
(z up). Ranges are metres along the ray. Terrain is the bilinear surface through the cell
centres, lowered by d^2 / (2R) at horizontal distance d from the observer (curvature).

Each ray marches with a horizontal step of half a cell, jumping over 64x64- and 8x8-cell
blocks whose maximum elevation lies below the ray (block maxima computed on first visit), and
refines the first above -> below crossing with Illinois regula falsi (exact for planar terrain).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

from mars_pairs.kernels.viewshed import MARS_RADIUS_M, as_grid, bilinear

_BLOCKS = (64, 8)  # two levels of max-elevation blocks (cells), coarse first
_REFINE_ITERS = 40
_SKIP_EPS = 1e-6  # metres past a block edge after a jump
_SKIP_MIN_GAP_CELLS = 1.0  # try block jumps only this many cells above the ground


@njit(cache=True)
def _block_max(dem: np.ndarray, b: int, bu: int, bv: int) -> float:
    """Max elevation of b x b block (bu, bv) incl. the next row/column (+inf if it has NaN)."""
    h, w = dem.shape
    m = -np.inf
    for r in range(bv * b, min(h, (bv + 1) * b + 1)):
        for c in range(bu * b, min(w, (bu + 1) * b + 1)):
            z = dem[r, c]
            if z != z:
                return np.inf
            m = max(m, z)
    return m


@njit(cache=True)
def _cached_block_max(dem, cache, b, bu, bv):
    """Block max from ``cache`` (NaN = not yet computed; threads may race benignly)."""
    m = cache[bv, bu]
    if m != m:
        m = _block_max(dem, b, bu, bv)
        cache[bv, bu] = m
    return m


@njit(cache=True)
def _gap(dem, t, o, d, c, a, f, e, obs_x, obs_y, inv2r):
    """Ray height above the curvature-lowered terrain at ray parameter t (NaN off-grid)."""
    x = o[0] + t * d[0]
    y = o[1] + t * d[1]
    u = (x - c) / a - 0.5
    v = (y - f) / e - 0.5
    h, w = dem.shape
    c0 = math.floor(u)
    r0 = math.floor(v)
    if 0 <= c0 < w - 1 and 0 <= r0 < h - 1:
        fu = u - c0
        fv = v - r0
        top = dem[r0, c0] + fu * (dem[r0, c0 + 1] - dem[r0, c0])
        bot = dem[r0 + 1, c0] + fu * (dem[r0 + 1, c0 + 1] - dem[r0 + 1, c0])
        z = top + fv * (bot - top)
        if z != z:  # nodata next to the point: weights of zero must not poison it
            z = bilinear(dem, u, v)
    else:
        z = bilinear(dem, u, v)
    ddx = x - obs_x
    ddy = y - obs_y
    return o[2] + t * d[2] - (z - (ddx * ddx + ddy * ddy) * inv2r)


@njit(cache=True)
def _refine(dem, ta, ga, tb, gb, o, d, c, a, f, e, obs_x, obs_y, inv2r):
    """Ray parameter of the crossing in [ta, tb] (ga > 0 >= gb), Illinois regula falsi."""
    side = 0
    for _ in range(_REFINE_ITERS):
        if tb - ta < 1e-9:
            break
        tm = tb - gb * (tb - ta) / (gb - ga)
        if not (ta < tm < tb):
            tm = 0.5 * (ta + tb)
        gm = _gap(dem, tm, o, d, c, a, f, e, obs_x, obs_y, inv2r)
        if gm != gm:
            tm = 0.5 * (ta + tb)
            gm = _gap(dem, tm, o, d, c, a, f, e, obs_x, obs_y, inv2r)
            if gm != gm:
                break
        if abs(gm) < 1e-9:
            return tm
        if gm > 0:
            ta, ga = tm, gm
            if side == 1:
                gb *= 0.5
            side = 1
        else:
            tb, gb = tm, gm
            if side == -1:
                ga *= 0.5
            side = -1
    return tb - gb * (tb - ta) / (gb - ga) if gb != ga else tb


@njit(cache=True)
def _block_exit(u, v, du, dv, b):
    """Ray-parameter increment to leave the b x b block containing grid point (u, v)."""
    bu = math.floor(u / b)
    bv = math.floor(v / b)
    tu = np.inf
    tv = np.inf
    if du > 0:
        tu = ((bu + 1) * b - u) / du
    elif du < 0:
        tu = (bu * b - u) / du
    if dv > 0:
        tv = ((bv + 1) * b - v) / dv
    elif dv < 0:
        tv = (bv * b - v) / dv
    return min(tu, tv)


@njit(cache=True)
def _skip_to(dem, cache0, cache1, t, z, u, v, du, dv, dz):
    """Ray parameter past the largest block (coarse, else fine) whose max stays under the ray
    across it; ``t`` when none does (cheap when the ray is below the fine block's max)."""
    b0, b1 = _BLOCKS
    bu = math.floor(u / b1)
    bv = math.floor(v / b1)
    if bu < 0 or bv < 0 or bu >= cache1.shape[1] or bv >= cache1.shape[0]:
        return t
    m1 = _cached_block_max(dem, cache1, b1, bu, bv)
    if not z > m1:
        return t
    cu = math.floor(u / b0)
    cv = math.floor(v / b0)
    if z > _cached_block_max(dem, cache0, b0, cu, cv):
        tx = _block_exit(u, v, du, dv, b0)
        if z + tx * dz > cache0[cv, cu]:
            return t + tx + _SKIP_EPS
    tx = _block_exit(u, v, du, dv, b1)
    if z + tx * dz > m1:
        return t + tx + _SKIP_EPS
    return t


@njit(cache=True)
def _cast_one(dem, cache0, cache1, o, d, max_range, step_h, c, a, f, e, obs_x, obs_y, inv2r):
    """Ray parameter (metres) of the first terrain hit of one ray, NaN when none."""
    hor = math.sqrt(d[0] * d[0] + d[1] * d[1])
    dt = min(step_h / hor, max_range) if hor > 1e-12 else max_range
    du = d[0] / a  # grid cells per metre of ray
    dv = d[1] / e
    skip_gap = _SKIP_MIN_GAP_CELLS * 2.0 * step_h
    t = 0.0
    g = _gap(dem, 0.0, o, d, c, a, f, e, obs_x, obs_y, inv2r)
    if not g > 0.0:
        return np.nan
    while t < max_range:
        u = (o[0] + t * d[0] - c) / a - 0.5
        v = (o[1] + t * d[1] - f) / e - 0.5
        t_next = t + dt
        if g > skip_gap:  # only rays well above the ground can clear a whole block
            t_next = max(t_next, _skip_to(dem, cache0, cache1, t, o[2] + t * d[2], u, v, du, dv,
                                          d[2]))  # fmt: skip
        t_next = min(t_next, max_range)
        g_next = _gap(dem, t_next, o, d, c, a, f, e, obs_x, obs_y, inv2r)
        if g_next != g_next:
            return np.nan
        if g_next <= 0.0:
            return _refine(dem, t, g, t_next, g_next, o, d, c, a, f, e, obs_x, obs_y, inv2r)
        t, g = t_next, g_next
    return np.nan


@njit(cache=True, parallel=True)
def _cast_kernel(dem, origins, dirs, max_range, c, a, f, e, obs_x, obs_y, inv2r):
    """(hits (N, 3), ranges (N,)) for every ray; NaN rows for rays without a hit."""
    n = origins.shape[0]
    hits = np.full((n, 3), np.nan)
    ranges = np.full(n, np.nan)
    h, w = dem.shape
    b0, b1 = _BLOCKS
    cache0 = np.full(((h + b0 - 1) // b0, (w + b0 - 1) // b0), np.nan)
    cache1 = np.full(((h + b1 - 1) // b1, (w + b1 - 1) // b1), np.nan)
    step_h = 0.5 * min(abs(a), abs(e))
    for i in prange(n):
        o = origins[i]
        d = dirs[i]
        t = _cast_one(dem, cache0, cache1, o, d, max_range, step_h, c, a, f, e, obs_x, obs_y, inv2r)
        if t == t:
            ranges[i] = t
            for j in range(3):
                hits[i, j] = o[j] + t * d[j]
    return hits, ranges


def cast_rays(
    origins: Any,
    directions: Any,
    window: Any,
    *,
    max_range: float,
    observer_xy: tuple[float, float] | None = None,
    planet_radius: float = MARS_RADIUS_M,
    transform: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """First terrain hit of each ray over a DEM window.

    ``origins`` (N, 3) and ``directions`` (N, 3; normalised here) in the window's map frame
    (x, y map units, z metres, z up). ``window``: a ``DemWindow``, (array, transform) pair, or
    array with ``transform=``. ``max_range``: metres along the ray. The terrain at horizontal
    distance d from ``observer_xy`` (default: the first origin's x, y) is lowered by
    d^2 / (2 ``planet_radius``); 0 disables it. Returns (hits (N, 3), ranges (N,)), NaN where a
    ray hits nothing: it goes to the sky, leaves the window, meets nodata, exceeds
    ``max_range``, or starts below the surface.
    """
    dem, tr = as_grid(window, transform)
    o = np.ascontiguousarray(np.asarray(origins, dtype=np.float64).reshape(-1, 3))
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"origins {o.shape} and directions {d.shape} differ in shape")
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.ascontiguousarray(d / norm)
    if not (max_range > 0):
        raise ValueError(f"max_range must be positive, got {max_range}")
    if observer_xy is None:
        observer_xy = (o[0, 0], o[0, 1]) if len(o) else (0.0, 0.0)
    inv2r = 0.0 if not planet_radius or not math.isfinite(planet_radius) else 0.5 / planet_radius
    if len(o) == 0:
        return np.empty((0, 3)), np.empty(0)
    return _cast_kernel(
        dem, o, d, float(max_range), float(tr.c), float(tr.a), float(tr.f), float(tr.e),
        float(observer_xy[0]), float(observer_xy[1]), inv2r,
    )  # fmt: skip
