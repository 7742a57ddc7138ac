"""Numba viewshed on a DEM window: radial sweep with a running maximum slope.

Frames and units: the DEM window grid of a projected raster CRS. x, y are map units (taken as
metres, square-ish pixels), elevations metres, azimuth degrees clockwise from grid north
(+y), elevation angles degrees above the horizontal. Grid coordinates (u, v) = fractional
(col, row) with cell centres at integers: x = c + a (u + 0.5), y = f + e (v + 0.5).

Visibility (the definition the tests check with an independent brute force): the terrain is
the bilinear surface through the cell centres, lowered by d^2 / (2R) at horizontal distance d
(curvature; R = 0 disables it). A cell is visible when the straight segment from the eye to its
centre's surface point (+ target height, lowered the same way) stays on or above that terrain
everywhere along it, and the cell lies inside the radius and the azimuth and elevation bands.

Algorithm: an "R2"-style sweep, made exact where it decides. Rays leave the observer's cell
towards the perimeter of the radius box, step one cell along their major axis and sample the
terrain where they cross each grid line (linear interpolation between the two straddling cells).
Each cell is *owned* by exactly one ray, the one passing closest to its centre (integer test, so
no two threads write a cell). A sample's slope (z - eye) / distance carries an error bar:
the terrain gradient across the line times how far a sight line to an owned cell may run beside
the ray, so the running maxima of (slope - bar) and (slope + bar), [lo, hi], bracket the horizon
of the exact sight line. A cell whose slope is below lo is hidden. Otherwise the sight line is
tested exactly (cut at every grid line it crosses; in each quad the bilinear terrain along it is
a quadratic, maximised exactly) from the grid line before the cell on, where it runs over the
cell's own slope, and, when its slope is below the horizon's upper bound, near every ray sample
whose bar reaches it. The bars are an
estimate, not a proof: against the exact reference the visible-set IoU is >= 0.998 on fractal
and real terrain (tests/kernels/test_viewshed_exact.py). A ray stops once its horizon rises above
the elevation band. In wedge mode only rays inside the azimuth band (and, near the observer, rays
close to it) are marched. The full circle marches a tree of rays: 16 per side of the box at the
observer, doubling wherever their spacing reaches a cell, each new ray starting from its
neighbour's horizon (error bars one cell wider), so the steps near the observer are not repeated
by every ray.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from affine import Affine
from llvmlite import ir  # type: ignore[import-untyped]  # llvmlite ships no types
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic, overload
from numpy.typing import NDArray

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.kernels.grid import Transform, as_grid, bilinear, xy_to_uv

# no 'nnan'/'ninf': NaN nodata and +-inf band limits must compare exactly
_SAFE_FM = {"arcp", "contract"}
_AZ_EPS = 1e-9
# planned ray steps below which one thread runs the job: the full circle at 500 m on a 1 m DEM
# (6 * 501 * 501 steps) takes 13.6 ms on two threads against 22.4 ms on one (idle 2 cores)
_PARALLEL_MIN_STEPS = 1_000_000
_HEAVY_STEPS = 8  # rays with at most this many steps go to the cheap second pass
_ERR_GAIN = 0.5  # safety factor on the sweep's horizon error estimate
# the tree's error bars are narrowed: with full-width bars the exact checks cost 1.15x the run
# time for an IoU 0.9997 instead of 0.9985 (fractal, 1000 m); wedges keep the full width
_TREE_BARS = 0.5
_TREE_MIN_RAYS = 16  # rays per side at the root of the full circle's tree of rays
_CHUNK = 64  # rays per parallel work item (one scratch buffer each)
_AHEAD = 32
_TOL_M = 1e-6  # metres the terrain may rise above a sight line (rounding at the target)

Dem = NDArray[np.float32]  # the DEM window (``as_grid``), or its raveled ``flat`` view
Scratch = NDArray[np.float64]  # per-ray horizon samples (``s_hi``) and their stack
Lines = NDArray[np.int64]  # grid lines of the kept samples (``s_j``), ray indices, step counts
Mask = NDArray[np.uint8]  # 1 = visible
# (h, w, ic, ir, u0, v0, a, e, eye, radius, inv2r, th, tmin, tmax, az_on, az_min, az_w):
# the window and observer every ray of one call shares (``_viewshed_kernel``)
Geo = tuple[
    int, int, int, int, float, float, float, float, float, float, float, float, float, float,
    bool, float, float,
]  # fmt: skip
# (q, rem, hi, lo, hi1, lo1, n_c): one ray's stepping state (``_march``)
RayState = tuple[int, int, float, float, float, float, int]


def _prefetch(arr: Dem, idx: int) -> None:
    """Hint the CPU to fetch the cache line of ``arr[idx]`` (1-d, C order) for reading: no
    effect on any result, no bounds check (a prefetch never faults). Plain Python: nothing."""


@overload(_prefetch, inline="always")
def _prefetch_jit(arr: Any, idx: Any) -> Any:
    """``_prefetch`` in compiled code: LLVM's prefetch intrinsic."""

    def impl(arr: Any, idx: Any) -> Any:  # (numba: the overload's very signature)
        _prefetch_line(arr, idx)  # type: ignore[call-arg]  # numba passes the typing context

    return impl


@intrinsic
def _prefetch_line(typingctx: Any, arr: Any, idx: Any) -> Any:
    """llvm.prefetch of ``arr[idx]``'s address (read, keep in every cache level)."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> None:
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [args[1]])
        i8p = builder.bitcast(ptr, ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(  # type: ignore[no-untyped-call]  # numba's untyped
            builder.module, fnty, "llvm.prefetch.p0"
        )
        builder.call(fn, [i8p, i32(0), i32(3), i32(1)])  # read, keep in all cache levels

    return types.void(arr, idx), codegen


# ---------------------------------------------------------------------------------------------
# kernel
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _decode_ray(r: int, big_d: int) -> tuple[bool, int, int]:
    """Ray index -> (u-major?, direction sign, perimeter offset k)."""
    n_u = 2 * big_d + 1
    n_v = 2 * big_d - 1
    if r < n_u:
        return True, 1, r - big_d
    if r < 2 * n_u:
        return True, -1, r - n_u - big_d
    if r < 2 * n_u + n_v:
        return False, 1, r - 2 * n_u - (big_d - 1)
    return False, -1, r - 2 * n_u - n_v - (big_d - 1)


@njit(cache=True)
def _in_az(cx: float, cy: float, az_min: float, az_width: float) -> bool:
    """Is the map offset (cx east, cy north) inside the azimuth band?"""
    az = math.degrees(math.atan2(cx, cy))
    rel = (az - az_min) % 360.0
    # 1e-9 deg tolerance: degrees(atan2) may land an ulp below a band edge (179.99999999999997)
    return rel <= az_width + _AZ_EPS or rel >= 360.0 - _AZ_EPS


@njit(cache=True, fastmath=_SAFE_FM)
def _line_z(flat: Dem, major: int, st_maj: int, st_min: int, n_min: int, mn: float) -> float:
    """Terrain (metres) at minor coordinate ``mn`` on grid line ``major`` (linear along the
    line); NaN when off the grid or nodata."""
    m0 = math.floor(mn)
    fm = mn - m0
    if m0 < 0 or m0 > n_min - 1 or (m0 == n_min - 1 and fm > 0.0):
        return np.nan
    idx = major * st_maj + m0 * st_min
    z: float = flat[idx] if fm == 0.0 else flat[idx] * (1.0 - fm) + flat[idx + st_min] * fm
    return z


@njit(cache=True, fastmath=_SAFE_FM)
def _quad_rise(
    flat: Dem, w: int, i: int, j: int, u0: float, v0: float, du: float, dv: float, ta: float,
    tb: float, q2c: float, eye: float, slope: float,
) -> float:  # fmt: skip
    """Max over t in [ta, tb] of (bilinear terrain - curvature drop - sight line), metres, in
    the quad with top-left cell centre (col i, row j); -inf when a corner is nodata."""
    idx = j * w + i
    z00 = flat[idx]
    z10 = flat[idx + 1]
    z01 = flat[idx + w]
    z11 = flat[idx + w + 1]
    if not (z00 == z00 and z10 == z10 and z01 == z01 and z11 == z11):
        return -np.inf
    fu0 = u0 - i
    fv0 = v0 - j
    ca = z10 - z00
    cb = z01 - z00
    cc = z00 - z10 - z01 + z11
    # along the line the bilinear surface is a quadratic in t (exact, not sampled)
    q2 = cc * du * dv - q2c
    q1 = ca * du + cb * dv + cc * (fu0 * dv + fv0 * du) - slope
    q0 = z00 + ca * fu0 + cb * fv0 + cc * fu0 * fv0 - eye
    best: float = max(q0 + ta * (q1 + ta * q2), q0 + tb * (q1 + tb * q2))
    if q2 < 0.0:
        tv = -q1 / (2.0 * q2)
        if ta < tv < tb:
            best = max(best, q0 + tv * (q1 + tv * q2))
    return best


@njit(cache=True, fastmath=_SAFE_FM)
def _segment_clear(
    flat: Dem, h: int, w: int, u0: float, v0: float, col: int, row: int, a: float, e: float,
    eye: float, zt: float, inv2r: float, t0: float, t1: float,
) -> bool:  # fmt: skip
    """Does the sight line from grid (u0, v0) at elevation ``eye`` to the surface point of
    cell (col, row) at ``zt`` (curvature-lowered, metres) stay on or above the bilinear,
    curvature-lowered terrain for t in [t0, t1]? Exact: the line is cut at every grid line it
    crosses and each piece's quadratic is maximised. Nodata quads never block."""
    du = col - u0
    dv = row - v0
    dc2 = (du * a) ** 2 + (dv * e) ** 2
    q2c = dc2 * inv2r
    slope = zt - eye
    ua = u0 + t0 * du
    va = v0 + t0 * dv
    if du > 0.0:
        tu = (math.floor(ua) + 1.0 - u0) / du
        su = 1.0 / du
    elif du < 0.0:
        tu = (math.ceil(ua) - 1.0 - u0) / du
        su = -1.0 / du
    else:
        tu = su = np.inf
    if dv > 0.0:
        tv = (math.floor(va) + 1.0 - v0) / dv
        sv = 1.0 / dv
    elif dv < 0.0:
        tv = (math.ceil(va) - 1.0 - v0) / dv
        sv = -1.0 / dv
    else:
        tv = sv = np.inf
    ta = t0
    while ta < t1:
        tb = min(tu, tv, t1)
        tm = 0.5 * (ta + tb)
        um = u0 + tm * du
        vm = v0 + tm * dv
        if 0.0 <= um <= w - 1 and 0.0 <= vm <= h - 1:
            i = min(int(um), w - 2)
            j = min(int(vm), h - 2)
            if _quad_rise(flat, w, i, j, u0, v0, du, dv, ta, tb, q2c, eye, slope) > _TOL_M:
                return False
        if tb == tu:
            tu += su
        if tb == tv:
            tv += sv
        ta = tb
    return True


@njit(cache=True)
def _compact(s_hi: Scratch, s_j: Lines, n_c: int, lo: float) -> int:
    """Drop the kept samples whose upper bound lies below the horizon's lower bound ``lo``
    (no sight line tested from then on runs below ``lo``); order kept; the new count."""
    n = 0
    for i in range(n_c):
        if s_hi[i] >= lo:
            s_hi[n] = s_hi[i]
            s_j[n] = s_j[i]
            n += 1
    return n


@njit(cache=True, fastmath=_SAFE_FM)
def _tail_clear(
    flat: Dem, h: int, w: int, u0: float, v0: float, col: int, row: int, a: float, e: float,
    eye: float, zt: float, inv2r: float, dc2: float, umaj: bool, t0: float,
) -> bool:  # fmt: skip
    """``_segment_clear`` over t in [``t0``, 1], the sight line's last gap between major
    grid lines (major axis u when ``umaj``; t0 = 0 when the observer lies in the gap); ``dc2``:
    the target's squared map distance. There the line crosses at most one minor grid line: one
    quad, when the minor run across the gap is within a cell and the gap inside the grid."""
    du = col - u0
    dv = row - v0
    r = (dv if umaj else du) * (1.0 - t0)  # the minor run over the gap, cells
    ua = u0 + t0 * du
    va = v0 + t0 * dv
    if not (-1.0 <= r <= 1.0 and 0.0 <= ua <= w - 1 and 0.0 <= va <= h - 1):
        return _segment_clear(flat, h, w, u0, v0, col, row, a, e, eye, zt, inv2r, t0, 1.0)
    if umaj:
        i = col - 1 if du > 0.0 else col
        j = row - 1 if r > 0.0 else min(row, h - 2)
    else:
        j = row - 1 if dv > 0.0 else row
        i = col - 1 if r > 0.0 else min(col, w - 2)
    rise = _quad_rise(flat, w, i, j, u0, v0, du, dv, t0, 1.0, dc2 * inv2r, eye, zt - eye)
    return rise <= _TOL_M


@njit(cache=True, fastmath=_SAFE_FM)
def _march(
    flat: Dem, out: Mask, geo: Geo, umaj: bool, sgn: int, k: int, big_p: int, s0: int, s1: int,
    off_m: float, st: RayState, s_hi: Scratch, s_j: Lines,
) -> tuple[RayState, bool]:  # fmt: skip
    """March one ray over steps ``s0`` + 1 .. ``s1`` and judge every cell it owns.

    The ray leaves the observer's cell along its major axis (``umaj``: u, the column axis;
    ``sgn``: direction) with minor offset ``k`` / ``big_p`` cells per step; a cell is owned
    when this ray passes closest to its centre among the rays of resolution ``big_p``.
    ``st`` = (q, rem, hi, lo, hi1, lo1, n_c): stepping state (k s = q big_p + rem), the
    horizon interval [lo, hi] of the samples on lines up to s - 2, the sample on line s - 1 and
    the count of kept samples in ``s_hi`` / ``s_j`` (those that may still reach a sight line).
    ``off_m``: cells the sight lines to owned cells may lie beside the samples (error bars).
    Returns (state, done): done when the ray left the radius, the grid or the elevation band.
    """
    h, w, ic, ir, u0, v0, a, e, eye, radius, inv2r, th, tmin, tmax, az_on, az_min, az_w = geo
    q, rem, hi, lo, hi1, lo1, n_c = st
    if umaj:
        st_maj, st_min, n_maj, n_min = 1, w, w, h
        c_maj, c_min, o_maj, o_min, sc_maj, sc_min = ic, ir, u0, v0, a, e
    else:
        st_maj, st_min, n_maj, n_min = w, 1, h, w
        c_maj, c_min, o_maj, o_min, sc_maj, sc_min = ir, ic, v0, u0, e, a
    inv_p = 1.0 / big_p
    last = min(s1, n_maj - 1 - c_maj if sgn > 0 else c_maj)
    done = last < s1
    r2 = radius * radius
    lim = radius + 1.5 * max(abs(a), abs(e))
    lim2 = lim * lim
    o_off = abs(c_maj - o_maj)
    gain = _ERR_GAIN * off_m
    # steps whose sample and owned cell lie strictly inside the minor range: no bounds checks
    # (0 < c_min + k s / P < n_min - 1, in integers: a float bound let an exact k s = room P
    # through, and the sample's neighbour was read one line past the grid)
    if k == 0:
        s_in = last if c_min < n_min - 1 else 0
    else:
        room = (n_min - 1 - c_min) if k > 0 else c_min
        s_in = min(last, (room * big_p - 1) // abs(k))
    n_cap = 2 * n_c + 32
    # the sample _AHEAD steps on, prefetched (a ray crosses a new cache line at most steps)
    rem_a = rem + k * _AHEAD
    q_a = q + rem_a // big_p
    rem_a %= big_p
    for s in range(s0 + 1, last + 1):
        major = c_maj + sgn * s
        rem_a += k
        if rem_a >= big_p:
            rem_a -= big_p
            q_a += 1
        elif rem_a < 0:
            rem_a += big_p
            q_a -= 1
        i_a = (major + sgn * _AHEAD) * st_maj + (c_min + q_a) * st_min
        _prefetch(flat, i_a)
        _prefetch(flat, i_a + st_min)
        dmaj = (major - o_maj) * sc_maj
        dmaj2 = dmaj * dmaj
        rem += k
        if rem >= big_p:
            rem -= big_p
            q += 1
        elif rem < 0:
            rem += big_p
            q -= 1
        fm = rem * inv_p
        m = c_min + q + fm
        dmin = (m - o_min) * sc_min
        d2 = dmaj2 + dmin * dmin
        if d2 > lim2:
            done = True
            break
        # the cell nearest to the ray on this line, c_off = round(k s / P), is owned when the
        # ray is the one closest to its centre: -s <= 2 (P c_off - k s) < s
        up = 2 * rem >= big_p
        err = 2 * (big_p - rem) if up else -2 * rem
        cm = c_min + q + up
        if -s <= err < s and (s <= s_in or 0 <= cm < n_min):
            dcm = (cm - o_min) * sc_min
            dc2 = dmaj2 + dcm * dcm
            dc = math.sqrt(dc2)
            zc = flat[major * st_maj + cm * st_min] + th - dc2 * inv2r  # NaN: never visible
            vis = (dc2 <= r2) & (zc - eye >= lo * dc)
            if vis:
                sl = (zc - eye) / dc
                vis = (sl >= tmin) & (sl <= tmax)
            if vis and az_on:
                vis = _in_az(dmaj, dcm, az_min, az_w) if umaj else _in_az(dcm, dmaj, az_min, az_w)
            if vis:
                col, row = (major, cm) if umaj else (cm, major)
                inv_n = 1.0 / abs(major - o_maj)
                # exact on the last lines, where the sight line runs over the cell's own
                # slope; then exact near every sample whose error bar reaches the sight line
                t_tail = max(0.0, 1.0 - inv_n)  # from the grid line before the cell's
                vis = _tail_clear(
                    flat, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, dc2, umaj, t_tail
                )
                if vis and sl < max(hi, hi1):  # (hi1: the sample on line s - 1)
                    vis = _head_clear(
                        flat, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, sl, s_hi, s_j,
                        n_c, s - 1, o_off, inv_n, t_tail,
                    )  # fmt: skip
            out[major * st_maj + cm * st_min] = vis
        hi = max(hi, hi1)  # the sample on line s - 1 joins the horizon
        lo = max(lo, lo1)
        if n_c >= n_cap:  # (amortised: the list at least doubled since the last compaction)
            n_c = _compact(s_hi, s_j, n_c, lo)
            n_cap = 2 * n_c + 32
        if lo > tmax:  # the horizon rose above the elevation band: nothing further is seen
            done = True
            break
        if s <= s_in:  # 0 <= m < n_min - 1
            idx = major * st_maj + (c_min + q) * st_min
            z = flat[idx]
            g = flat[idx + st_min] - z
            if rem != 0:  # (a zero weight must not let a NaN neighbour poison the sample)
                z += fm * g
        else:
            z = _line_z(flat, major, st_maj, st_min, n_min, m)
            g = 0.0
        inv_d = 1.0 / math.sqrt(d2)
        sl = (z - d2 * inv2r - eye) * inv_d
        de = gain * abs(g) * inv_d
        if sl == sl:
            hi1 = sl + de if de == de else np.inf
            lo1 = sl - de if de == de else sl
        else:
            hi1 = lo1 = -np.inf
        # kept unless below the horizon, where a sample never matters again (branch-free)
        s_j[n_c] = s
        s_hi[n_c] = hi1
        n_c += hi1 >= lo
    return (q, rem, hi, lo, hi1, lo1, n_c), done


@njit(cache=True, fastmath=_SAFE_FM)
def _head_clear(
    flat: Dem, h: int, w: int, u0: float, v0: float, col: int, row: int, a: float, e: float,
    eye: float, zt: float, inv2r: float, sl: float, s_hi: Scratch, s_j: Lines, n_c: int,
    j_max: int, o_off: float, inv_n: float, t_tail: float,
) -> bool:  # fmt: skip
    """Exact test of the sight line (slope ``sl``) near every kept ray sample on lines up to
    ``j_max`` whose upper bound reaches it: between the grid lines on either side of it.
    ``o_off``: the observer's offset from its cell centre along the major axis (cells);
    ``inv_n``: 1 / the target's major distance from the observer (cells)."""
    for i in range(n_c):
        jj = s_j[i]
        if jj > j_max:
            break
        if s_hi[i] >= sl:
            ta = max(0.0, (jj - 1 - o_off) * inv_n)
            tb = min(t_tail, (jj + 1 + o_off) * inv_n)
            if ta < tb and not _segment_clear(
                flat, h, w, u0, v0, col, row, a, e, eye, zt, inv2r, ta, tb
            ):
                return False
    return True


@njit(cache=True)
def _ray_steps(
    big_d: int, big_p: int, a: float, e: float, az_on: bool, az_min: float, az_w: float,
    ratio: float,
) -> Lines:  # fmt: skip
    """Steps to march per ray: all of them in the band, a few near it, 4 elsewhere."""
    n = 8 * big_p
    steps = np.empty(n, dtype=np.int64)
    for r in range(n):
        if not az_on:
            steps[r] = big_d
            continue
        umaj, sgn, k = _decode_ray(r, big_p)
        du, dv = (sgn * big_p, k) if umaj else (k, sgn * big_p)
        az = math.degrees(math.atan2(du * a, dv * e))
        rel = (az - az_min) % 360.0
        if rel <= az_w + _AZ_EPS or rel >= 360.0 - _AZ_EPS:
            steps[r] = big_d
        else:
            off = math.radians(min(rel - az_w, 360.0 - rel))
            steps[r] = min(big_d, math.ceil(2.0 * ratio / off) + 4)
    return steps


@njit(cache=True, fastmath=_SAFE_FM)
def _flat_rays(
    flat: Dem, out: Mask, geo: Geo, rays: Lines, steps: Lines, big_p: int, s_hi: Scratch,
    s_j: Lines,
) -> None:  # fmt: skip
    """Sweep ``rays`` (indices at resolution ``big_p``), each from the observer on its own."""
    _, _, ic, ir, u0, v0 = geo[:6]
    for i in range(rays.size):
        umaj, sgn, k = _decode_ray(rays[i], big_p)
        c_maj, c_min, o_maj, o_min = (ic, ir, u0, v0) if umaj else (ir, ic, v0, u0)
        s_max = steps[rays[i]]
        off_m = max(0.5 * s_max / big_p, abs(c_min - o_min) + abs(c_maj - o_maj))
        st = (0, 0, -np.inf, -np.inf, -np.inf, -np.inf, 0)
        _march(flat, out, geo, umaj, sgn, k, big_p, 0, s_max, off_m, st, s_hi, s_j)


@njit(cache=True, fastmath=_SAFE_FM)
def _tree_ray(
    flat: Dem, out: Mask, geo: Geo, r: int, big_p: int, n_lev: int, s_max: int, off_m: float,
    s_hi: Scratch, s_j: Lines, stk_hi: Scratch, stk_j: Lines,
) -> None:  # fmt: skip
    """Sweep the tree of rays under coarse ray ``r`` (resolution ``big_p`` >> ``n_lev``).

    A ray of resolution P owns cells out to P steps; there it goes on as ray 2k of resolution
    2P and hands its horizon to the new ray 2k + 1 beside it, which starts there (its samples
    so far are its parent's, within one cell of its own sight lines: see ``off_m``).
    """
    p_c = big_p >> n_lev
    umaj, sgn, k = _decode_ray(r, p_c)
    n_stk = 0
    stk_i = np.empty((stk_hi.shape[0], 3), dtype=np.int64)  # level, k, s0
    stk_st = np.empty((stk_hi.shape[0], 7))
    lev = n_lev
    s0 = 0
    st = (0, 0, -np.inf, -np.inf, -np.inf, -np.inf, 0)
    while True:
        p_l = big_p >> lev
        s1 = s_max if lev == 0 else min(p_l, s_max)
        st, done = _march(flat, out, geo, umaj, sgn, k, p_l, s0, s1, off_m, st, s_hi, s_j)
        if not done and lev > 0 and s1 < s_max:
            q, rem, hi, lo, hi1, lo1, n_c = st
            n_c = _compact(s_hi, s_j, n_c, lo)
            # the new rays beside this one: 2k + 1, and 2k - 1 at the low end of a v side
            for kk in (2 * k + 1, 2 * k - 1):
                if kk == 2 * k + 1:
                    ok = kk <= (2 * p_l if umaj else 2 * p_l - 1)
                else:
                    ok = (not umaj) and k == -(p_l - 1)
                if not ok:
                    continue
                r2 = 2 * rem + (s1 if kk > 2 * k else -s1)
                q2 = q
                if r2 >= 2 * p_l:
                    r2 -= 2 * p_l
                    q2 += 1
                elif r2 < 0:
                    r2 += 2 * p_l
                    q2 -= 1
                stk_i[n_stk, 0] = lev - 1
                stk_i[n_stk, 1] = kk
                stk_i[n_stk, 2] = s1
                stk_st[n_stk, 0] = q2
                stk_st[n_stk, 1] = r2
                stk_st[n_stk, 2] = hi
                stk_st[n_stk, 3] = lo
                stk_st[n_stk, 4] = hi1
                stk_st[n_stk, 5] = lo1
                stk_st[n_stk, 6] = n_c
                stk_hi[n_stk, :n_c] = s_hi[:n_c]
                stk_j[n_stk, :n_c] = s_j[:n_c]
                n_stk += 1
            st = (q, 2 * rem, hi, lo, hi1, lo1, n_c)
            k = 2 * k
            lev -= 1
            s0 = s1
            continue
        if n_stk == 0:
            return
        n_stk -= 1
        lev, k, s0 = stk_i[n_stk, 0], stk_i[n_stk, 1], stk_i[n_stk, 2]
        n_c = int(stk_st[n_stk, 6])
        st = (
            int(stk_st[n_stk, 0]), int(stk_st[n_stk, 1]), stk_st[n_stk, 2], stk_st[n_stk, 3],
            stk_st[n_stk, 4], stk_st[n_stk, 5], n_c,
        )  # fmt: skip
        s_hi[:n_c] = stk_hi[n_stk, :n_c]
        s_j[:n_c] = stk_j[n_stk, :n_c]


@njit(cache=True, parallel=True)
def _tree_parallel(
    flat: Dem, out: Mask, geo: Geo, big_p: int, n_lev: int, s_max: int, off_m: float
) -> None:
    """All coarse rays' trees over the threads (each cell has one owner: no write conflicts)."""
    n_r = 8 * (big_p >> n_lev)
    for r in prange(n_r):
        s_hi = np.empty(s_max + 2)
        s_j = np.empty(s_max + 2, dtype=np.int64)
        stk_hi = np.empty((2 * n_lev + 2, s_max + 2))
        stk_j = np.empty((2 * n_lev + 2, s_max + 2), dtype=np.int64)
        _tree_ray(flat, out, geo, r, big_p, n_lev, s_max, off_m, s_hi, s_j, stk_hi, stk_j)


@njit(cache=True)
def _tree_serial(
    flat: Dem, out: Mask, geo: Geo, big_p: int, n_lev: int, s_max: int, off_m: float
) -> None:
    """All coarse rays' trees on the calling thread (small jobs)."""
    s_hi = np.empty(s_max + 2)
    s_j = np.empty(s_max + 2, dtype=np.int64)
    stk_hi = np.empty((2 * n_lev + 2, s_max + 2))
    stk_j = np.empty((2 * n_lev + 2, s_max + 2), dtype=np.int64)
    for r in range(8 * (big_p >> n_lev)):
        _tree_ray(flat, out, geo, r, big_p, n_lev, s_max, off_m, s_hi, s_j, stk_hi, stk_j)


@njit(cache=True, parallel=True)
def _flat_parallel(flat: Dem, out: Mask, geo: Geo, rays: Lines, steps: Lines, big_p: int) -> None:
    """``_flat_rays`` over the threads, in chunks of ``_CHUNK`` rays (one scratch each)."""
    n_s = steps.max() + 2
    for c in prange((rays.size + _CHUNK - 1) // _CHUNK):
        s_hi = np.empty(n_s)
        s_j = np.empty(n_s, dtype=np.int64)
        part = rays[c * _CHUNK : (c + 1) * _CHUNK]
        _flat_rays(flat, out, geo, part, steps, big_p, s_hi, s_j)


@njit(cache=True)
def _flat_serial(flat: Dem, out: Mask, geo: Geo, rays: Lines, steps: Lines, big_p: int) -> None:
    """``_flat_rays`` on the calling thread (small jobs: wedges, the short rays)."""
    n_s = (steps.max() if steps.size else 0) + 2
    s_hi = np.empty(n_s)
    s_j = np.empty(n_s, dtype=np.int64)
    _flat_rays(flat, out, geo, rays, steps, big_p, s_hi, s_j)


@njit(cache=True)
def _viewshed_kernel(
    dem: Dem, u0: float, v0: float, a: float, e: float, eye: float, radius: float,
    inv2r: float, th: float, tmin: float, tmax: float, el_min_deg: float, el_max_deg: float,
    az_on: bool, az_min: float, az_w: float, big_d: int, big_p: int, n_lev: int,
) -> Mask:  # fmt: skip
    """uint8 visibility mask of ``dem`` seen from grid point (u0, v0) at elevation ``eye``.

    ``big_d``: steps per ray (radius in cells + 1); ``big_p``: perimeter resolution, i.e.
    rays end at minor offsets k / (big_p / big_d) cells (oversampling when big_p > big_d).
    ``n_lev`` > 0 (full circle only): a tree of rays, ``big_p`` >> ``n_lev`` rays per side at
    the observer, doubling at each level. Jobs under ``_PARALLEL_MIN_STEPS`` ray steps run on
    one thread.
    """
    h, w = dem.shape
    out = np.zeros((h, w), dtype=np.uint8)
    flat = dem.reshape(-1)
    oflat = out.reshape(-1)
    ic = math.floor(u0 + 0.5)
    ir = math.floor(v0 + 0.5)
    geo = (h, w, ic, ir, u0, v0, a, e, eye, radius, inv2r, th, tmin, tmax, az_on, az_min, az_w)
    if n_lev > 0:
        # sight lines run within half a cell of their owner ray, which runs within one cell
        # of the ancestors that took its early samples
        off_m = _TREE_BARS * (max(0.5 * big_d / big_p, abs(ic - u0) + abs(ir - v0)) + 1.0)
        if 6 * big_d * big_p >= _PARALLEL_MIN_STEPS:
            _tree_parallel(flat, oflat, geo, big_p, n_lev, big_d, off_m)
        else:
            _tree_serial(flat, oflat, geo, big_p, n_lev, big_d, off_m)
    else:
        ratio = max(abs(a), abs(e)) / min(abs(a), abs(e))
        steps = _ray_steps(big_d, big_p, a, e, az_on, az_min, az_w, ratio)
        heavy = np.nonzero(steps > _HEAVY_STEPS)[0]
        light = np.nonzero(steps <= _HEAVY_STEPS)[0]
        if steps[heavy].sum() >= _PARALLEL_MIN_STEPS:
            _flat_parallel(flat, oflat, geo, heavy, steps, big_p)
        else:
            _flat_serial(flat, oflat, geo, heavy, steps, big_p)
        _flat_serial(flat, oflat, geo, light, steps, big_p)
    _judge_origin(
        dem, out, ic, ir, u0, v0, a, e, eye, th, el_min_deg, el_max_deg, az_on, az_min, az_w
    )
    return out


@njit(cache=True)
def _judge_origin(
    dem: Dem, out: Mask, ic: int, ir: int, u0: float, v0: float, a: float, e: float, eye: float,
    th: float, el_min: float, el_max: float, az_on: bool, az_min: float, az_w: float,
) -> None:  # fmt: skip
    """The observer's own cell: nothing lies in between; only the bands apply."""
    zc = dem[ir, ic]
    if zc != zc:
        return
    cx = (ic - u0) * a
    cy = (ir - v0) * e
    dc = math.sqrt(cx * cx + cy * cy)
    el = math.degrees(math.atan2(zc + th - eye, dc))
    if el < el_min or el > el_max:
        return
    if az_on and dc > 0.0 and not _in_az(cx, cy, az_min, az_w):
        return
    out[ir, ic] = 1


# ---------------------------------------------------------------------------------------------
# public wrapper
# ---------------------------------------------------------------------------------------------
def _az_params(az_band: Sequence[float] | None) -> tuple[bool, float, float]:
    """(band on?, az_min in [0, 360), clockwise width in degrees) of an azimuth band."""
    if az_band is None:
        return False, 0.0, 360.0
    az_min, az_max = (float(v) for v in az_band)
    if not (math.isfinite(az_min) and math.isfinite(az_max)):
        raise ArgumentError(f"azimuth band must be finite, got {az_band}")
    if az_max - az_min >= 360.0:
        return False, 0.0, 360.0
    return True, az_min % 360.0, (az_max - az_min) % 360.0


def _el_params(el_band: Sequence[float] | None) -> tuple[float, float, float, float]:
    """(tan lower, tan upper, lower deg, upper deg) of an elevation band, +-inf when open."""
    if el_band is None:
        return -np.inf, np.inf, -90.0, 90.0
    lo, hi = (float(v) for v in el_band)
    if not (-90.0 <= lo <= hi <= 90.0):
        raise ArgumentError(f"elevation band must satisfy -90 <= el_min <= el_max <= 90: {el_band}")
    tlo = -np.inf if lo <= -90.0 else math.tan(math.radians(lo))
    thi = np.inf if hi >= 90.0 else math.tan(math.radians(hi))
    return tlo, thi, lo, hi


def observer_eye(
    dem: np.ndarray, tr: Affine, x: float, y: float, height: float, absolute: bool
) -> tuple[float, float, float]:
    """(u0, v0, eye elevation in metres) of an observer at map (x, y); ArgumentError off the
    grid or over NaN."""
    u0, v0 = (float(t) for t in xy_to_uv(tr, x, y))
    h, w = dem.shape
    if not (-0.5 <= u0 < w - 0.5 and -0.5 <= v0 < h - 0.5):
        raise ArgumentError(f"observer x={x}, y={y} lies outside the DEM window")
    if absolute:
        return u0, v0, float(height)
    ground = bilinear(dem, min(max(u0, 0.0), w - 1.0), min(max(v0, 0.0), h - 1.0))
    if not math.isfinite(ground):
        raise ArgumentError(f"no DEM data under the observer at x={x}, y={y}")
    return u0, v0, ground + float(height)


def compute_viewshed(
    window: Any,
    x: float,
    y: float,
    *,
    height: float,
    radius: float,
    height_is_absolute: bool = False,
    az_band: Sequence[float] | None = None,
    el_band: Sequence[float] | None = None,
    target_height: float = 0.0,
    planet_radius: float = MARS_RADIUS_M,
    transform: Transform | None = None,
    oversample: int = 1,
) -> np.ndarray:
    """Visibility mask (uint8, 1 = visible) on the DEM window grid.

    ``window``: a ``DemWindow``, an (array, transform) pair, or an array with ``transform=``
    (NaN = nodata). Observer at map (x, y) of the window's CRS; eye at ``height`` metres above
    the terrain there, or at absolute elevation ``height`` when ``height_is_absolute``.
    ``radius`` in map units. ``az_band`` = (az_min, az_max) degrees clockwise from grid north,
    taken clockwise from az_min (355..5 crosses north); None = all azimuths. ``el_band`` =
    (el_min, el_max) degrees above the horizontal; None = all. ``target_height`` (metres) is
    added to each cell's surface. ``planet_radius`` (metres) drives the d^2/(2R) curvature drop;
    0 disables it. A cell is visible when the segment from the eye to its surface point stays
    on or above the bilinear terrain along its whole length (exact where the sweep's verdict is
    close: see the module docstring). ``oversample``: rays per perimeter cell (2: a cell lies
    within a quarter cell of its ray, narrower error bars, slower; 1: within half a cell).
    """
    dem, tr = as_grid(window, transform)
    if not (radius > 0 and math.isfinite(radius)):
        raise ArgumentError(f"radius must be positive and finite, got {radius}")
    u0, v0, eye = observer_eye(dem, tr, x, y, height, height_is_absolute)
    az_on, az_min, az_w = _az_params(az_band)
    tmin, tmax, el_lo, el_hi = _el_params(el_band)
    inv2r = 0.0 if not planet_radius or not math.isfinite(planet_radius) else 0.5 / planet_radius
    big_d = math.ceil(radius / min(abs(tr.a), abs(tr.e))) + 1
    if int(oversample) < 1:
        raise ArgumentError(f"oversample must be >= 1, got {oversample}")
    big_p = big_d * int(oversample)
    n_lev = 0
    if not az_on:  # full circle: a tree of rays, at least _TREE_MIN_RAYS per side at the root
        n_lev = max(0, int(math.log2(big_p / _TREE_MIN_RAYS)))
        big_p = math.ceil(big_p / 2**n_lev) * 2**n_lev
    return _viewshed_kernel(
        dem, u0, v0, float(tr.a), float(tr.e), eye, float(radius), inv2r, float(target_height),
        tmin, tmax, el_lo, el_hi, az_on, az_min, az_w, big_d, big_p, n_lev,
    )  # fmt: skip
