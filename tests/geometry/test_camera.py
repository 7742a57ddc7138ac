"""CAHV / CAHVOR projection and unprojection on generated cameras."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mars_pairs.geometry.camera import CameraModel, cross3
from mars_pairs.geometry.frames import quaternion_to_matrix


def make_camera(
    kind: str = "CAHVOR",
    focal_px: float = 4500.0,
    width: int = 1152,
    height: int = 432,
    radial: tuple[float, float, float] = (-1.5e-4, -0.139, -1.25),
    yaw_deg: float = 20.0,
) -> CameraModel:
    """A mast-camera-like model looking mostly forward (ROVER_NAV_FRAME, z down)."""
    yaw = np.radians(yaw_deg)
    a = np.array([np.cos(yaw), np.sin(yaw), 0.1])
    a /= np.linalg.norm(a)
    right = np.cross([0.0, 0.0, 1.0], a)
    right /= np.linalg.norm(right)
    down = np.cross(a, right)
    hc, vc = (width - 1) / 2 + 3.2, (height - 1) / 2 - 2.1
    h = focal_px * right + hc * a
    v = focal_px * down + vc * a
    o = a + np.array([0.002, -0.001, 0.0015])
    o /= np.linalg.norm(o)
    c = np.array([0.82, 0.43, -1.97])
    if kind == "CAHV":
        return CameraModel("CAHV", c, a, h, v)
    return CameraModel("CAHVOR", c, a, h, v, o=o, r=np.array(radial))


@pytest.mark.parametrize("kind", ["CAHV", "CAHVOR"])
def test_round_trip_over_the_whole_image(kind: str) -> None:
    cam = make_camera(kind)
    xs, ys = np.meshgrid(np.linspace(-0.5, 1151.5, 41), np.linspace(-0.5, 431.5, 17))
    pix = np.stack([xs.ravel(), ys.ravel()], axis=-1)
    origins, rays = cam.unproject(pix)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    back = cam.project(origins + 37.0 * rays)
    assert np.max(np.abs(back - pix)) < 1e-6


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-0.5, 1151.5),
    y=st.floats(-0.5, 431.5),
    rng=st.floats(0.5, 5000.0),
    r1=st.floats(-0.3, 0.3),
    r2=st.floats(-2.0, 2.0),
)
def test_cahvor_inverse_converges_anywhere_in_the_image(
    x: float, y: float, rng: float, r1: float, r2: float
) -> None:
    cam = make_camera("CAHVOR", radial=(1e-4, r1, r2))
    origin, ray = cam.unproject(np.array([[x, y]]))
    back = cam.project(origin + rng * ray)
    assert np.all(np.isfinite(back))
    assert np.max(np.abs(back - [[x, y]])) < 1e-6


def test_cahv_projection_is_the_pinhole_formula() -> None:
    cam = make_camera("CAHV")
    p = np.array([10.0, 3.0, -1.0])
    d = p - cam.c
    expected = [d @ cam.h / (d @ cam.a), d @ cam.v / (d @ cam.a)]
    np.testing.assert_allclose(cam.project(p), expected, rtol=1e-12)
    # the axis projects onto the image centre (A.H, A.V)
    np.testing.assert_allclose(cam.project(cam.c + 5 * cam.a), [cam.hc, cam.vc], atol=1e-9)


def test_points_behind_the_camera_are_nan() -> None:
    cam = make_camera("CAHVOR")
    assert np.all(np.isnan(cam.project(cam.c - 3 * cam.a)))


def test_fov_of_a_pinhole_matches_the_focal_length() -> None:
    cam = make_camera("CAHV", focal_px=4000.0, width=1600, height=1200)
    hfov, vfov = cam.fov_deg(1600, 1200)
    # centre offset by (3.2, -2.1) px shifts the edges but barely changes the full angle
    assert hfov == pytest.approx(2 * np.degrees(np.arctan(800 / 4000)), rel=1e-4)
    assert vfov == pytest.approx(2 * np.degrees(np.arctan(600 / 4000)), rel=1e-4)


def test_rotation_moves_rays_with_the_frame() -> None:
    cam = make_camera("CAHVOR")
    rot = quaternion_to_matrix([np.cos(0.4), 0.0, 0.0, np.sin(0.4)])
    moved = cam.transformed(rot, np.array([5.0, -2.0, 0.5]), "SITE_FRAME")
    pix = np.array([[100.0, 50.0], [900.0, 400.0]])
    o1, r1 = cam.unproject(pix)
    o2, r2 = moved.unproject(pix)
    np.testing.assert_allclose(r2, r1 @ rot.T, atol=1e-12)
    np.testing.assert_allclose(o2, o1 @ rot.T + [5.0, -2.0, 0.5], atol=1e-12)
    assert moved.frame == "SITE_FRAME"


def test_scaled_model_follows_a_resampled_image() -> None:
    cam = make_camera("CAHVOR")
    half = cam.scaled(0.5, 0.5)
    p = np.array([[30.0, 4.0, 1.0], [12.0, -3.0, 0.2]])
    full_px = cam.project(p)
    np.testing.assert_allclose(half.project(p), 0.5 * (full_px + 0.5) - 0.5, atol=1e-9)


def test_unknown_model_type_is_refused() -> None:
    with pytest.raises(ValueError, match="unsupported"):
        CameraModel("PINHOLE", np.zeros(3), np.ones(3), np.ones(3), np.ones(3))


@pytest.mark.parametrize("kind", ["CAHV", "CAHVOR", "CAHVORE"])
@pytest.mark.parametrize("factor", [(0.5, 0.5), (0.25, 0.25), (1 / 3, 0.5), (2.0, 2.0)])
def test_scaled_model_is_the_camera_of_the_resized_image(
    kind: str, factor: tuple[float, float]
) -> None:
    """Resizing the image by (sx, sy) moves pixel edges: x' + 0.5 = sx (x + 0.5). The scaled
    model must put every 3-D point there, and give the same ray for the moved pixel."""
    base = make_camera("CAHVOR" if kind == "CAHVORE" else kind)
    cam = base
    if kind == "CAHVORE":
        cam = CameraModel("CAHVORE", base.c, base.a, base.h, base.v, o=base.o, r=base.r,
                          e=np.array([0.01, 0.05, -0.02]), mtype=3, mparm=0.3)  # fmt: skip
    sx, sy = factor
    small = cam.scaled(sx, sy)
    rng = np.random.default_rng(11)
    _, rays = cam.unproject(rng.uniform([0, 0], [1151, 431], size=(300, 2)))
    points = cam.c + rng.uniform(2.0, 80.0, size=(300, 1)) * rays
    full = cam.project(points)
    expected = np.stack([sx * (full[:, 0] + 0.5) - 0.5, sy * (full[:, 1] + 0.5) - 0.5], axis=-1)
    np.testing.assert_allclose(small.project(points), expected, atol=1e-7)
    o_full, r_full = cam.unproject(full)
    o_small, r_small = small.unproject(expected)
    np.testing.assert_allclose(r_small, r_full, atol=1e-10)
    np.testing.assert_allclose(o_small, o_full, atol=1e-10)
    assert small.model_type == cam.model_type and small.frame == cam.frame


def test_cross3_is_numpys_cross_bit_for_bit() -> None:
    """The camera's cross product gives np.cross's bits, broadcast over leading axes."""
    rng = np.random.default_rng(11)
    f = rng.normal(size=(500, 3)) * 10.0 ** rng.integers(-6, 6, size=(500, 1))
    g = rng.normal(size=(500, 3))
    assert np.array_equal(cross3(f, g), np.cross(f, g))
    assert np.array_equal(cross3(f[0], g), np.cross(f[0], g))
    assert np.array_equal(cross3(np.array([1.0, 0, 0]), np.array([0.0, 1, 0])), [0.0, 0, 1])
