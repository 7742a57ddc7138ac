"""Experiment (not used by the package): a full-circle viewshed by line propagation (XDraw,
GDAL's scheme), re-tested exactly where its margin is thin, against GDAL and compute_viewshed.

    python benchmarks/experiments/xdraw_viewshed.py --radius 500,2000

Frames and units: the DEM window grid, (u, v) = fractional (col, row) with cell centres at
integers; ``a``, ``e`` map pixel sizes (metres per column, per row); elevations metres. The
visibility definition is ``mars_pairs.kernels.viewshed``'s (bilinear terrain lowered by
d^2 / (2R); the whole segment from the eye to the cell's surface point on or above it).

Algorithm: the window is cut into 8 octant halves, each swept line by line away from the
observer (lines: rows for north and south, columns for east and west). A cell's sight line
crosses the line before it between two cells; the horizon there (the steepest slope seen so
far) is interpolated from theirs: O(1) a cell. The cell is visible when its own slope reaches
that horizon; its horizon is the larger of the two; the line where the horizon was set travels
with it. East and west are swept row by row (a cell needs its neighbours one column nearer the
observer, in its own row and the row before), so every octant reads the DEM along rows. A cell
whose margin (own slope minus interpolated horizon) lies in [-band_lo, band_hi] is re-tested on
its exact sight line (``viewshed._segment_clear``): its last two grid lines and +-2 lines around
the lines its two neighbours' horizons were set on; on the hidden side, then the whole line,
skipping 8 x 8 blocks whose highest cell lies below it (``_coarse_clear``).

Findings (4096 x 4096 fractal DEM of bench_viewshed.py at 1 m, observer 2 m above the centre;
one run, load 11 on 2 cores; wall = median of 7 interleaved rounds, CPU = process time; IoU on
50,000 sampled cells against the exact reference):

wall ms (vs GDAL) / CPU ms / IoU   | 500 m                   | 2000 m
GDAL ViewshedGenerate in process   | 20.3 (1.00x) / 8.2      | 404 (1.00x) / 108
compute_viewshed full 360          | 76.0 (0.27x) / 25 / .998 | 735 (0.55x) / 208 / .998
XDraw sweep alone                  | 22.8 (0.89x) / 7 / .953  | 330 (1.22x) / 94 / .951
XDraw + re-tests (band 2e-4)       | 53.8 (0.38x) / 20 / .991 | 744 (0.54x) / 236 / .983

The sweep costs what GDAL's does (the same algorithm; GDAL's own IoU here is 0.95). Thin
margins are common (~7% of the cells within 5 cm of the interpolated horizon at 500 m) and a
visible verdict needs the whole sight line, so the re-tests cost more than the sweep (at
2000 m: tail and horizon-line tests of the thin-margin visible side ~95 ms CPU, whole-line
tests of the hidden side ~55 ms), and the 8 octants over 2 threads gain nothing at this load.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

from bench_viewshed import (  # noqa: E402
    HEIGHT,
    R_MARS,
    X0,
    Y0,
    accuracy,
    band_cells,
    fractal_dem,
    one_thread,
    start_worker,
    write_dem,
)

from mars_pairs.kernels import compute_viewshed  # noqa: E402
from mars_pairs.kernels.viewshed import (  # noqa: E402
    _SAFE_FM,
    Dem,
    Mask,
    _judge_origin,
    _segment_clear,
)
from mars_pairs.raster.terrain import Terrain  # noqa: E402
from mars_pairs.runtime import configure_process  # noqa: E402
from support.los_reference import exact_viewshed  # noqa: E402

_NEG = -1e30  # the horizon slope of nothing seen yet (finite: interpolation weights may be 0)
_EXACT_LINES = 4  # cells on the first lines out from the observer: whole sight line, exact
_HEAD_LINES = 2  # grid lines either side of the horizon's line re-tested exactly
_BLOCK = 8  # quads a side of the blocks whose maxima let a whole re-test skip clear terrain

Ints = NDArray[np.int64]
# (h, w, ic, ir, u0, v0, a, e, eye, r2, inv2r, th, tmin, tmax, band_lo, band_hi)
LGeo = tuple[
    int, int, int, int, float, float, float, float, float, float, float, float, float, float,
    float, float,
]  # fmt: skip


@njit(cache=True)
def _block_max(dem: Dem) -> Dem:
    """Per block of ``_BLOCK`` x ``_BLOCK`` quads (top-left cells (i, j), i // _BLOCK = bi,
    j // _BLOCK = bj), the highest of their corner cells, metres (-inf: all nodata)."""
    h, w = dem.shape
    nbh = max(1, (h - 2) // _BLOCK + 1)
    nbw = max(1, (w - 2) // _BLOCK + 1)
    out = np.full((nbh, nbw), -np.inf, dtype=np.float32)
    rb = np.empty(nbw, dtype=np.float32)
    for r in range(h):
        for bi in range(nbw):
            m = -np.inf
            for c in range(bi * _BLOCK, min(w, bi * _BLOCK + _BLOCK + 1)):
                z = dem[r, c]
                if z > m:
                    m = z
            rb[bi] = m
        bj = min(r // _BLOCK, nbh - 1)
        for bi in range(nbw):
            out[bj, bi] = max(out[bj, bi], rb[bi])
        if r % _BLOCK == 0 and r > 0 and r // _BLOCK <= nbh - 1:
            for bi in range(nbw):
                out[bj - 1, bi] = max(out[bj - 1, bi], rb[bi])
    return out


@njit(cache=True, fastmath=_SAFE_FM)
def _block_crossing(p0: float, dp: float, t0: float) -> tuple[float, float]:
    """(first t > t0 where p0 + t dp crosses a block edge (a multiple of ``_BLOCK``), the t
    between edges); (inf, inf) when dp is 0. Grid units (cells)."""
    bs = float(_BLOCK)
    pa = (p0 + t0 * dp) / bs
    if dp > 0.0:
        return ((math.floor(pa) + 1.0) * bs - p0) / dp, bs / dp
    if dp < 0.0:
        return ((math.ceil(pa) - 1.0) * bs - p0) / dp, -bs / dp
    return np.inf, np.inf


@njit(cache=True, fastmath=_SAFE_FM)
def _coarse_clear(
    flat: Dem, bz: Dem, h: int, w: int, u0: float, v0: float, col: int, row: int, a: float,
    e: float, eye: float, zt: float, inv2r: float, t0: float, t1: float,
) -> bool:  # fmt: skip
    """``viewshed._segment_clear`` over t in [t0, t1], block by block (``_block_max``): a
    block whose highest cell lies below the sight line's lowest point over it (less the
    smallest curvature drop there) is clear; the others are tested exactly."""
    du = col - u0
    dv = row - v0
    drop = ((du * a) ** 2 + (dv * e) ** 2) * inv2r
    slope = zt - eye
    nbh, nbw = bz.shape
    tu, su = _block_crossing(u0, du, t0)
    tv, sv = _block_crossing(v0, dv, t0)
    ta = t0
    while ta < t1:
        tb = min(tu, tv, t1)
        tm = 0.5 * (ta + tb)
        um = u0 + tm * du
        vm = v0 + tm * dv
        if 0.0 <= um <= w - 1 and 0.0 <= vm <= h - 1:
            bi = min(min(int(um), w - 2) // _BLOCK, nbw - 1)
            bj = min(min(int(vm), h - 2) // _BLOCK, nbh - 1)
            low = eye + (ta if slope >= 0.0 else tb) * slope
            if bz[bj, bi] - ta * ta * drop > low and not _segment_clear(
                flat, h, w, u0, v0, col, row, a, e, eye, zt, inv2r, ta, tb
            ):
                return False
        if tb == tu:
            tu += su
        if tb == tv:
            tv += sv
        ta = tb
    return True


@njit(cache=True, fastmath=_SAFE_FM)
def _retest(
    flat: Dem, bz: Dem, geo: LGeo, col: int, row: int, d2: float, p: float, om: float, s: int,
    j: int, j2: int, whole: bool,
) -> bool:  # fmt: skip
    """Exact test of the sight line to cell (col, row) at major distance ``p`` cells (line
    ``s`` of its octant, whose observer sits ``om`` cells past its line 0), horizon set on
    lines ``j``, ``j2`` (0: none): the last two grid lines, +-``_HEAD_LINES`` around them, then
    (``whole``, or on the first ``_EXACT_LINES`` lines) the rest of the sight line."""
    h, w, _, _, u0, v0, a, e, eye, _, inv2r, th = geo[:12]
    zc = flat[row * w + col] + th - d2 * inv2r
    if s <= _EXACT_LINES:
        return _segment_clear(flat, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, 0.0, 1.0)
    inv_n = 1.0 / p
    t_tail = max(0.0, 1.0 - 2.0 * inv_n)
    if not _segment_clear(flat, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, t_tail, 1.0):
        return False
    for jj in (j, j2):
        if jj > 0:
            ta = max(0.0, (jj - _HEAD_LINES - om) * inv_n)
            tb = min(t_tail, (jj + _HEAD_LINES - om) * inv_n)
            if ta < tb and not _segment_clear(
                flat, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, ta, tb
            ):
                return False
    if not whole:
        return True
    return _coarse_clear(flat, bz, h, w, u0, v0, col, row, a, e, eye, zc, inv2r, 0.0, t_tail)


@njit(cache=True, fastmath=_SAFE_FM)
def _octant(
    grid: Dem, flat: Dem, bz: Dem, out: Mask, geo: LGeo, sgn_maj: int, sgn_min: int
) -> None:  # fmt: skip
    """North (``sgn_maj`` -1) or south octant half of the DEM ``grid`` (``flat`` raveled):
    line ``s`` = row offset from the observer, ``k`` = column offset towards ``sgn_min``;
    owns 0 (+) or 1 (-) <= k < s."""
    h, w, ic, ir, u0, v0, a, e, eye, r2, inv2r, th, tmin, tmax, band_lo, band_hi = geo
    gh, gw, gic, gir, gu0, gv0, sc_maj, sc_min = h, w, ic, ir, u0, v0, abs(e), abs(a)
    om = sgn_maj * (gv0 - gir)
    on = sgn_min * (gu0 - gic)
    s_max = min((gh - 1 - gir) if sgn_maj > 0 else gir, math.floor(math.sqrt(r2) / sc_maj + om))
    k_grid = (gw - 1 - gic) if sgn_min > 0 else gic
    k_own0 = 0 if sgn_min > 0 else 1
    n = k_grid + 4
    hp = np.full(n, _NEG)
    hc = np.full(n, _NEG)
    jp = np.zeros(n, dtype=np.int64)
    jc = np.zeros(n, dtype=np.int64)
    mg = np.empty(n)
    dd = np.empty(n)
    slb = np.empty(n)
    jh = np.zeros(n, dtype=np.int64)
    jh2 = np.zeros(n, dtype=np.int64)
    zb = np.empty(n)
    qk = np.empty(n)
    dmin2 = np.empty(n)
    for k in range(n):
        qk[k] = k - on
        dmin2[k] = ((k - on) * sc_min) ** 2
    zoff = th - eye
    for s in range(1, s_max + 1):
        p = s - om
        dmaj2 = (p * sc_maj) ** 2
        k_rad = math.floor(on + math.sqrt(max(0.0, r2 - dmaj2)) / sc_min)
        k1 = min(s + 1, k_grid, k_rad + 1)
        if k1 < 0:
            break
        inv_p = 1.0 / p
        grow = gir + sgn_maj * s
        for k in range(k1 + 1):
            zb[k] = grid[grow, gic + sgn_min * k]
        hp[0] = hp[1]
        jp[0] = jp[1]
        for k in range(k1 + 1):
            dl = min(max(qk[k] * inv_p, 0.0), 1.0)
            ha = hp[k + 1]
            hb_ = hp[k]
            hb = ha + dl * (hb_ - ha)
            near = ha >= hb_
            jb = jp[k + 1] if near else jp[k]
            jh2[k] = jp[k] if near else jp[k + 1]
            d2 = dmaj2 + dmin2[k]
            d = math.sqrt(d2)
            sl = (zb[k] + zoff - d2 * inv2r) / d
            up = sl > hb
            hc[k + 1] = sl if up else hb
            jc[k + 1] = s if up else jb
            mg[k] = sl - hb
            dd[k] = d2
            slb[k] = sl
            jh[k] = jb
        hc[k1 + 2] = hc[k1 + 1]
        jc[k1 + 2] = jc[k1 + 1]
        for k in range(k_own0, min(s - 1, k1) + 1):
            m = mg[k]
            d2 = dd[k]
            sl = slb[k]
            if m != m or d2 > r2 or sl < tmin or sl > tmax or m < -band_lo:
                continue
            gcol = gic + sgn_min * k
            col, row = gcol, grow
            if s <= _EXACT_LINES or m <= band_hi:
                out[row * w + col] = _retest(flat, bz, geo, col, row, d2, p, om, s, jh[k], jh2[k],
                                             m < 0.0)  # fmt: skip
            else:
                out[row * w + col] = 1
        hp, hc = hc, hp
        jp, jc = jc, jp


@njit(cache=True, fastmath=_SAFE_FM)
def _octant_cols(
    flat: Dem, bz: Dem, out: Mask, geo: LGeo, sgn_maj: int, sgn_min: int
) -> None:  # fmt: skip
    """East (``sgn_maj`` +1) or west octant half: lines are columns, ``k`` = row offset towards
    ``sgn_min``; owns 0 (+) or 1 (-) <= k <= s. Swept row by row, in the order rows run in
    memory: cell (s, k) needs (s - 1, k) of its own row and (s - 1, k - 1) of the row before."""
    h, w, ic, ir, u0, v0, a, e, eye, r2, inv2r, th, tmin, tmax, band_lo, band_hi = geo
    sc_maj, sc_min = abs(a), abs(e)
    om = sgn_maj * (u0 - ic)
    on = sgn_min * (v0 - ir)
    s_max = min((w - 1 - ic) if sgn_maj > 0 else ic, math.floor(math.sqrt(r2) / sc_maj + om))
    k_max = min((h - 1 - ir) if sgn_min > 0 else ir, math.floor(math.sqrt(r2) / sc_min + on))
    k_own0 = 0 if sgn_min > 0 else 1
    n = max(s_max, 0) + 3
    inv_p = np.zeros(n)
    dmaj2 = np.zeros(n)
    for s in range(1, s_max + 1):
        inv_p[s] = 1.0 / (s - om)
        dmaj2[s] = ((s - om) * sc_maj) ** 2
    hp = np.full(n, _NEG)
    hc = np.full(n, _NEG)
    jp = np.zeros(n, dtype=np.int64)
    jc = np.zeros(n, dtype=np.int64)
    mg = np.empty(n)
    slb = np.empty(n)
    jh = np.zeros(n, dtype=np.int64)
    jh2 = np.zeros(n, dtype=np.int64)
    zb = np.empty(n)
    zoff = th - eye
    for k in range(k_max + 1):
        q = k - on
        dmin2 = (q * sc_min) ** 2
        s1 = min(s_max, math.floor(om + math.sqrt(max(0.0, r2 - dmin2)) / sc_maj))
        s0 = max(1, k - 1)
        if s1 < s0:
            break
        qq = max(q, 0.0) if k > 0 else 0.0  # the axis row has no row before it
        row = ir + sgn_min * k
        base = row * w + ic
        for s in range(s0, s1 + 1):
            zb[s] = flat[base + sgn_maj * s]
        for s in range(s0, s1 + 1):  # the part without the row's own recurrence
            d2 = dmaj2[s] + dmin2
            slb[s] = (zb[s] + zoff - d2 * inv2r) / math.sqrt(d2)
        if s0 == 1:
            ha, ja = _NEG, 0
        else:
            ha, ja = hp[s0 - 1], jp[s0 - 1]
        for s in range(s0, s1 + 1):
            dl = min(qq * inv_p[s], 1.0)
            hb_ = hp[s - 1]
            hb = ha + dl * (hb_ - ha)
            near = ha >= hb_
            jb = ja if near else jp[s - 1]
            jh2[s] = jp[s - 1] if near else ja
            sl = slb[s]
            mg[s] = sl - hb
            jh[s] = jb
            up = sl > hb
            ha = sl if up else hb
            ja = s if up else jb
            hc[s] = ha
            jc[s] = ja
        if k >= k_own0:
            for s in range(max(k, 1), s1 + 1):
                d2 = dmaj2[s] + dmin2
                sl = slb[s]
                m = mg[s]
                if m != m or d2 > r2 or sl < tmin or sl > tmax or m < -band_lo:
                    continue
                col = ic + sgn_maj * s
                if s <= _EXACT_LINES or m <= band_hi:
                    out[base + sgn_maj * s] = _retest(flat, bz, geo, col, row, d2, s - om, om,
                                                      s, jh[s], jh2[s], m < 0.0)  # fmt: skip
                else:
                    out[base + sgn_maj * s] = 1
        hp, hc = hc, hp
        jp, jc = jc, jp


@njit(cache=True, parallel=True)
def _octants(dem: Dem, bz: Dem, out: Mask, geo: LGeo) -> None:
    """The 8 octant halves over the threads (each owns its cells: no write conflicts)."""
    flat = dem.reshape(-1)
    for o in prange(8):
        sgn_maj = 1 - 2 * ((o >> 1) & 1)
        sgn_min = 1 - 2 * (o & 1)
        if o < 4:
            _octant_cols(flat, bz, out, geo, sgn_maj, sgn_min)
        else:
            _octant(dem, flat, bz, out, geo, sgn_maj, sgn_min)


@njit(cache=True)
def _lines_kernel(
    dem: Dem, u0: float, v0: float, a: float, e: float, eye: float, radius: float,
    inv2r: float, th: float, tmin: float, tmax: float, el_min_deg: float, el_max_deg: float,
    band_lo: float, band_hi: float,
) -> Mask:  # fmt: skip
    """uint8 full-circle visibility mask of ``dem`` from grid point (u0, v0), eye elevation
    ``eye`` (metres); ``radius`` map units; ``tmin``/``tmax`` the elevation band's tangents;
    cells with margin (slope) in [-``band_lo``, ``band_hi``] are re-tested exactly."""
    h, w = dem.shape
    out = np.zeros((h, w), dtype=np.uint8)
    ic = math.floor(u0 + 0.5)
    ir = math.floor(v0 + 0.5)
    geo = (h, w, ic, ir, u0, v0, a, e, eye, radius * radius, inv2r, th, tmin, tmax, band_lo,
           band_hi)  # fmt: skip
    bz = _block_max(dem)
    _octants(dem, bz, out.reshape(-1), geo)
    _judge_origin(
        dem, out, ic, ir, u0, v0, a, e, eye, th, el_min_deg, el_max_deg, False, 0.0, 360.0
    )
    return out


def _run(dem, u0, v0, eye, radius, band, parallel):
    """The experiment's mask (observer at grid (u0, v0), eye metres; 1 m cells, north up);
    numba's parallel regions on one thread unless ``parallel``."""
    args = (dem, u0, v0, 1.0, -1.0, eye, radius, 0.5 / R_MARS, 0.0, -np.inf, np.inf, -90.0, 90.0,
            band[0], band[1])  # fmt: skip
    if parallel:
        return _lines_kernel(*args)
    return one_thread(lambda: _lines_kernel(*args))


def _timed(fn):
    """``fn`` wrapped to return (wall ms, process CPU ms)."""

    def run():
        t, c = time.perf_counter(), time.process_time()
        fn()
        return (time.perf_counter() - t) * 1e3, (time.process_time() - c) * 1e3

    return run


def _gdal_times(reply: dict[str, object]) -> tuple[float, float]:
    """(wall ms, CPU ms) of one GDAL worker reply."""
    return float(str(reply["ms"])), float(str(reply["cpu_ms"]))


def main() -> None:
    configure_process()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", default="500,2000", help="metres, comma list")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--ref-cells", type=int, default=50_000)
    ap.add_argument("--band", type=float, default=2e-4, help="re-test band (slope), both sides")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        dem_path = Path(tmp) / "dem.tif"
        write_dem(dem_path, fractal_dem(4096), 1.0)
        worker = start_worker("/usr/bin/python3", dem_path)
        try:
            for radius in (float(r) for r in args.radius.split(",")):
                one_radius(args, worker, dem_path, radius)
        finally:
            if worker is not None:
                worker.close()


def one_radius(args: argparse.Namespace, worker, dem_path: Path, radius: float) -> None:
    """Print the table of one radius: wall and CPU medians of interleaved rounds, IoU."""
    x, y = X0 + 2048.5, Y0 - 2048.5
    with Terrain.open(dem_path) as t:
        win = t.read_dem_window(x, y, radius)
        eye = t.elevation_at(x, y) + HEIGHT
    u0, v0 = (float(c) - 0.5 for c in ~win.transform * (x, y))
    dem = np.ascontiguousarray(win.data, dtype=np.float32)
    cells = band_cells(win, x, y, radius, None, None, eye, args.ref_cells)
    ref = exact_viewshed(dem, u0, v0, eye, radius, planet_radius=R_MARS, cells=cells)
    band = (args.band, args.band)
    cases = {
        "compute_viewshed full 360": lambda: compute_viewshed(
            win, x, y, height=HEIGHT, radius=radius
        ),
        "XDraw sweep alone": lambda: _run(dem, u0, v0, eye, radius, (0.0, -1.0), False),
        f"XDraw + re-tests (band {args.band:g})": lambda: _run(
            dem, u0, v0, eye, radius, band, False
        ),
        "XDraw + re-tests, 8 octants over the threads": lambda: _run(
            dem, u0, v0, eye, radius, band, True
        ),
    }
    masks = {k: f() for k, f in cases.items()}
    fns = {k: _timed(f) for k, f in cases.items()}
    req = {"x": x, "y": y, "height": HEIGHT, "radius": radius, "out": None}
    gdal = "GDAL ViewshedGenerate (in process)"
    if worker is not None:
        fns[gdal] = lambda: _gdal_times(worker.ask(req))
    load = os.getloadavg()
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in fns}
    for i in range(2 + args.repeats):
        for k, fn in fns.items():
            r = fn()
            if i >= 2:
                times[k].append(r)
    med = {k: np.median(np.array(v), axis=0) for k, v in times.items()}
    g = med[gdal][0] if gdal in med else float("nan")
    print(f"\nradius {radius:g} m, load {load[0]:.1f} before, {os.getloadavg()[0]:.1f} after\n")
    print("| case | wall ms | CPU ms | vs GDAL (wall) | IoU | false + /1000 | false - /1000 |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for k, (wall, cpu) in med.items():
        acc = accuracy(masks[k][cells], ref) if k in masks else "| |"
        print(f"| {k} | {wall:.1f} | {cpu:.1f} | {g / wall:.2f}x | {acc} |")


if __name__ == "__main__":
    main()
