"""Forward-projection renderer: the DEM, textured with the ortho, seen through a mast camera.

Terrain points are sampled from the bilinear DEM surface (cell centres are the grid nodes) at
a density adapted to their projected size (every sample lands within half a pixel of the
next), projected through the camera model into the image, and kept where nearest (depth
buffer). It never casts rays, so a separate ray caster can check it.

Frames and units: DEM in the map CRS (x, y map metres, z elevation above the areoid, metres);
the camera comes from ``MapCamera`` (vectors in local NED at the rover, metres; linear map
Jacobian). Planet curvature as in the kernels: a point at horizontal distance d from the
camera is drawn d^2 / (2 R) lower in the local tangent frame. Pixels (sample, line), first
pixel centre at (0, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from affine import Affine
from numba import njit
from numpy.typing import NDArray

from mars_pairs.geometry.frames import MARS_RADIUS_M
from mars_pairs.geometry.mapcam import MapCamera

F64 = NDArray[np.float64]

SKY_RGB = (222, 189, 150)  # flat pale butterscotch
TERRAIN_TINT = (1.12, 0.86, 0.64)  # grey ortho -> Mars orange (luminance ~ 0.93 x grey)
BLOCK = 16  # cells per culling block side
_STEP_PX = 0.5  # largest projected spacing between samples
_LEAF_PX = 48.0  # quads larger than this on screen are split (to clip them to the image)
_MAX_DEPTH = 14
_MIN_RANGE_M = 0.2

# parameter vector layout (see ``camera_params``)
_OZ, _C, _A, _H, _V, _O, _R, _ISOR, _INV2R = 0, 1, 4, 7, 10, 13, 16, 19, 20


@dataclass(frozen=True)
class DemGrid:
    """A DEM array (NaN = nodata, row 0 north) and its affine transform (cell corners)."""

    z: F64
    transform: Affine

    @property
    def res(self) -> float:
        """Cell size, map metres."""
        return abs(self.transform.a)


def camera_params(mc: MapCamera) -> tuple[F64, F64]:
    """Kernel parameters of a MapCamera: (params vector, 2x2 inverse of the map Jacobian)."""
    cam = mc.camera
    p = np.zeros(21)
    p[_OZ] = mc.origin_map[2]
    p[_C : _C + 3] = cam.c
    p[_A : _A + 3] = cam.a
    p[_H : _H + 3] = cam.h
    p[_V : _V + 3] = cam.v
    if cam.model_type == "CAHVOR":
        assert cam.o is not None and cam.r is not None
        p[_O : _O + 3] = cam.o
        p[_R : _R + 3] = cam.r
        p[_ISOR] = 1.0
    p[_INV2R] = 1.0 / (2.0 * MARS_RADIUS_M)
    jinv = np.asarray(np.linalg.inv(mc.jacobian[:2, :2]), dtype=np.float64)
    return p, jinv


@njit(cache=True)
def _point(n: float, e: float, z: float, p: np.ndarray) -> tuple[float, float, float, float]:
    """Local (n, e) metres + DEM z -> (sample, line, range m, cos angle to the axis A)."""
    dn = n - p[1]
    de = e - p[2]
    dd = p[0] - z + (dn * dn + de * de) * p[20] - p[3]
    rng = math.sqrt(dn * dn + de * de + dd * dd)
    cos_t = (dn * p[4] + de * p[5] + dd * p[6]) / max(rng, 1e-12)
    if p[19] > 0.0:
        zeta = dn * p[13] + de * p[14] + dd * p[15]
        lx, ly, lz = dn - zeta * p[13], de - zeta * p[14], dd - zeta * p[15]
        tau = (lx * lx + ly * ly + lz * lz) / max(zeta * zeta, 1e-24)
        mu = p[16] + p[17] * tau + p[18] * tau * tau
        dn, de, dd = dn + mu * lx, de + mu * ly, dd + mu * lz
    den = dn * p[4] + de * p[5] + dd * p[6]
    if den <= 1e-9:
        return -1e9, -1e9, rng, -1.0
    x = (dn * p[7] + de * p[8] + dd * p[9]) / den
    y = (dn * p[10] + de * p[11] + dd * p[12]) / den
    return x, y, rng, cos_t


@njit(cache=True)
def _splat_quad(
    z00: float, z01: float, z10: float, z11: float, n0: float, e0: float,
    dn_dj: float, de_dj: float, dn_di: float, de_di: float, i: int, j: int,
    s0: float, s1: float, t0: float, t1: float, nu: int, nv: int, p: np.ndarray,
    tol: float, reach: float, gate: np.ndarray, zbuf: np.ndarray, off2: np.ndarray,
    tolbuf: np.ndarray, hit_col: np.ndarray, hit_row: np.ndarray,
) -> None:  # fmt: skip
    """Sample a (sub-)cell on an nu x nv parametric grid and splat the samples.

    Depth test with a tolerance ``tol`` (metres, about the range span of one pixel on this
    surface): a sample clearly nearer than the stored one replaces it; one on the same surface
    (within ``tol``) replaces it when it lies closer to the pixel centre, so each pixel shows
    the surface point under its centre rather than the nearest edge of its footprint.
    A sample only counts for a pixel whose centre lies within ``reach`` pixels of it (about
    the covering radius of the sample lattice), so silhouettes fall where the pixel-centre
    rays put them. Samples not farther than ``gate`` (per pixel, metres) are ignored.
    """
    h, w = zbuf.shape
    reach2 = reach * reach
    for kv in range(nv):
        t = t0 + (t1 - t0) * kv / nv
        for ku in range(nu):
            s = s0 + (s1 - s0) * ku / nu
            zz = (z00 * (1 - s) + z01 * s) * (1 - t) + (z10 * (1 - s) + z11 * s) * t
            n = n0 + (j + s) * dn_dj + (i + t) * dn_di
            e = e0 + (j + s) * de_dj + (i + t) * de_di
            x, y, rng, cos_t = _point(n, e, zz, p)
            if cos_t <= 0.0 or rng < _MIN_RANGE_M:
                continue
            px = int(np.floor(x + 0.5))
            py = int(np.floor(y + 0.5))
            if not (0 <= px < w and 0 <= py < h):
                continue
            d2 = (x - px) * (x - px) + (y - py) * (y - py)
            if d2 > reach2:
                continue  # the surface does not reach this pixel's centre through this sample
            if rng <= gate[py, px]:
                continue
            stored = zbuf[py, px]
            if rng < stored - tol or (rng <= stored + tol and d2 < off2[py, px]):
                zbuf[py, px] = rng
                off2[py, px] = d2
                tolbuf[py, px] = tol
                hit_col[py, px] = j + s
                hit_row[py, px] = i + t


@njit(cache=True, nogil=True)
def render_depth(
    dem: np.ndarray, block_zmin: np.ndarray, block_zmax: np.ndarray, res: float,
    n0: float, e0: float, dn_dj: float, de_dj: float, dn_di: float, de_di: float,
    p: np.ndarray, width: int, height: int, cos_lim: float, gate: np.ndarray,
    gate_sat: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Depth buffer (range m, inf = sky) and DEM (col, row) of the nearest terrain per pixel.

    ``n0, e0`` and the four slopes give the local (north, east) metres of DEM node (i, j):
    n = n0 + j dn_dj + i dn_di. ``cos_lim``: cosine of a cone around the axis A that holds
    the whole image with margin; terrain outside it is culled.
    """
    zbuf = np.full((height, width), np.inf)
    tolbuf = np.zeros((height, width))
    off2 = np.full((height, width), np.inf)
    hit_col = np.full((height, width), np.nan)
    hit_row = np.full((height, width), np.nan)
    rows, cols = dem.shape
    nbi, nbj = block_zmin.shape
    sin_lim = math.sqrt(max(0.0, 1.0 - cos_lim * cos_lim))
    theta_lim = math.atan2(sin_lim, cos_lim)
    # quads wholly inside a wider cone are judged in screen space (bounding box of their
    # projected corners); only quads reaching outside it need the angular cull below, so
    # quads straddling the image's own cone never split down to the maximum depth
    cos_wide = math.cos(min(theta_lim + math.radians(10.0), math.radians(75.0)))
    lo_x, hi_x = -0.5, width - 0.5
    lo_y, hi_y = -0.5, height - 0.5
    vx = np.empty((BLOCK + 1, BLOCK + 1))
    vy = np.empty((BLOCK + 1, BLOCK + 1))
    vc = np.empty((BLOCK + 1, BLOCK + 1))
    vr = np.empty((BLOCK + 1, BLOCK + 1))
    qx, qy, qc, qr = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    qz = np.empty(4)
    st_s0 = np.empty(4 * _MAX_DEPTH + 8)
    st_s1 = np.empty(4 * _MAX_DEPTH + 8)
    st_t0 = np.empty(4 * _MAX_DEPTH + 8)
    st_t1 = np.empty(4 * _MAX_DEPTH + 8)
    st_d = np.empty(4 * _MAX_DEPTH + 8, dtype=np.int64)
    for bi in range(nbi):
        for bj in range(nbj):
            zlo, zhi = block_zmin[bi, bj], block_zmax[bi, bj]
            if not (zlo <= zhi):
                continue  # all nodata
            i0, j0 = bi * BLOCK, bj * BLOCK
            i1, j1 = min(i0 + BLOCK, rows - 1), min(j0 + BLOCK, cols - 1)
            if i1 <= i0 or j1 <= j0:
                continue
            ic, jc = 0.5 * (i0 + i1), 0.5 * (j0 + j1)
            nc = n0 + jc * dn_dj + ic * dn_di
            ec = e0 + jc * de_dj + ic * de_di
            _x, _y, rng, cos_t = _point(nc, ec, 0.5 * (zlo + zhi), p)
            half = 0.5 * res * math.sqrt((i1 - i0) ** 2 + (j1 - j0) ** 2) * 1.01
            radius = math.sqrt(half * half + (0.5 * (zhi - zlo) + 0.05) ** 2)
            if rng > radius:
                beta = math.asin(min(1.0, radius / rng))
                theta = math.acos(max(-1.0, min(1.0, cos_t)))
                if theta - beta > theta_lim:
                    continue
            # vertices of the block
            for a in range(i1 - i0 + 1):
                for b in range(j1 - j0 + 1):
                    ii, jj = i0 + a, j0 + b
                    zz = dem[ii, jj]
                    if not math.isfinite(zz):
                        vc[a, b] = np.nan
                        continue
                    n = n0 + jj * dn_dj + ii * dn_di
                    e = e0 + jj * de_dj + ii * de_di
                    vx[a, b], vy[a, b], vr[a, b], vc[a, b] = _point(n, e, zz, p)
            for a in range(i1 - i0):
                for b in range(j1 - j0):
                    if not (math.isfinite(vc[a, b]) and math.isfinite(vc[a, b + 1])
                            and math.isfinite(vc[a + 1, b])
                            and math.isfinite(vc[a + 1, b + 1])):  # fmt: skip
                        continue
                    i, j = i0 + a, j0 + b
                    z00, z01 = dem[i, j], dem[i, j + 1]
                    z10, z11 = dem[i + 1, j], dem[i + 1, j + 1]
                    top = 0
                    st_s0[0], st_s1[0], st_t0[0], st_t1[0], st_d[0] = 0.0, 1.0, 0.0, 1.0, 0
                    while top >= 0:
                        s0, s1 = st_s0[top], st_s1[top]
                        t0, t1 = st_t0[top], st_t1[top]
                        d = st_d[top]
                        top -= 1
                        # corners k = (t index) * 2 + (s index); s along columns, t along rows
                        for k in range(4):
                            ks, kt = k & 1, k >> 1
                            if d == 0:
                                qx[k], qy[k] = vx[a + kt, b + ks], vy[a + kt, b + ks]
                                qr[k], qc[k] = vr[a + kt, b + ks], vc[a + kt, b + ks]
                                qz[k] = dem[i + kt, j + ks]
                                continue
                            s = s1 if ks else s0
                            t = t1 if kt else t0
                            zz = (z00 * (1 - s) + z01 * s) * (1 - t) + (z10 * (1 - s) + z11 * s) * t
                            qz[k] = zz
                            n = n0 + (j + s) * dn_dj + (i + t) * dn_di
                            e = e0 + (j + s) * de_dj + (i + t) * de_di
                            qx[k], qy[k], qr[k], qc[k] = _point(n, e, zz, p)
                        if min(min(qc[0], qc[1]), min(qc[2], qc[3])) > cos_wide:
                            xmin, xmax = qx.min(), qx.max()
                            ymin, ymax = qy.min(), qy.max()
                            size = max(xmax - xmin, ymax - ymin)
                            margin = 0.25 * size + 2.0
                            if (xmax < lo_x - margin or xmin > hi_x + margin
                                    or ymax < lo_y - margin or ymin > hi_y + margin):  # fmt: skip
                                continue
                            if gate_sat.shape[0] > 1:
                                # second pass: only quads over pixels still to be resolved
                                bx0 = min(max(int(xmin - margin + 0.5), 0), width)
                                bx1 = min(max(int(xmax + margin + 1.5), 0), width)
                                by0 = min(max(int(ymin - margin + 0.5), 0), height)
                                by1 = min(max(int(ymax + margin + 1.5), 0), height)
                                if (gate_sat[by1, bx1] - gate_sat[by0, bx1] - gate_sat[by1, bx0]
                                        + gate_sat[by0, bx0]) == 0:  # fmt: skip
                                    continue
                            if size <= _LEAF_PX or d >= _MAX_DEPTH:
                                lu = max(math.hypot(qx[1] - qx[0], qy[1] - qy[0]),
                                         math.hypot(qx[3] - qx[2], qy[3] - qy[2]))  # fmt: skip
                                lv = max(math.hypot(qx[2] - qx[0], qy[2] - qy[0]),
                                         math.hypot(qx[3] - qx[1], qy[3] - qy[1]))  # fmt: skip
                                nu = max(1, int(np.ceil(lu / _STEP_PX)))
                                nv = max(1, int(np.ceil(lv / _STEP_PX)))
                                tol = 1.5 * (qr.max() - qr.min()) / max(size, 1e-3)
                                tol += 1e-4 * qr.min()
                                if gate_sat.shape[0] > 1:
                                    tol = np.inf  # second pass: nearest to the centre wins
                                su, sv = lu / nu, lv / nv
                                reach = min(0.75, 0.6 * math.sqrt(su * su + sv * sv) + 0.03)
                                _splat_quad(z00, z01, z10, z11, n0, e0, dn_dj, de_dj, dn_di,
                                            de_di, i, j, s0, s1, t0, t1, nu, nv, p, tol,
                                            reach, gate, zbuf, off2, tolbuf, hit_col,
                                            hit_row)  # fmt: skip
                                continue
                        else:
                            if d >= _MAX_DEPTH:
                                continue
                            # cull a quad that lies wholly outside the cone (or behind)
                            qmin = qr.min()
                            # a bilinear patch takes its extreme heights at its corners
                            dz = qz.max() - qz.min()
                            diag = 1.01 * res * math.hypot(s1 - s0, t1 - t0) + dz
                            if qmin > diag:
                                beta = math.asin(min(1.0, diag / qmin))
                                cm = max(-1.0, min(1.0, qc.max()))
                                if math.acos(cm) - beta > theta_lim:
                                    continue
                        # split into four
                        sm, tm = 0.5 * (s0 + s1), 0.5 * (t0 + t1)
                        for k in range(4):
                            top += 1
                            st_s0[top] = sm if (k & 1) else s0
                            st_s1[top] = s1 if (k & 1) else sm
                            st_t0[top] = tm if (k & 2) else t0
                            st_t1[top] = t1 if (k & 2) else tm
                            st_d[top] = d + 1
    return zbuf, tolbuf, hit_col, hit_row


@njit(cache=True)
def _at(
    dem: np.ndarray,
    col: float,
    row: float,
    n0: float,
    e0: float,
    dn_dj: float,
    de_dj: float,
    dn_di: float,
    de_di: float,
    p: np.ndarray,
) -> tuple[float, float, float]:
    """Pixel (x, y) and range of the bilinear DEM surface at fractional node (col, row)."""
    rows, cols = dem.shape
    j = min(max(int(np.floor(col)), 0), cols - 2)
    i = min(max(int(np.floor(row)), 0), rows - 2)
    s, t = col - j, row - i
    zz = (dem[i, j] * (1 - s) + dem[i, j + 1] * s) * (1 - t) + (
        dem[i + 1, j] * (1 - s) + dem[i + 1, j + 1] * s
    ) * t
    n = n0 + col * dn_dj + row * dn_di
    e = e0 + col * de_dj + row * de_di
    x, y, rng, _ = _point(n, e, zz, p)
    return x, y, rng


@njit(cache=True, nogil=True)
def refine_hits(
    dem: np.ndarray, hit_col: np.ndarray, hit_row: np.ndarray, n0: float, e0: float,
    dn_dj: float, de_dj: float, dn_di: float, de_di: float, p: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Move each pixel's surface point (DEM col, row) to where it projects onto the pixel
    centre: Newton steps on the forward projection, from the splatted sample (which lies
    within half a pixel). A point is moved only when the steps converge (1e-3 pixel) within
    two pixel footprints of the start (far off, at a silhouette, the centre ray may meet
    other terrain); far away one pixel spans many DEM cells, so the limit scales with it.
    Returns the pixels left unresolved: their surface does not reach the centre ray."""
    h, w = hit_col.shape
    eps = 1e-4
    failed = np.zeros((h, w), dtype=np.bool_)
    for py in range(h):
        for px in range(w):
            c, r = hit_col[py, px], hit_row[py, px]
            if not math.isfinite(c):
                continue
            c_start, r_start = c, r
            foot = -1.0  # DEM cells per image pixel at the start
            ok = False
            for _ in range(6):
                x, y, _r = _at(dem, c, r, n0, e0, dn_dj, de_dj, dn_di, de_di, p)
                ex, ey = px - x, py - y
                if not (ex * ex + ey * ey < 1e30):
                    break  # nodata under the point
                if ex * ex + ey * ey < 1e-6:
                    ok = True
                    break
                xc, yc, _r = _at(dem, c + eps, r, n0, e0, dn_dj, de_dj, dn_di, de_di, p)
                xr, yr, _r = _at(dem, c, r + eps, n0, e0, dn_dj, de_dj, dn_di, de_di, p)
                a11, a21 = (xc - x) / eps, (yc - y) / eps
                a12, a22 = (xr - x) / eps, (yr - y) / eps
                det = a11 * a22 - a12 * a21
                if not (abs(det) > 1e-12):
                    break
                if foot < 0.0:
                    foot = math.sqrt(a11 * a11 + a12 * a12 + a21 * a21 + a22 * a22) / abs(det)
                dc = (a22 * ex - a12 * ey) / det
                dr = (-a21 * ex + a11 * ey) / det
                step = math.hypot(dc, dr)
                if step > 1.0:  # at most one cell per step: stay near the local patch
                    dc, dr = dc / step, dr / step
                c, r = c + dc, r + dr
            if ok and math.hypot(c - c_start, r - r_start) <= 2.0 * max(foot, 0.0) + 1e-9:
                hit_col[py, px], hit_row[py, px] = c, r
            else:
                failed[py, px] = True
    return failed


@njit(cache=True, nogil=True)
def shade(
    hit_col: np.ndarray, hit_row: np.ndarray, ortho: np.ndarray, factor: int,
    sky: np.ndarray, tint: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """RGB uint8 image: the ortho (bilinear) at each pixel's terrain point, tinted; sky else."""
    h, w = hit_col.shape
    oh, ow = ortho.shape
    out = np.empty((h, w, 3), dtype=np.uint8)
    for y in range(h):
        for x in range(w):
            c = hit_col[y, x]
            if not math.isfinite(c):
                for k in range(3):
                    out[y, x, k] = sky[k]
                continue
            fx = (c + 0.5) * factor - 0.5
            fy = (hit_row[y, x] + 0.5) * factor - 0.5
            fx = min(max(fx, 0.0), ow - 1.0)
            fy = min(max(fy, 0.0), oh - 1.0)
            j = min(int(fx), ow - 2)
            i = min(int(fy), oh - 2)
            tx, ty = fx - j, fy - i
            g = (ortho[i, j] * (1 - tx) + ortho[i, j + 1] * tx) * (1 - ty) + (
                ortho[i + 1, j] * (1 - tx) + ortho[i + 1, j + 1] * tx
            ) * ty
            for k in range(3):
                out[y, x, k] = min(255, max(0, int(g * tint[k] + 0.5)))
    return out


def block_ranges(dem: F64) -> tuple[F64, F64]:
    """Per-block (BLOCK x BLOCK cells, with their far edge nodes) min and max of the DEM."""
    rows, cols = dem.shape
    nbi, nbj = -(-(rows - 1) // BLOCK), -(-(cols - 1) // BLOCK)
    pad = np.full((nbi * BLOCK + 1, nbj * BLOCK + 1), np.nan)
    pad[:rows, :cols] = dem
    core = pad[:-1, :-1].reshape(nbi, BLOCK, nbj, BLOCK)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            zmin = np.nanmin(core, axis=(1, 3))
            zmax = np.nanmax(core, axis=(1, 3))
            # include the shared far edges
            edge_r = pad[BLOCK::BLOCK, :-1].reshape(nbi, nbj, BLOCK)
            edge_c = pad[:-1, BLOCK::BLOCK].reshape(nbi, BLOCK, nbj)
            zmin = np.fmin(zmin, np.fmin(np.nanmin(edge_r, axis=2), np.nanmin(edge_c, axis=1)))
            zmax = np.fmax(zmax, np.fmax(np.nanmax(edge_r, axis=2), np.nanmax(edge_c, axis=1)))
    return zmin, zmax


def image_cone_cos(mc: MapCamera, margin_deg: float = 3.0) -> float:
    """Cosine of a cone about the camera axis A that holds every pixel ray, plus a margin."""
    w, h = mc.width, mc.height
    xs = np.linspace(-0.5, w - 0.5, 33)
    ys = np.linspace(-0.5, h - 0.5, 33)
    border = np.concatenate([
        np.stack([xs, np.full_like(xs, -0.5)], 1), np.stack([xs, np.full_like(xs, h - 0.5)], 1),
        np.stack([np.full_like(ys, -0.5), ys], 1), np.stack([np.full_like(ys, w - 0.5), ys], 1),
    ])  # fmt: skip
    _, rays = mc.camera.unproject(border)
    theta = np.degrees(np.arccos(np.clip(rays @ mc.camera.a, -1, 1))).max()
    return float(np.cos(np.radians(min(theta + margin_deg, 80.0))))


def render_hits(mc: MapCamera, dem: DemGrid, blocks: tuple[F64, F64]) -> tuple[F64, F64, F64]:
    """Each pixel's nearest terrain point: (DEM column, DEM row) fractional node coordinates
    (NaN: sky) and its range (metres from the camera centre; inf: sky), (height, width)."""
    p, jinv = camera_params(mc)
    t = dem.transform
    # map x, y of node (i, j): x = t.c + (j + 0.5) t.a, y = t.f + (i + 0.5) t.e
    x00 = t.c + 0.5 * t.a - mc.origin_map[0]
    y00 = t.f + 0.5 * t.e - mc.origin_map[1]
    n0, e0 = jinv @ np.array([x00, y00])
    dn_dj, de_dj = jinv @ np.array([t.a, 0.0])
    dn_di, de_di = jinv @ np.array([0.0, t.e])
    geo = (float(n0), float(e0), float(dn_dj), float(de_dj), float(dn_di), float(de_di))
    cos_lim = image_cone_cos(mc)
    open_gate = np.full((mc.height, mc.width), -np.inf)
    zbuf, _tolbuf, hc, hr = render_depth(
        dem.z,
        blocks[0],
        blocks[1],
        dem.res,
        *geo,
        p,
        mc.width,
        mc.height,
        cos_lim,
        open_gate,
        np.zeros((1, 1)),
    )
    failed = refine_hits(dem.z, hc, hr, *geo, p)
    if failed.any():
        # silhouette pixels: the nearest surface grazes the pixel but misses its centre ray;
        # splat again keeping only what lies behind it (the sample nearest the pixel centre),
        # and take that where it reaches the centre
        gate = np.where(failed, zbuf * (1.0 + 1e-4) + 0.01, np.inf)
        sat = np.zeros((mc.height + 1, mc.width + 1))
        sat[1:, 1:] = np.cumsum(np.cumsum(failed, axis=0), axis=1)
        zb2, _, hc2, hr2 = render_depth(
            dem.z, blocks[0], blocks[1], dem.res, *geo, p, mc.width, mc.height, cos_lim, gate, sat
        )
        failed2 = refine_hits(dem.z, hc2, hr2, *geo, p)
        use = failed & ~(failed2 & np.isfinite(hc2))
        hc = np.where(use, hc2, hc)
        hr = np.where(use, hr2, hr)
        zbuf = np.where(use, zb2, zbuf)
    return hc, hr, zbuf


def render_view(
    mc: MapCamera, dem: DemGrid, blocks: tuple[F64, F64], ortho: NDArray[np.uint8], factor: int
) -> tuple[NDArray[np.uint8], F64]:
    """Render ``mc``'s image (height, width, 3) uint8 and its depth buffer (range m, inf sky).

    ``ortho`` covers the DEM's bounds with ``factor`` pixels per DEM cell.
    """
    rgb, zbuf, _hc, _hr = render_view_hits(mc, dem, blocks, ortho, factor)
    return rgb, zbuf


def render_view_hits(
    mc: MapCamera, dem: DemGrid, blocks: tuple[F64, F64], ortho: NDArray[np.uint8], factor: int
) -> tuple[NDArray[np.uint8], F64, F64, F64]:
    """``render_view`` and each pixel's terrain point (``render_hits``: DEM column, row)."""
    hc, hr, zbuf = render_hits(mc, dem, blocks)
    rgb = shade(hc, hr, ortho.astype(np.float32), factor,
                np.array(SKY_RGB, dtype=np.uint8), np.array(TERRAIN_TINT))  # fmt: skip
    return rgb, zbuf, hc, hr


def classes_at(hit_col: F64, hit_row: F64, classes: NDArray[np.uint8], factor: int,
               sky: int = 255) -> NDArray[np.uint8]:  # fmt: skip
    """The class raster ``classes`` (the ortho's grid: ``factor`` pixels per DEM cell) at each
    pixel's terrain point (DEM column, row; nearest ortho pixel), ``sky`` where none."""
    ok = np.isfinite(hit_col)
    oh, ow = classes.shape
    u = np.where(ok, (hit_col + 0.5) * factor - 0.5, 0.0)
    v = np.where(ok, (hit_row + 0.5) * factor - 0.5, 0.0)
    j = np.clip(np.floor(u + 0.5).astype(np.int64), 0, ow - 1)
    i = np.clip(np.floor(v + 0.5).astype(np.int64), 0, oh - 1)
    return np.where(ok, classes[i, j], np.uint8(sky)).astype(np.uint8)
