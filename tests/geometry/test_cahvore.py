"""CAHVORE: round trips over whole images, reductions to simpler models, the moving pupil.

The independent checks compute what a CAHVORE camera must do from plain trigonometry
(an equidistant fish-eye, a pupil shift written out from Gennery's formula) or from the
CAHVOR code, which shares nothing with the CAHVORE solver.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.frames import quaternion_to_matrix

W, H = 1024, 1024


def cahvore(
    mtype: int = 3,
    mparm: float = 0.0,
    focal_px: float = 474.0,
    radial: tuple[float, float, float] = (-1.2e-6, 0.12, 0.034),
    entrance: tuple[float, float, float] = (-0.079, 0.183, -0.116),
    size: tuple[int, int] = (W, H),
) -> CameraModel:
    """A body-camera-like CAHVORE model (ROVER_NAV_FRAME, looking forward and down).

    The default R and E are those of a real Mars 2020 fish-eye calibration (LCAM, type 2);
    focal 474 px on 1024 px gives a Hazcam-like ~110 degree field of view.
    """
    a = np.array([1.0, 0.15, 0.45])
    a /= np.linalg.norm(a)
    right = np.cross([0.0, 0.0, 1.0], a)
    right /= np.linalg.norm(right)
    down = np.cross(a, right)
    hc, vc = (size[0] - 1) / 2 + 4.5, (size[1] - 1) / 2 - 3.0
    o = a + 0.004 * right - 0.002 * down
    o /= np.linalg.norm(o)
    return CameraModel(
        "CAHVORE",
        np.array([1.1, 0.4, -0.8]),
        a,
        focal_px * right + hc * a,
        focal_px * down + vc * a,
        o=o,
        r=np.array(radial),
        e=np.array(entrance),
        mtype=mtype,
        mparm=mparm,
    )


MODELS = {
    "hazcam fish-eye (type 2)": cahvore(mtype=2),
    "hazcam general L=0 (type 3)": cahvore(mtype=3, mparm=0.0),
    "general L=-0.4 (type 3)": cahvore(mtype=3, mparm=-0.4, focal_px=420.0),
    "general L=0.5 (type 3)": cahvore(mtype=3, mparm=0.5, focal_px=520.0),
    "navcam perspective (type 1)": cahvore(
        mtype=1, focal_px=1230.0, radial=(1e-5, 0.01, -0.003), entrance=(0.002, 0.01, -0.004)
    ),
}


# Real Mars 2020 CAHVORE models: a Navcam model from an example Mars 2020 PDS4 label (type 2,
# fish-eye linearity, ROVER_NAV_FRAME) and the front-left Hazcam of the m2020-urdf-models
# calibration file (5120 x 3840; its type 3 / linearity 0.37 may be that file's default).
REAL = {
    "m2020 navcam label (type 2)": CameraModel(
        "CAHVORE", c=np.array([0.955584, 0.764515, -1.95254]),
        a=np.array([-0.35631, 0.916392, 0.182443]), h=np.array([-3229.43, 141.993, 229.563]),
        v=np.array([-168.067, 400.716, 3088.89]), o=np.array([-0.357624, 0.915861, 0.182539]),
        r=np.array([1.736e-06, 0.0501396, -0.0171254]), e=np.array([-8.0e-09, 1.0e-08, -2.9e-08]),
        mtype=2, mparm=0.0,
    ),
    "m2020 front hazcam left (type 3, L = 0.37)": CameraModel(
        "CAHVORE", c=np.array([1.103534, -0.008945, -0.729124]),
        a=np.array([0.884935, -0.17181, 0.432865]),
        h=np.array([2606.49053, 1675.438136, 1273.544923]),
        v=np.array([747.819318, -326.899856, 2757.18855]),
        o=np.array([0.885293, -0.171227, 0.432363]), r=np.array([1e-6, 0.00889, -0.006754]),
        e=np.array([-0.006127, 0.010389, 0.004541]), mtype=3, mparm=0.37,
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", list(REAL))
def test_real_models_round_trip_over_their_whole_image(name: str) -> None:
    """The frame is the one centred on the model's principal point (A.H, A.V)."""
    cam = REAL[name]
    width, height = round(2 * cam.hc + 1), round(2 * cam.vc + 1)
    pix = every_pixel(width, height, step=8)
    origins, rays = cam.unproject(pix)
    assert np.all(np.isfinite(rays)) and np.all(np.isfinite(origins)), "unproject diverged"
    for distance in (0.5, 3.0, 100.0):
        back = cam.project(origins + distance * rays)
        assert np.max(np.abs(back - pix)) < 1e-6, (name, distance)
    # the principal point's ray is the axis A (JPL's convention)
    _, axis = cam.unproject(np.array([[cam.hc, cam.vc]]))
    assert float(axis[0] @ cam.a) == pytest.approx(1.0, abs=1e-5)


def every_pixel(width: int = W, height: int = H, step: int = 1) -> np.ndarray:
    """Every ``step``-th pixel centre plus the outer pixel edges (-0.5 and size - 0.5)."""
    xs = np.unique(np.r_[-0.5, np.arange(0, width, step), width - 0.5])
    ys = np.unique(np.r_[-0.5, np.arange(0, height, step), height - 0.5])
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


@pytest.mark.parametrize("name", list(MODELS))
def test_round_trip_below_1e6_px_over_the_whole_image(name: str) -> None:
    cam = MODELS[name]
    pix = every_pixel(step=2 if "navcam" in name else 3)
    origins, rays = cam.unproject(pix)
    assert np.all(np.isfinite(rays)) and np.all(np.isfinite(origins)), "unproject diverged"
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    for distance in (0.2, 1.5, 30.0, 2000.0):
        back = cam.project(origins + distance * rays)
        assert np.all(np.isfinite(back)), (name, distance)
        assert np.max(np.abs(back - pix)) < 1e-6, (name, distance)


def test_every_pixel_of_a_full_image_converges() -> None:
    cam = MODELS["hazcam fish-eye (type 2)"]
    pix = every_pixel()
    assert len(pix) >= W * H
    origins, rays = cam.unproject(pix)
    assert np.all(np.isfinite(rays))
    assert np.max(np.abs(cam.project(origins + 10.0 * rays) - pix)) < 1e-6


@settings(max_examples=150)
@given(
    x=st.floats(-0.5, W - 0.5),
    y=st.floats(-0.5, H - 0.5),
    distance=st.floats(0.05, 5000.0),
    lin=st.floats(-0.9, 1.0),
    e1=st.floats(-0.3, 0.3),
    r1=st.floats(0.0, 0.2),
)
def test_round_trip_anywhere_for_any_linearity(
    x: float, y: float, distance: float, lin: float, e1: float, r1: float
) -> None:
    # a focal length whose image lies inside the model's domain (chi <= 1 / |L| for L < 0)
    focal = max(600.0 if lin > 0.5 else 420.0, 1.2 * np.hypot(W, H) / 2 * max(-lin, 0.0))
    cam = cahvore(mtype=3, mparm=lin, focal_px=focal, radial=(0.0, r1, 0.01),
                  entrance=(0.01, e1, -0.05))  # fmt: skip
    origin, ray = cam.unproject(np.array([[x, y]]))
    assert np.all(np.isfinite(ray))
    back = cam.project(origin + distance * ray)
    assert np.max(np.abs(back - [[x, y]])) < 1e-6


def test_type_1_without_entrance_terms_is_cahvor() -> None:
    """CAHVORE with E = 0 and linearity 1 is CAHVOR (its separate code gives the same)."""
    ore = cahvore(mtype=1, focal_px=1200.0, radial=(2e-4, -0.05, 0.02), entrance=(0, 0, 0))
    cahvor = CameraModel("CAHVOR", ore.c, ore.a, ore.h, ore.v, o=ore.o, r=ore.r)
    rng = np.random.default_rng(3)
    points = ore.c + rng.uniform([2, -3, -1], [40, 3, 4], size=(500, 3))
    np.testing.assert_allclose(ore.project(points), cahvor.project(points), atol=1e-8)
    pix = every_pixel(step=16)
    o1, r1 = ore.unproject(pix)
    o2, r2 = cahvor.unproject(pix)
    np.testing.assert_allclose(r1, r2, atol=1e-12)
    np.testing.assert_allclose(o1, o2, atol=1e-12)


def test_fisheye_without_distortion_is_equidistant() -> None:
    """Type 2, R = E = 0, O = A: the image radius is focal * (angle off the axis)."""
    cam = cahvore(mtype=2, radial=(0, 0, 0), entrance=(0, 0, 0))
    cam = CameraModel("CAHVORE", cam.c, cam.a, cam.h, cam.v, o=cam.a, r=cam.r, e=cam.e, mtype=2)
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    theta = np.arccos(dirs @ cam.a)
    dirs, theta = dirs[theta < np.radians(80)], theta[theta < np.radians(80)]
    pix = cam.project(cam.c + 7.0 * dirs)
    radius = np.hypot(pix[:, 0] - cam.hc, pix[:, 1] - cam.vc)
    np.testing.assert_allclose(radius, cam.hs * theta, rtol=1e-9, atol=1e-7)


def test_ray_origins_follow_the_entrance_pupil() -> None:
    """Each ray starts at C + (theta / sin theta - 1)(e0 + e1 theta^2 + e2 theta^4) O."""
    cam = MODELS["hazcam fish-eye (type 2)"]
    origins, rays = cam.unproject(every_pixel(step=64))
    theta = np.arccos(np.clip(rays @ cam.o, -1.0, 1.0))
    e0, e1, e2 = cam.e
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(theta > 1e-6, theta / np.sin(theta) - 1.0, 0.0)
    expected = cam.c + (ratio * (e0 + e1 * theta**2 + e2 * theta**4))[:, None] * cam.o
    np.testing.assert_allclose(origins, expected, atol=1e-12)
    assert np.ptp(np.linalg.norm(origins - cam.c, axis=1)) > 1e-3  # the pupil does move


def test_beyond_the_linearity_limit_is_nan() -> None:
    """Type 1 (L = 1) sees nothing at or past 90 degrees off the optical axis."""
    cam = MODELS["navcam perspective (type 1)"]
    side = np.cross(cam.o, [0.0, 0.0, 1.0])
    assert np.all(np.isnan(cam.project(cam.c + 3.0 * side - 0.5 * cam.o)))
    assert np.all(np.isnan(cam.project(cam.c - 3.0 * cam.a)))


def test_fov_of_the_fisheye_is_wide() -> None:
    hfov, vfov = MODELS["hazcam fish-eye (type 2)"].fov_deg(W, H)
    assert 100.0 < hfov < 130.0 and 100.0 < vfov < 130.0


def test_rotation_moves_cahvore_rays_with_the_frame() -> None:
    cam = MODELS["general L=-0.4 (type 3)"]
    rot = quaternion_to_matrix([np.cos(0.3), 0.1, 0.0, np.sin(0.3)] / np.linalg.norm(
        [np.cos(0.3), 0.1, 0.0, np.sin(0.3)]))  # fmt: skip
    moved = cam.transformed(rot, np.array([5.0, -2.0, 0.5]), "SITE_FRAME")
    pix = every_pixel(step=128)
    o1, r1 = cam.unproject(pix)
    o2, r2 = moved.unproject(pix)
    np.testing.assert_allclose(r2, r1 @ rot.T, atol=1e-12)
    np.testing.assert_allclose(o2, o1 @ rot.T + [5.0, -2.0, 0.5], atol=1e-12)


@pytest.mark.parametrize("bad", [{"mtype": 4}, {"mtype": 0}, {"e": None}, {"mparm": np.inf}])
def test_invalid_cahvore_is_refused(bad: dict) -> None:
    cam = MODELS["navcam perspective (type 1)"]
    fields = {"o": cam.o, "r": cam.r, "e": cam.e, "mtype": 3, "mparm": 0.0, **bad}
    with pytest.raises(ValueError):
        CameraModel("CAHVORE", cam.c, cam.a, cam.h, cam.v, **fields)
