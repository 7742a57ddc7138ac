"""Numba ray casting onto a DEM window: first terrain hit of each ray.

Frames and units: the DEM window's projected map frame. Ray origins and hits are (x, y, z) with
x, y in map units (~metres) and z metres of elevation; directions are unit vectors in that frame
(z up). Ranges are metres along the ray. Terrain is the bilinear surface through the cell
centres, lowered by d^2 / (2R) at horizontal distance d from the observer (curvature).

Traversal: a maximum mipmap (Tevs et al. 2008). Level 0 is the grid of *quads* between four
neighbouring cell centres; level k holds the maximum elevation of 2^k x 2^k quads (+inf where
any corner is nodata). A ray climbs one level after clearing a block (its lowest point over
the block's span stays above the block maximum minus the smallest curvature drop there) and
descends one level otherwise. In a level-0 quad the ray height minus the bilinear, curvature-
lowered terrain is a quadratic in the ray parameter, solved exactly for its first root (exact
for planar terrain and for the curvature drop). The pyramid can be built once per DEM window
with ``max_pyramid`` and passed to every ``cast_rays`` call on that window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit, prange
from numpy.typing import ArrayLike, NDArray

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.kernels.grid import Transform, as_grid, bilinear

_MAX_LEVEL = 9  # coarsest pyramid blocks: 512 x 512 quads
_BASE = 2  # finest stored level (4 x 4 quads); below it rays walk the quads themselves
_NUDGE = 1e-7  # cells: block lookups look this far ahead along the ray (progress at edges)
_CHUNK = 32  # consecutive rays per work item
_SCATTER = 7919  # prime stride that scatters the work items over the threads

Dem = NDArray[np.float32]  # the DEM window (``as_grid``), its pyramid levels, row scratch
Index = NDArray[np.int64]  # pyramid offsets (levels + 1,) and dims (levels, 2)
Vectors = NDArray[np.float64]  # ray origins, directions and hits, (3,) or (N, 3); ranges (N,)


@dataclass(frozen=True)
class MaxPyramid:
    """Maximum mipmap of one DEM window (see the module docstring); build with ``max_pyramid``.

    ``dem``: the float32 window it was built from; ``data``: levels 1.. raveled one after the
    other; ``offsets[k]`` / ``dims[k]`` = start and (rows, cols) of level k (level 0 = quads).
    """

    dem: Dem
    data: Dem
    offsets: Index
    dims: Index

    @property
    def n_levels(self) -> int:
        """Coarsest level stored (0 when the window has no level above the quads)."""
        return len(self.dims) - 1


@njit(cache=True)
def _rows_max(dem: Dem, r0: int, r1: int, tmp: Dem, poison: Dem) -> None:
    """Column-wise max of rows r0..r1-1 into ``tmp``; ``poison`` turns NaN under NaN/inf."""
    w = dem.shape[1]
    for r in range(r0, r1):
        row = dem[r]
        for cc in range(w):
            z = row[cc]
            m = tmp[cc]
            tmp[cc] = z if z > m else m
            poison[cc] += z * np.float32(0.0)


@njit(cache=True, parallel=True)
def _pyramid_kernel(dem: Dem, n_levels: int) -> tuple[Dem, Index, Index]:
    """(data, offsets, dims) of the max pyramid of ``dem``: levels _BASE..n_levels stored
    (dims/offsets rows for the levels below _BASE are placeholders)."""
    h, w = dem.shape
    dims = np.zeros((n_levels + 1, 2), dtype=np.int64)
    offsets = np.zeros(n_levels + 2, dtype=np.int64)
    dims[0, 0] = h - 1
    dims[0, 1] = w - 1
    for k in range(1, n_levels + 1):
        dims[k, 0] = (dims[k - 1, 0] + 1) // 2
        dims[k, 1] = (dims[k - 1, 1] + 1) // 2
        offsets[k + 1] = offsets[k] + (dims[k, 0] * dims[k, 1] if k >= _BASE else 0)
    data = np.empty(offsets[n_levels + 1], dtype=np.float32)
    if n_levels < _BASE:
        return data, offsets, dims
    sb = 1 << _BASE
    hb, wb = dims[_BASE, 0], dims[_BASE, 1]
    dst = offsets[_BASE]
    for j in prange(hb):  # base level: sb x sb quads = (sb + 1)^2 cell centres, row-major
        tmp = dem[j * sb].copy()
        poison = np.zeros(w, dtype=np.float32)  # NaN where a column holds NaN (or inf)
        _rows_max(dem, j * sb, min(j * sb + sb + 1, h), tmp, poison)
        bad = False
        for cc in range(w):
            bad |= poison[cc] != 0.0
        for i in range(wb):
            c0 = i * sb
            m = tmp[c0]
            for cc in range(c0 + 1, min(c0 + sb + 1, w)):
                z = tmp[cc]
                m = z if z > m else m
            if bad:
                for cc in range(c0, min(c0 + sb + 1, w)):
                    if poison[cc] != 0.0:
                        m = np.inf
            data[dst + j * wb + i] = m
    for k in range(_BASE + 1, n_levels + 1):  # serial: small, and each parallel region
        hk, wk = dims[k, 0], dims[k, 1]  # waits for a descheduled thread on a busy machine
        hp, wp = dims[k - 1, 0], dims[k - 1, 1]
        src = offsets[k - 1]
        dst = offsets[k]
        for j in range(hk):
            for i in range(wk):
                m = data[src + 2 * j * wp + 2 * i]
                if 2 * i + 1 < wp:
                    m = max(m, data[src + 2 * j * wp + 2 * i + 1])
                if 2 * j + 1 < hp:
                    m = max(m, data[src + (2 * j + 1) * wp + 2 * i])
                    if 2 * i + 1 < wp:
                        m = max(m, data[src + (2 * j + 1) * wp + 2 * i + 1])
                data[dst + j * wk + i] = m
    return data, offsets, dims


def max_pyramid(window: Any, transform: Transform | None = None) -> MaxPyramid:
    """Maximum mipmap of a DEM window (``DemWindow``, (array, transform) or array), to pass as
    ``cast_rays(..., pyramid=...)`` when casting several ray sets over the same window."""
    if isinstance(window, np.ndarray) and transform is None:
        dem = np.ascontiguousarray(window, dtype=np.float32)
        if dem.ndim != 2:
            raise ArgumentError(f"DEM window must be 2-D, got shape {dem.shape}")
    else:
        dem, _ = as_grid(window, transform)
    h, w = dem.shape
    n = max(h - 1, w - 1, 1)
    n_levels = 0 if min(h, w) < 2 else min(_MAX_LEVEL, max(_BASE, math.ceil(math.log2(n))))
    data, offsets, dims = _pyramid_kernel(dem, n_levels)
    return MaxPyramid(dem, data, offsets, dims)


@njit(cache=True, inline="always")
def _gap(
    dem: Dem, t: float, o: Vectors, d: Vectors, c: float, a: float, f: float, e: float,
    obs_x: float, obs_y: float, inv2r: float,
) -> float:  # fmt: skip
    """Ray height above the curvature-lowered terrain at ray parameter t (NaN off-grid)."""
    x = o[0] + t * d[0]
    y = o[1] + t * d[1]
    z = bilinear(dem, (x - c) / a - 0.5, (y - f) / e - 0.5)
    ddx = x - obs_x
    ddy = y - obs_y
    gap: float = o[2] + t * d[2] - (z - (ddx * ddx + ddy * ddy) * inv2r)
    return gap


@njit(cache=True, inline="always")
def _quad_hit(
    dem: Dem, bu: int, bv: int, ts: float, te: float, uo: float, vo: float, du: float, dv: float,
    o: Vectors, d: Vectors, px: float, py: float, hor2: float, inv2r: float,
) -> float:  # fmt: skip
    """First ray parameter in [ts, te] where the ray meets the bilinear, curvature-lowered
    surface of quad (bu, bv); -1 when it stays above, NaN when a corner is nodata."""
    z00 = np.float64(dem[bv, bu])
    z01 = np.float64(dem[bv, bu + 1])
    z10 = np.float64(dem[bv + 1, bu])
    z11 = np.float64(dem[bv + 1, bu + 1])
    a1 = z01 - z00
    a2 = z10 - z00
    a3 = z11 - z10 - a1
    if a3 != a3:
        return np.nan
    fu = uo + du * ts - bu
    fv = vo + dv * ts - bv
    qx = px + ts * d[0]
    qy = py + ts * d[1]
    # gap(ts + s) = A s^2 + B s + C
    cc = o[2] + d[2] * ts - (z00 + fu * a1 + fv * a2 + fu * fv * a3) + (qx * qx + qy * qy) * inv2r
    if not cc > 0.0:
        return ts
    bb = d[2] - du * (a1 + fv * a3) - dv * (a2 + fu * a3) + 2.0 * inv2r * (qx * d[0] + qy * d[1])
    aa = inv2r * hor2 - du * dv * a3
    ln = te - ts
    if not (aa * ln + bb) * ln + cc <= 0.0:  # above at the exit: a dip in between?
        if not (aa > 0.0 and bb < 0.0 and -bb < 2.0 * aa * ln):
            return -1.0
        if cc - bb * bb / (4.0 * aa) > 0.0:
            return -1.0
    disc = max(bb * bb - 4.0 * aa * cc, 0.0)
    q = -0.5 * (bb + math.copysign(math.sqrt(disc), bb))
    s = cc / q if q != 0.0 else 0.0
    if not s >= 0.0:
        s = q / aa if aa != 0.0 else 0.0
    return ts + min(max(s, 0.0), ln)


@njit(cache=True, inline="always")
def _cast_one(
    dem: Dem, pyr: Dem, offs: Index, dims: Index, zmax: float, o: Vectors, d: Vectors,
    max_range: float, c: float, a: float, f: float, e: float, obs_x: float, obs_y: float,
    inv2r: float,
) -> float:  # fmt: skip
    """Ray parameter (metres) of the first terrain hit of one ray, NaN when none."""
    h, w = dem.shape
    if not _gap(dem, 0.0, o, d, c, a, f, e, obs_x, obs_y, inv2r) > 0.0:
        return np.nan
    top = dims.shape[0] - 1
    uo = (o[0] - c) / a - 0.5
    vo = (o[1] - f) / e - 0.5
    du = d[0] / a  # grid cells per metre of ray
    dv = d[1] / e
    nu = _NUDGE if du > 0 else (-_NUDGE if du < 0 else 0.0)
    nv = _NUDGE if dv > 0 else (-_NUDGE if dv < 0 else 0.0)
    px = o[0] - obs_x
    py = o[1] - obs_y
    hor2 = d[0] * d[0] + d[1] * d[1]
    t_near = -(px * d[0] + py * d[1]) / hor2 if hor2 > 0.0 else 0.0  # closest to observer
    inv_du = 1.0 / du if du != 0.0 else 0.0
    inv_dv = 1.0 / dv if dv != 0.0 else 0.0
    umax = w - 1.0
    vmax = h - 1.0
    t = 0.0
    k = 0
    while t < max_range:
        u = uo + du * t + nu
        v = vo + dv * t + nv
        if not (0.0 <= u <= umax and 0.0 <= v <= vmax):
            return np.nan
        bu = min(int(u) >> k, dims[k, 1] - 1)
        bv = min(int(v) >> k, dims[k, 0] - 1)
        t1 = np.inf
        if du > 0:
            t1 = (((bu + 1) << k) - uo) * inv_du
        elif du < 0:
            t1 = ((bu << k) - uo) * inv_du
        if dv > 0:
            t1 = min(t1, (((bv + 1) << k) - vo) * inv_dv)
        elif dv < 0:
            t1 = min(t1, ((bv << k) - vo) * inv_dv)
        te = min(t1, max_range)
        if k == 0:
            th = _quad_hit(dem, bu, bv, t, te, uo, vo, du, dv, o, d, px, py, hor2, inv2r)
            if th != -1.0:
                return th
            t = t1
            # stay on the quads while inside the same (failed) base block
            nbu = int(uo + du * t + nu) >> _BASE
            nbv = int(vo + dv * t + nv) >> _BASE
            if (nbu != bu >> _BASE or nbv != bv >> _BASE) and top >= _BASE:
                k = _BASE
            continue
        m = pyr[offs[k] + bv * dims[k, 1] + bu]
        zr = o[2] + d[2] * (te if d[2] < 0 else t)
        tc = min(max(t_near, t), te)
        qx = px + tc * d[0]
        qy = py + tc * d[1]
        if zr > m - (qx * qx + qy * qy) * inv2r:
            if d[2] >= 0.0 and zr > zmax:
                return np.nan  # rising above the highest point of the window
            t = t1
            k = min(k + 1, top)
        else:
            k = k - 1 if k > _BASE else 0
    return np.nan


@njit(cache=True, parallel=True)
def _cast_kernel(
    dem: Dem, pyr: Dem, offs: Index, dims: Index, origins: Vectors, dirs: Vectors,
    max_range: float, c: float, a: float, f: float, e: float, obs_x: float, obs_y: float,
    inv2r: float,
) -> tuple[Vectors, Vectors]:  # fmt: skip
    """(hits (N, 3), ranges (N,)) for every ray; NaN rows for rays without a hit.

    Rays go out in blocks of ``_CHUNK`` consecutive rays (coherent: neighbouring pixels), the
    blocks in a scattered order (block j -> j * _SCATTER mod n_blocks, a permutation) so that
    each thread's share samples the whole image: cheap near-ground and costly grazing rays.
    """
    n = origins.shape[0]
    hits = np.full((n, 3), np.nan)
    ranges = np.full(n, np.nan)
    n_blocks = (n + _CHUNK - 1) // _CHUNK
    top = dims.shape[0] - 1
    zmax = np.inf
    if top >= _BASE:
        zmax = pyr[offs[top] : offs[top] + dims[top, 0] * dims[top, 1]].max()
    scatter = _SCATTER if n_blocks % _SCATTER != 0 else 1
    for j in prange(n_blocks):
        b = (j * scatter) % n_blocks
        for i in range(b * _CHUNK, min(n, (b + 1) * _CHUNK)):
            o = origins[i]
            d = dirs[i]
            t = _cast_one(
                dem, pyr, offs, dims, zmax, o, d, max_range, c, a, f, e, obs_x, obs_y, inv2r
            )
            if t == t:
                ranges[i] = t
                for k in range(3):
                    hits[i, k] = o[k] + t * d[k]
    return hits, ranges


def cast_rays(
    origins: ArrayLike,
    directions: ArrayLike,
    window: Any,
    *,
    max_range: float,
    observer_xy: tuple[float, float] | None = None,
    planet_radius: float = MARS_RADIUS_M,
    transform: Transform | None = None,
    pyramid: MaxPyramid | None = None,
) -> tuple[Vectors, Vectors]:
    """First terrain hit of each ray over a DEM window.

    ``origins`` (N, 3) and ``directions`` (N, 3; normalised here) in the window's map frame
    (x, y map units, z metres, z up). ``window``: a ``DemWindow``, (array, transform) pair, or
    array with ``transform=``. ``max_range``: metres along the ray. The terrain at horizontal
    distance d from ``observer_xy`` (default: the first origin's x, y) is lowered by
    d^2 / (2 ``planet_radius``); 0 disables it. ``pyramid``: ``max_pyramid(window)``, built
    once and reused across calls on the same window (built here when None). Returns
    (hits (N, 3), ranges (N,)), NaN where a ray hits nothing: it goes to the sky, leaves the
    window, meets nodata, exceeds ``max_range``, or starts below the surface.
    """
    dem, tr = as_grid(window, transform)
    o = np.ascontiguousarray(np.asarray(origins, dtype=np.float64).reshape(-1, 3))
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ArgumentError(f"origins {o.shape} and directions {d.shape} differ in shape")
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.ascontiguousarray(d / norm)
    if not (max_range > 0):
        raise ArgumentError(f"max_range must be positive, got {max_range}")
    if observer_xy is None:
        observer_xy = (o[0, 0], o[0, 1]) if len(o) else (0.0, 0.0)
    inv2r = 0.0 if not planet_radius or not math.isfinite(planet_radius) else 0.5 / planet_radius
    if len(o) == 0 or min(dem.shape) < 2:
        return np.full((len(o), 3), np.nan), np.full(len(o), np.nan)
    if pyramid is None:
        pyramid = max_pyramid(dem)
    elif pyramid.dem.shape != dem.shape:
        raise ArgumentError(f"pyramid built for a {pyramid.dem.shape} window, not {dem.shape}")
    return _cast_kernel(
        dem, pyramid.data, pyramid.offsets, pyramid.dims, o, d, float(max_range), float(tr.c),
        float(tr.a), float(tr.f), float(tr.e), float(observer_xy[0]), float(observer_xy[1]),
        inv2r,
    )  # fmt: skip
