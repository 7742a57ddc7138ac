"""Viewshed against the exact line-of-sight reference (``support.los_reference``, written from the
definition, sharing no code with the kernel): visible-set IoU on fractal terrain and on the real
Gale DEM, wedge and full circle. Map frame: x east, y north (metres)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.kernels import compute_viewshed
from support.los_reference import exact_viewshed, iou, segment_clear
from support.terrain import centre_xy, fractal_dem, grid

GALE = Path(__file__).resolve().parents[2].parent / "shared" / "real-gale"
SOL_1051_XY = (8142579.427, -276693.318)  # site 48 drive 2470, README of real-gale
IOU_MIN = 0.98


def band_mask(shape, u0, v0, radius, az_band, cell=1.0) -> np.ndarray:
    """Cells whose centre lies within ``radius`` metres and inside the azimuth band (degrees
    clockwise from north), from the cell geometry alone."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    east, north = (cols - u0) * cell, (v0 - rows) * cell
    ok = np.hypot(east, north) <= radius
    if az_band is not None:
        az = np.degrees(np.arctan2(east, north)) % 360.0
        ok &= ((az - az_band[0]) % 360.0) <= (az_band[1] - az_band[0]) % 360.0
    return ok


def compare(dem, tr, x, y, radius, az_band, height=2.0, th=0.0):
    """(IoU, kernel mask, reference mask) of the kernel against the exact reference."""
    u0, v0 = ~tr * (x, y)
    u0, v0 = u0 - 0.5, v0 - 0.5
    kw = {"height": height, "radius": radius, "az_band": az_band, "target_height": th}
    mask = compute_viewshed((dem, tr), x, y, planet_radius=MARS_RADIUS_M, **kw) == 1
    ground = exact_ground(dem, u0, v0)
    ref = exact_viewshed(dem, u0, v0, ground + height, radius, a=tr.a, e=tr.e, th=th,
                         planet_radius=MARS_RADIUS_M) == 1  # fmt: skip
    ref &= band_mask(dem.shape, u0, v0, radius, az_band, cell=tr.a)
    oc, orow = math.floor(u0 + 0.5), math.floor(v0 + 0.5)
    ref[orow, oc] = mask[orow, oc]  # the observer's own cell: a convention, not a sight line
    return iou(mask, ref), mask, ref


def exact_ground(dem, u0, v0) -> float:
    """Bilinear DEM value at grid (u0, v0) (cell centres at integers)."""
    c0, r0 = math.floor(u0), math.floor(v0)
    fu, fv = u0 - c0, v0 - r0
    z = dem.astype(np.float64)
    return float(
        z[r0, c0] * (1 - fu) * (1 - fv) + z[r0, c0 + 1] * fu * (1 - fv)
        + z[r0 + 1, c0] * (1 - fu) * fv + z[r0 + 1, c0 + 1] * fu * fv
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# the reference itself
# --------------------------------------------------------------------------------------------
def test_reference_on_analytic_terrain():
    n = 81
    flat = np.zeros((n, n))
    assert exact_viewshed(flat, 40, 40, 2.0, 35.0)[40, 40:76].all()
    wall = flat.copy()
    wall[:, 60] = 10.0  # north-south wall 20 m east of the observer
    vis = exact_viewshed(wall, 40, 40, 2.0, 35.0)
    assert vis[40, 60] == 1 and not vis[40, 61:76].any()
    # a ridge: its near face is seen; its far face, falling away more steeply than the sight
    # line, hides itself (the segment runs under the terrain just before the target)
    ridge = np.maximum(0.0, 8.0 - 2.0 * np.abs(np.arange(n) - 55.0))[None, :].repeat(n, 0)
    vis = exact_viewshed(ridge, 40, 40, 2.0, 35.0)
    assert vis[40, 52:56].all()
    assert not vis[40, 56:60].any()
    # curvature: an eye h above a sphere of radius R sees the plane out to sqrt(2 R h)
    vis = exact_viewshed(flat, 40, 40, 2.0, 40.0, planet_radius=200.0)
    assert vis[40, 40 + 27] == 1 and vis[40, 40 + 30] == 0


@pytest.mark.parametrize(
    ("k", "p", "q", "planet_radius", "a", "e"),
    [
        (0.0, 0.0, 0.0, 200.0, 1.0, -1.0),  # flat plane: the horizon at sqrt(2 R h)
        (0.0, 0.3, -0.2, 500.0, 2.0, -1.5),  # tilted plane, oblong cells
        (0.02, 0.0, 0.0, 0.0, 1.0, -1.0),  # saddle: the cross term alone
        (-0.015, 0.1, 0.25, 900.0, 1.0, -0.5),  # tilted saddle with curvature
    ],
)
def test_reference_on_bilinear_terrain_in_closed_form(k, p, q, planet_radius, a, e):
    # z = k (u - 40)(v - 41) + p u + q v is bilinear: the DEM's interpolant is z itself. Along
    # the sight line from h above the ground at grid (u0, v0) to the ground at cell (u0 + du,
    # v0 + dv), D metres away, terrain minus line is g(t) = (t - 1)(A t + h) with
    # A = k du dv - D^2 / (2R) (the linear terms cancel); on [0, 1] g <= 0 iff A >= -h.
    n, u0, v0, h = 81, 40.3, 40.6, 2.5
    rr, cc = np.mgrid[0:n, 0:n].astype(np.float64)
    dem = k * (cc - 40.0) * (rr - 41.0) + p * cc + q * rr
    eye = k * (u0 - 40.0) * (v0 - 41.0) + p * u0 + q * v0 + h
    vis = exact_viewshed(dem, u0, v0, eye, 1e9, a=a, e=e, planet_radius=planet_radius) == 1
    du, dv = cc - u0, rr - v0
    d2 = (du * a) ** 2 + (dv * e) ** 2
    big_a = k * du * dv - (d2 / (2.0 * planet_radius) if planet_radius else 0.0)
    # hidden cells rise (A + h)^2 / (4 |A|) above the line at most: within 0.05 m of A = -h
    # that is below the reference's 1e-6 m tolerance, so those tangent cells are left out
    clear = np.abs(big_a + h) > 0.05
    want = big_a >= -h
    assert want[clear].any() and not want[clear].all()
    assert (vis[clear] == want[clear]).all(), np.argwhere(clear & (vis != want))[:5]


def test_reference_on_a_ridge_in_closed_form():
    # a ridge along the rows: 4 m high at column 55, faces of slope 2 (feet at 53 and 57); the
    # DEM's interpolant is the profile itself. From 11 m above the plain at u0, the far face
    # (steeper than any sight line) is hidden, and the plain beyond is seen from the column
    # where the line to it clears the crest: h (c - 55) >= 4 (c - u0), c >= (55 h - 4 u0)/(h - 4)
    n, u0, v0, h = 81, 40.3, 40.6, 11.0
    rr, cc = np.mgrid[0:n, 0:n]
    ridge = np.maximum(0.0, 4.0 - 2.0 * np.abs(cc - 55.0))
    vis = exact_viewshed(ridge, u0, v0, h, 38.0) == 1
    inside = np.hypot(cc - u0, rr - v0) <= 38.0
    want = inside & ((cc <= 55) | (cc >= (55.0 * h - 4.0 * u0) / (h - 4.0)))
    assert (vis == want).all(), np.argwhere(vis != want)[:5]


def test_reference_treats_nodata_as_the_definition_says():
    dem = np.zeros((21, 21))
    dem[:, 14] = 10.0  # a wall 4 m east of the observer
    eye = 2.0
    assert not segment_clear(dem, 10.0, 10.0, eye, 18, 10, 1.0, -1.0, 0.0, 0.0)
    dem[10, 14] = np.nan  # its quads in the line's way have a nodata corner: they never block
    assert segment_clear(dem, 10.0, 10.0, eye, 18, 10, 1.0, -1.0, 0.0, 0.0)
    assert not segment_clear(dem, 10.0, 10.0, eye, 14, 10, 1.0, -1.0, 0.0, 0.0)  # nodata cell


def test_reference_agrees_with_dense_sampling():
    # a second, cruder method: the same definition sampled every 1/200 of a cell
    dem = fractal_dem(64, 5, std=3.0).astype(np.float64)
    u0, v0, eye = 31.3, 30.6, float(dem[31, 31]) + 1.5
    rng = np.random.default_rng(0)
    cells = rng.integers(2, 62, size=(300, 2))
    agree = 0
    for row, col in cells:
        du, dv = col - u0, row - v0
        t = np.linspace(0.0, 1.0, int(200 * max(abs(du), abs(dv))) + 2)
        u, v = u0 + t * du, v0 + t * dv
        c0 = np.minimum(np.floor(u).astype(int), 62)
        r0 = np.minimum(np.floor(v).astype(int), 62)
        fu, fv = u - c0, v - r0
        z = (dem[r0, c0] * (1 - fu) * (1 - fv) + dem[r0, c0 + 1] * fu * (1 - fv)
             + dem[r0 + 1, c0] * (1 - fu) * fv + dem[r0 + 1, c0 + 1] * fu * fv)  # fmt: skip
        dense = bool((z <= eye + t * (dem[row, col] - eye) + 1e-6).all())
        exact = segment_clear(dem, u0, v0, eye, col, row, 1.0, -1.0, 0.0, 0.0)
        agree += dense == exact
    assert agree >= 297  # (dense sampling may step over a thin crossing)


# --------------------------------------------------------------------------------------------
# the kernel against it
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("seed", "std", "beta", "az_band", "th"),
    [
        (21, 4.0, 1.6, (75.0, 105.0), 0.0),  # 30 deg wedge, rough
        (22, 10.0, 2.0, (200.0, 230.0), 0.0),
        (23, 4.0, 1.6, None, 0.0),  # full circle
        (24, 10.0, 2.0, None, 0.5),
        (25, 4.0, 1.6, (340.0, 20.0), 0.0),  # crossing north
    ],
)
def test_fractal_iou_against_exact_line_of_sight(seed, std, beta, az_band, th):
    n, radius = 448, 200.0
    dem = fractal_dem(n, seed, std=std, beta=beta)
    tr = grid(n)
    x, y = centre_xy(tr, 224.3, 223.8)
    score, _, ref = compare(dem, tr, x, y, radius, az_band, th=th)
    assert ref.sum() > 50
    print(f"IoU {score:.4f}, {int(ref.sum())} visible")
    assert score >= IOU_MIN, f"IoU {score:.4f} against exact line of sight"


@pytest.mark.parametrize("az_band", [None, (60.0, 90.0), (300.0, 330.0)])
def test_real_gale_iou_against_exact_line_of_sight(az_band):
    rasterio = pytest.importorskip("rasterio")
    path = GALE / "dem.tif"
    if not path.is_file():
        pytest.skip(f"real Gale DEM not found at {path} (../shared beside the checkout)")
    with rasterio.open(path) as ds:
        dem = ds.read(1, masked=True).filled(np.nan).astype(np.float32)
        tr = ds.transform
    score, _, ref = compare(dem, tr, *SOL_1051_XY, 150.0, az_band, height=1.9)
    assert ref.sum() > 200
    print(f"IoU {score:.4f}, {int(ref.sum())} visible")
    assert score >= IOU_MIN, f"IoU {score:.4f} against exact line of sight at sol 1051"


def test_oversample_keeps_exactness():
    dem = fractal_dem(256, 31, std=4.0)
    tr = grid(256)
    x, y = centre_xy(tr, 128, 128)
    u0 = v0 = 128.0
    eye = float(dem[128, 128]) + 2.0
    ref = exact_viewshed(dem, u0, v0, eye, 110.0, planet_radius=MARS_RADIUS_M) == 1
    for ov in (1, 2):
        mask = compute_viewshed((dem, tr), x, y, height=2.0, radius=110.0, oversample=ov) == 1
        ref[128, 128] = mask[128, 128]
        assert iou(mask, ref) >= 0.99
