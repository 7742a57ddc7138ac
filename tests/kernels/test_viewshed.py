"""Viewshed kernel: analytic cases (flat plane, wall, curvature, bands) and the exact
line-of-sight reference (``los_reference``) on fractal DEMs. Map frame: x east, y north
(metres), 1 m cells."""

from __future__ import annotations

import math

import numpy as np
import pytest
from affine import Affine

from mars_pairs.kernels import compute_viewshed
from mars_pairs.raster.terrain import DemWindow
from support.los_reference import exact_viewshed
from support.terrain import X0, Y0, centre_xy, fractal_dem, grid


def cell_geometry(shape, ic, ir, eye, dem, th=0.0, inv2r=0.0):
    """Per-cell horizontal distance (cells), azimuth (deg from north), elevation angle (deg)."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    east, north = cols - ic, ir - rows
    d = np.hypot(east, north)
    az = np.degrees(np.arctan2(east, north)) % 360.0
    el = np.degrees(np.arctan2(dem + th - d**2 * inv2r - eye, d))
    return d, az, el


def near_boundary(d, az, el, radius, az_band, el_band, tol=0.75) -> np.ndarray:
    """Cells whose centre lies within ``tol`` cells of a band or radius boundary (flat plane)."""
    near = np.abs(d - radius) <= tol
    if az_band is not None:
        for edge in az_band:
            ang = np.radians((az - edge + 180.0) % 360.0 - 180.0)
            near |= (np.abs(d * np.sin(ang)) <= tol) & (np.cos(ang) > 0)
    if el_band is not None:
        eye_h = -np.tan(np.radians(el)) * d  # eye height above the plane, per cell
        for edge in el_band:
            if edge < 0:  # the depression angle equals the edge at d_edge = h / tan(-edge)
                near |= np.abs(d - eye_h / np.tan(np.radians(-edge))) <= tol
    return near


def in_band(az, el, d, radius, az_band, el_band) -> np.ndarray:
    """Analytic visibility on flat ground: inside the radius and both bands."""
    ok = d <= radius
    if az_band is not None:
        width = (az_band[1] - az_band[0]) % 360.0
        ok &= ((az - az_band[0]) % 360.0) <= width
    if el_band is not None:
        ok &= (el >= el_band[0]) & (el <= el_band[1])
    return ok


# --------------------------------------------------------------------------------------------
# flat plane: analytic annular sectors
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("az_band", "el_band", "offset"),
    [
        ((30.0, 75.0), (-20.0, -5.0), (0.0, 0.0)),
        ((200.0, 260.0), (-12.0, -2.0), (0.3, -0.2)),
        ((350.0, 10.0), (-25.0, -3.0), (0.0, 0.0)),  # crosses north
        ((87.0, 93.0), (-8.0, -3.0), (0.0, 0.0)),  # Mastcam-like 6 x 5 wedge
        (None, (-15.0, -4.0), (0.0, 0.0)),
        ((100.0, 160.0), None, (0.0, 0.0)),
    ],
)
def test_flat_plane_matches_annular_sector(az_band, el_band, offset):
    n, h, radius = 161, 2.0, 70.0
    dem = np.full((n, n), 50.0, np.float32)
    tr = grid(n)
    ic = ir = n // 2
    x, y = centre_xy(tr, ic + offset[0], ir + offset[1])
    mask = compute_viewshed(
        (dem, tr), x, y, height=h, radius=radius, az_band=az_band, el_band=el_band,
        planet_radius=0.0,
    )  # fmt: skip
    assert mask.dtype == np.uint8 and mask.shape == dem.shape
    d, az, el = cell_geometry(dem.shape, ic + offset[0], ir - offset[1], 52.0, dem)
    expected = in_band(az, el, d, radius, az_band, el_band)
    expected[ir, ic] = mask[ir, ic]  # the observer's own cell is degenerate
    diff = (mask == 1) != expected
    assert expected.sum() > 20
    assert not (diff & ~near_boundary(d, az, el, radius, az_band, el_band)).any()
    assert diff.sum() <= 0.05 * expected.sum() + 4


def test_flat_plane_full_circle():
    n = 121
    dem = np.zeros((n, n), np.float32)
    tr = grid(n)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 60, 60), height=2.0, radius=50.0,
                            planet_radius=0.0)  # fmt: skip
    d, _, _ = cell_geometry(dem.shape, 60, 60, 2.0, dem)
    np.testing.assert_array_equal(mask == 1, d <= 50.0)


def test_band_crossing_north_is_union_of_two_bands():
    dem = fractal_dem(96, 7)
    tr = grid(96)
    kw = {"height": 2.0, "radius": 45.0, "el_band": (-30.0, 10.0)}
    xy = centre_xy(tr, 48, 48)
    both = compute_viewshed((dem, tr), *xy, az_band=(340.0, 20.0), **kw)
    west = compute_viewshed((dem, tr), *xy, az_band=(340.0, 360.0), **kw)
    east = compute_viewshed((dem, tr), *xy, az_band=(0.0, 20.0), **kw)
    np.testing.assert_array_equal(both, west | east)
    assert both.sum() > 0


def test_curvature_horizon_on_flat_plane():
    # on a sphere of radius R an eye h above the ground sees to d = sqrt(2 R h)
    n, big_r, h = 201, 1000.0, 2.0
    dem = np.zeros((n, n), np.float32)
    tr = grid(n)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 100, 100), height=h, radius=99.0,
                            planet_radius=big_r)  # fmt: skip
    d, _, _ = cell_geometry(dem.shape, 100, 100, h, dem)
    horizon = math.sqrt(2 * big_r * h)
    assert mask[(d < horizon - 1.5)].all()
    assert not mask[(d > horizon + 1.5) & (d <= 99)].any()


# --------------------------------------------------------------------------------------------
# occluders
# --------------------------------------------------------------------------------------------
def test_wall_hides_everything_behind_it():
    n = 121
    dem = np.zeros((n, n), np.float32)
    dem[:, 80] = 10.0  # a north-south wall 20 m east of the observer
    tr = grid(n)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 60, 60), height=2.0, radius=55.0,
                            planet_radius=0.0)  # fmt: skip
    assert not mask[:, 81:].any()
    d, _, _ = cell_geometry(dem.shape, 60, 60, 2.0, dem)
    assert mask[:, :80][d[:, :80] <= 55].all()
    assert mask[:, 80][d[:, 80] <= 55].all()  # the wall's face is seen


def test_band_above_horizon_on_flat_plane_sees_nothing():
    n = 101
    dem = np.zeros((n, n), np.float32)
    tr = grid(n)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 50, 50), height=2.0, radius=48.0,
                            el_band=(1.0, 30.0), planet_radius=0.0)  # fmt: skip
    assert mask.sum() == 0


def test_band_above_horizon_sees_only_high_part_of_hill():
    n = 121
    rows, cols = np.mgrid[0:n, 0:n]
    hill = 30.0 * np.exp(-((cols - 100.0) ** 2 + (rows - 60.0) ** 2) / (2 * 6.0**2))
    dem = hill.astype(np.float32)
    tr = grid(n)
    kw = {"height": 2.0, "radius": 58.0, "planet_radius": 0.0}
    up = compute_viewshed((dem, tr), *centre_xy(tr, 60, 60), el_band=(5.0, 60.0), **kw)
    full = compute_viewshed((dem, tr), *centre_xy(tr, 60, 60), **kw)
    _d, _, el = cell_geometry(dem.shape, 60, 60, 2.0, dem)
    assert up.sum() > 10
    assert (dem[up == 1] > 2.0 + np.tan(np.radians(5.0)) * 30).all()  # only high ground
    np.testing.assert_array_equal(up == 1, (full == 1) & (el >= 5.0) & (el <= 60.0))


# --------------------------------------------------------------------------------------------
# fractal DEMs against the exact line-of-sight reference (los_reference)
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("seed", "std", "az_band", "el_band", "th", "big_r"),
    [
        (1, 4.0, None, None, 0.0, 0.0),
        (2, 8.0, (20.0, 140.0), (-30.0, 5.0), 0.0, 0.0),
        (3, 4.0, (300.0, 30.0), (-20.0, 10.0), 0.5, 0.0),
        (4, 6.0, None, (-45.0, 20.0), 0.0, 2000.0),
        (5, 3.0, (150.0, 240.0), None, 1.0, 3396190.0),
    ],
)
def test_fractal_agrees_with_brute_force(seed, std, az_band, el_band, th, big_r):
    n, radius, h = 128, 60.0, 2.0
    dem = fractal_dem(n, seed, std=std)
    tr = grid(n)
    ic = ir = 64
    eye = float(dem[ir, ic]) + h
    inv2r = 0.0 if big_r == 0 else 0.5 / big_r
    mask = compute_viewshed(
        (dem, tr), *centre_xy(tr, ic, ir), height=h, radius=radius, az_band=az_band,
        el_band=el_band, target_height=th, planet_radius=big_r,
    )  # fmt: skip
    ref = exact_viewshed(dem, ic, ir, eye, radius, th=th, planet_radius=big_r)
    d, az, el = cell_geometry(dem.shape, ic, ir, eye, dem, th=th, inv2r=inv2r)
    band = in_band(az, el, d, radius, az_band, el_band)
    band[ir, ic] = False
    assert not mask[~band & (d > 0)].any()  # nothing outside the band is marked
    agree = (mask[band] == ref[band]).mean()
    assert agree >= 0.995, f"agreement {agree:.4f} with exact line of sight"
    assert ref[band].sum() > 0


def test_wedge_equals_full_run_masked_by_band():
    n = 256
    dem = fractal_dem(n, 11, std=6.0)
    tr = grid(n)
    xy = centre_xy(tr, 128, 128)
    full = compute_viewshed((dem, tr), *xy, height=2.0, radius=120.0)
    bands = [((87.0, 93.0), (-9.0, -4.0)), ((355.0, 15.0), (-20.0, 2.0)), ((180.0, 181.0), None)]
    for az_band, el_band in bands:
        wedge = compute_viewshed((dem, tr), *xy, height=2.0, radius=120.0, az_band=az_band,
                                 el_band=el_band)  # fmt: skip
        eye = float(dem[128, 128]) + 2.0
        d, az, el = cell_geometry(dem.shape, 128, 128, eye, dem, inv2r=0.5 / 3396190.0)
        band = in_band(az, el, d, 120.0, az_band, el_band)
        expected = (full == 1) & band
        # (the full circle's tree of rays has its own error bars: both are near-exact)
        assert ((wedge == 1) != expected).sum() <= 2 + 0.005 * expected.sum()


def test_nodata_is_never_visible_and_does_not_block():
    n = 81
    dem = np.zeros((n, n), np.float32)
    dem[:, 50:53] = np.nan
    tr = grid(n)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 40, 40), height=2.0, radius=38.0,
                            planet_radius=0.0)  # fmt: skip
    assert not mask[:, 50:53].any()
    assert mask[40, 60:78].all()


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------
def test_input_forms_agree_and_absolute_height():
    dem = fractal_dem(64, 3)
    tr = grid(64)
    xy = centre_xy(tr, 30, 33)
    a = compute_viewshed((dem, tr), *xy, height=2.0, radius=30.0)
    b = compute_viewshed(dem, *xy, transform=tuple(tr)[:6], height=2.0, radius=30.0)
    c = compute_viewshed(DemWindow(dem, tr, None), *xy, height=2.0, radius=30.0)
    d = compute_viewshed((dem, tr), *xy, height=float(dem[33, 30]) + 2.0,
                         height_is_absolute=True, radius=30.0)  # fmt: skip
    for other in (b, c, d):
        np.testing.assert_array_equal(a, other)


def test_invalid_inputs_raise():
    dem = np.zeros((32, 32), np.float32)
    tr = grid(32)
    with pytest.raises(ValueError, match="rotated"):
        compute_viewshed((dem, Affine(1, 0.1, X0, 0, -1, Y0)), X0 + 5, Y0 - 5, height=2,
                         radius=10)  # fmt: skip
    with pytest.raises(ValueError, match="outside"):
        compute_viewshed((dem, tr), X0 - 50, Y0 - 5, height=2, radius=10)
    dem[5, 5] = np.nan
    with pytest.raises(ValueError, match="no DEM data"):
        compute_viewshed((dem, tr), *centre_xy(tr, 5, 5), height=2, radius=10)
    with pytest.raises(ValueError, match="elevation band"):
        compute_viewshed((dem, tr), *centre_xy(tr, 9, 9), height=2, radius=10, el_band=(5, -5))


def test_observer_near_window_edge():
    dem = fractal_dem(64, 9)
    tr = grid(64)
    mask = compute_viewshed((dem, tr), *centre_xy(tr, 1, 62), height=2.0, radius=100.0)
    assert mask[62, 1] == 1 and mask.sum() > 50


def test_tail_quad_test_agrees_with_the_general_segment_test():
    # the kernel's one-quad test of a sight line's last grid-line gap against the general
    # piecewise test over the same stretch: observers anywhere (edges included), any target
    from mars_pairs.kernels.viewshed import _segment_clear, _tail_clear

    rng = np.random.default_rng(5)
    n = 24
    flat = (rng.normal(0.0, 1.0, (n, n)).cumsum(axis=1) * 0.4).astype(np.float32).reshape(-1)
    inv2r = 0.5 / 3396190.0
    a, e = 1.0, -1.0
    blocked = 0
    for _ in range(4000):
        u0, v0 = rng.uniform(-0.5, n - 0.5, 2)
        col, row = (int(c) for c in rng.integers(0, n, 2))
        du, dv = col - u0, row - v0
        umaj = abs(du) >= abs(dv)
        n_maj = abs(du) if umaj else abs(dv)
        if n_maj < 0.5:
            continue
        t0 = max(0.0, 1.0 - 1.0 / n_maj)
        eye = float(flat[math.floor(v0 + 0.5) * n + math.floor(u0 + 0.5)]) + rng.uniform(0, 2)
        dc2 = (du * a) ** 2 + (dv * e) ** 2
        zt = float(flat[row * n + col]) - dc2 * inv2r
        args = (flat, n, n, u0, v0, col, row, a, e, eye, zt, inv2r)
        tail = _tail_clear(*args, dc2, umaj, t0)
        assert tail == _segment_clear(*args, t0, 1.0), (u0, v0, col, row)
        blocked += not tail
    assert blocked > 100  # the cases include blocked tails
