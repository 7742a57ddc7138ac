"""Ray casting kernel: analytic planes, misses, curvature, block skipping, viewshed consistency.
Map frame: x east, y north (metres), z up (metres); 1 m cells."""

from __future__ import annotations

import numpy as np
import pytest

from mars_pairs.kernels import cast_rays, compute_viewshed
from mars_pairs.kernels.raycast import max_pyramid
from support.los_reference import exact_viewshed
from support.terrain import X0, Y0, bilinear_np, centre_xy, fractal_dem, grid


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cone(n: int, seed: int, dz_range=(-0.9, -0.05)) -> np.ndarray:
    """Random unit directions pointing down between the given z components."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n)
    dz = rng.uniform(*dz_range, n)
    hor = np.sqrt(1 - dz**2)
    return np.column_stack([hor * np.sin(az), hor * np.cos(az), dz])


def test_flat_plane_hits_exactly():
    n = 101
    dem = np.full((n, n), 100.0, np.float32)
    tr = grid(n)
    x, y = centre_xy(tr, 50.3, 49.7)
    dirs = _cone(500, 1)
    origins = np.tile([x, y, 102.0], (len(dirs), 1))
    hits, ranges = cast_rays(origins, dirs, (dem, tr), max_range=500.0, planet_radius=0.0)
    t = 2.0 / -dirs[:, 2]
    inside = (np.abs(t * dirs[:, 0]) < 48) & (np.abs(t * dirs[:, 1]) < 48)
    np.testing.assert_allclose(ranges[inside], t[inside], atol=1e-6)
    np.testing.assert_allclose(hits[inside], origins[inside] + t[inside, None] * dirs[inside],
                               atol=1e-6)  # fmt: skip
    assert inside.sum() > 300
    assert np.isnan(ranges[~inside & (np.abs(t * dirs[:, 0]) > 52)]).all()  # left the window


def test_upward_and_horizontal_rays_miss():
    dem = fractal_dem(64, 2)
    tr = grid(64)
    x, y = centre_xy(tr, 32, 32)
    z = float(dem[32, 32]) + 2.0
    dirs = _unit(np.array([[0.3, 0.2, 0.5], [0, 0, 1], [1, 0, 0.6], [-0.5, 0.5, 0.7]]))
    hits, ranges = cast_rays(np.tile([x, y, z], (4, 1)), dirs, (dem, tr), max_range=1e4)
    assert np.isnan(hits).all() and np.isnan(ranges).all()
    flat = np.zeros((64, 64), np.float32)
    _, r = cast_rays([[x, y, 2.0]], [[1.0, 0.0, 0.0]], (flat, tr), max_range=1e4,
                     planet_radius=0.0)  # fmt: skip
    assert np.isnan(r).all()


def test_inclined_plane_hits_exactly():
    n = 121
    rows, cols = np.mgrid[0:n, 0:n]
    xs, ys = grid(n) @ (cols + 0.5, rows + 0.5)
    gx, gy, z0 = 0.12, -0.07, 250.0
    dem = (z0 + gx * (xs - X0) + gy * (ys - Y0)).astype(np.float64)
    dem32 = dem.astype(np.float32)
    tr = grid(n)
    x, y = centre_xy(tr, 60, 60)
    zo = z0 + gx * (x - X0) + gy * (y - Y0) + 3.0
    dirs = _cone(400, 3, (-0.8, -0.15))
    origins = np.tile([x, y, zo], (len(dirs), 1))
    hits, ranges = cast_rays(origins, dirs, (dem32, tr), max_range=300.0, planet_radius=0.0)
    # plane z = z0 + gx (x - X0) + gy (y - Y0): solve o_z + t d_z = plane(o + t d)
    t = 3.0 / (gx * dirs[:, 0] + gy * dirs[:, 1] - dirs[:, 2])
    ok = np.isfinite(ranges)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(ranges[ok], t[ok], atol=2e-3)  # float32 DEM rounding
    plane = z0 + gx * (hits[ok, 0] - X0) + gy * (hits[ok, 1] - Y0)
    np.testing.assert_allclose(hits[ok, 2], plane, atol=2e-3)


def test_curvature_lowers_distant_terrain():
    n, big_r = 201, 2000.0
    dem = np.zeros((n, n), np.float32)
    tr = grid(n)
    x, y = centre_xy(tr, 100, 100)
    dz = -0.06
    d = _unit(np.array([[1.0, 0.0, dz]]))
    _, r = cast_rays([[x, y, 2.0]], d, (dem, tr), max_range=500.0, planet_radius=big_r)
    # 2 + s dz' = -(s h)^2 / (2R) with s along the ray, h = horizontal fraction
    a, b, c = d[0, 0] ** 2 / (2 * big_r), d[0, 2], 2.0
    s = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
    np.testing.assert_allclose(r[0], s, atol=1e-5)
    _, flat_r = cast_rays([[x, y, 2.0]], d, (dem, tr), max_range=500.0, planet_radius=0.0)
    assert r[0] > flat_r[0]  # the curving ground drops away: the hit comes later


def test_misses_nodata_range_and_underground():
    n = 81
    dem = np.zeros((n, n), np.float32)
    dem[:, 55:] = np.nan
    tr = grid(n)
    x, y = centre_xy(tr, 40, 40)
    d = _unit(np.array([[1.0, 0.0, -0.05], [1.0, 0.0, -0.2], [-1.0, 0.0, -0.2]]))
    _, r = cast_rays(np.tile([x, y, 2.0], (3, 1)), d, (dem, tr), max_range=100.0,
                     planet_radius=0.0)  # fmt: skip
    assert np.isnan(r[0])  # would land at 40 m, beyond the nodata edge at ~15 m
    assert np.isfinite(r[1]) and np.isfinite(r[2])
    _, r = cast_rays(np.tile([x, y, 2.0], (3, 1)), d, (dem, tr), max_range=5.0,
                     planet_radius=0.0)  # fmt: skip
    assert np.isnan(r).all()  # hits are ~10 m away
    _, r = cast_rays([[x, y, -1.0]], [[0.0, 0.0, -1.0]], (dem, tr), max_range=10.0)
    assert np.isnan(r).all()


def _march_reference(dem, tr, o, d, max_range, step=0.05):
    """Plain dense march (no block skipping), first sample below the surface."""
    t = np.arange(step, max_range, step)
    p = o[None, :] + t[:, None] * d[None, :]
    u, v = (p[:, 0] - tr.c) / tr.a - 0.5, (p[:, 1] - tr.f) / tr.e - 0.5
    inside = (u >= 0) & (v >= 0) & (u <= dem.shape[1] - 1) & (v <= dem.shape[0] - 1)
    below = inside & (p[:, 2] <= bilinear_np(dem, u, v))
    first_out = np.argmin(inside) if not inside.all() else len(t)
    idx = np.argmax(below)
    return t[idx] if below.any() and idx < first_out else np.nan


def test_block_skipping_matches_dense_march():
    n = 160
    dem = fractal_dem(n, 21, std=6.0).astype(np.float32)
    tr = grid(n)
    x, y = centre_xy(tr, 80, 80)
    o = np.array([x, y, float(dem[80, 80]) + 2.0])
    dirs = _cone(200, 5, (-0.4, 0.02))
    _, r = cast_rays(np.tile(o, (len(dirs), 1)), dirs, (dem, tr), max_range=150.0,
                     planet_radius=0.0)  # fmt: skip
    ref = np.array([_march_reference(dem, tr, o, dd, 150.0) for dd in dirs])
    same = (np.isnan(r) & np.isnan(ref)) | (np.abs(r - ref) <= 0.1)
    assert same.mean() >= 0.98
    assert np.isfinite(r).sum() > 100


@pytest.mark.parametrize("seed", [31, 32, 33])
def test_ray_hits_are_visible_in_viewshed(seed):
    # gentle fractal: a ray's hit point is visible by construction, so its cell should be too
    n = 200
    dem = fractal_dem(n, seed, std=1.0)
    tr = grid(n)
    x, y = centre_xy(tr, 100, 100)
    o = np.array([x, y, float(dem[100, 100]) + 2.0])
    dirs = _cone(4000, seed, (-0.7, -0.03))
    hits, _ = cast_rays(np.tile(o, (len(dirs), 1)), dirs, (dem, tr), max_range=200.0)
    hits = hits[np.isfinite(hits[:, 0])]
    cols = np.floor((hits[:, 0] - tr.c) / tr.a).astype(int)
    rows = np.floor((hits[:, 1] - tr.f) / tr.e).astype(int)
    vs = compute_viewshed((dem, tr), x, y, height=2.0, radius=99.0)
    inside = np.hypot(cols - 100, rows - 100) <= 98
    assert inside.sum() > 3000
    # (a hit point is seen; its cell's centre may sit just behind a crest, or on a face turned
    # away, which the exact cell-centre sight line then rightly hides)
    assert vs[rows[inside], cols[inside]].mean() >= 0.97


def test_hit_cells_on_rough_terrain_match_brute_force():
    # on rough terrain a visible surface point can sit in a cell whose centre is hidden; the
    # viewshed must still agree with brute-force line of sight on those cells
    n = 200
    dem = fractal_dem(n, 31, std=5.0)
    tr = grid(n)
    x, y = centre_xy(tr, 100, 100)
    eye = float(dem[100, 100]) + 2.0
    dirs = _cone(3000, 31, (-0.7, -0.03))
    hits, _ = cast_rays(np.tile([x, y, eye], (len(dirs), 1)), dirs, (dem, tr), max_range=200.0,
                        planet_radius=0.0)  # fmt: skip
    hits = hits[np.isfinite(hits[:, 0])]
    cols = np.floor((hits[:, 0] - tr.c) / tr.a).astype(int)
    rows = np.floor((hits[:, 1] - tr.f) / tr.e).astype(int)
    inside = np.hypot(cols - 100, rows - 100) <= 98
    vs = compute_viewshed((dem, tr), x, y, height=2.0, radius=99.0, planet_radius=0.0)
    ref = exact_viewshed(dem, 100, 100, eye, 99.0)
    r, c = rows[inside], cols[inside]
    assert vs[r, c].mean() >= 0.95
    assert (vs[r, c] == ref[r, c]).mean() >= 0.99


def test_shapes_and_empty_input():
    dem = np.zeros((16, 16), np.float32)
    tr = grid(16)
    hits, ranges = cast_rays(np.empty((0, 3)), np.empty((0, 3)), (dem, tr), max_range=10.0)
    assert hits.shape == (0, 3) and ranges.shape == (0,)
    with pytest.raises(ValueError, match="differ in shape"):
        cast_rays(np.zeros((2, 3)), np.zeros((3, 3)), (dem, tr), max_range=10.0)


def test_grazing_rays_match_dense_march_over_long_ranges():
    # near-horizontal rays cross many pyramid levels before they land (or leave the window)
    n = 600
    dem = fractal_dem(n, 41, std=8.0, beta=2.0)
    tr = grid(n)
    x, y = centre_xy(tr, 300.4, 299.8)
    o = np.array([x, y, float(dem[300, 300]) + 2.0])
    dirs = _cone(60, 41, (-0.03, 0.01))
    _, r = cast_rays(np.tile(o, (len(dirs), 1)), dirs, (dem, tr), max_range=420.0,
                     planet_radius=0.0)  # fmt: skip
    ref = np.array([_march_reference(dem, tr, o, dd, 420.0, step=0.02) for dd in dirs])
    same = (np.isnan(r) & np.isnan(ref)) | (np.abs(r - ref) <= 0.05)
    assert same.mean() >= 0.95
    assert np.isfinite(r).sum() >= 15 and (np.nan_to_num(r) > 50).sum() >= 5


def test_max_pyramid_bounds_quads_and_is_reusable():
    n = 75
    dem = fractal_dem(n, 12, std=5.0)
    dem[40, 17] = np.nan
    tr = grid(n)
    pyr = max_pyramid((dem, tr))
    quad = np.maximum.reduce([dem[:-1, :-1], dem[:-1, 1:], dem[1:, :-1], dem[1:, 1:]])
    quad = np.where(np.isnan(quad), np.inf, quad)  # np.maximum propagates NaN
    for k in range(2, pyr.n_levels + 1):
        hk, wk = pyr.dims[k]
        level = pyr.data[pyr.offsets[k] : pyr.offsets[k] + hk * wk].reshape(hk, wk)
        b = 2**k
        for j in range(hk):
            for i in range(wk):
                want = quad[j * b : (j + 1) * b, i * b : (i + 1) * b].max()
                assert level[j, i] == want
    x, y = centre_xy(tr, 37, 37)
    o = np.tile([x, y, float(np.nanmax(dem)) + 1.0], (300, 1))
    dirs = _cone(300, 12, (-0.6, -0.02))
    plain = cast_rays(o, dirs, (dem, tr), max_range=200.0)
    given = cast_rays(o, dirs, (dem, tr), max_range=200.0, pyramid=pyr)
    np.testing.assert_array_equal(plain[1], given[1])
    np.testing.assert_array_equal(plain[0], given[0])
    with pytest.raises(ValueError, match="pyramid"):
        cast_rays(o, dirs, (dem[:-1], tr), max_range=200.0, pyramid=pyr)
