"""The view's compiled frustum test keeps the points and cells the numpy path keeps."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.pipeline.sample.view import AnchoredView, in_view, view_mask
from mars_pairs.raster.terrain import DemWindow

X0, Y0 = 4351200.0, 1095210.0


def _camera(kind: str) -> CameraModel:
    """A camera 2 m up looking north-east and 20 degrees down (NED metres, 200 x 150 px)."""
    az, el = np.radians(45.0), np.radians(-20.0)
    a = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
    right = np.array([-np.sin(az), np.cos(az), 0.0])
    down = np.cross(a, right)
    f, cx, cy = 180.0, 99.5, 74.5
    extra = {}
    if kind == "CAHVOR":
        extra = {"o": a, "r": np.array([0.0, -0.08, 0.01])}
    return CameraModel(kind, c=np.array([0.0, 0.0, -2.0]), a=a, h=f * right + cx * a,
                       v=f * down + cy * a, **extra)  # fmt: skip


def _view(kind: str, mode: str = "frustum") -> AnchoredView:
    jacobian = np.array([[0.02, 1.05, 0.0], [0.999, -0.03, 0.0], [0.0, 0.0, -1.0]])
    camera = MapCamera(_camera(kind), np.array([X0, Y0, -2500.0]), jacobian, "", 200, 150)
    rng = np.random.default_rng(1)
    heights = (-2500.0 + rng.normal(0.0, 1.5, (120, 120))).astype(np.float32)
    heights[:5, :7] = np.nan
    window = DemWindow(heights, Affine(1.0, 0.0, X0 - 60.0, 0.0, -1.0, Y0 + 60.0), None)
    return AnchoredView(camera, 2.0, 0.0, window, 50.0, mode, ((0.0, 90.0), (-60.0, 5.0)))


def _numpy_keep(points: np.ndarray, view: AnchoredView) -> np.ndarray:
    camera = view.camera
    local = camera.local_points(points, MARS_RADIUS_M)
    rel = local - camera.map_to_local(camera.center_map)
    return (np.hypot(rel[:, 0], rel[:, 1]) <= view.radius_m) & camera.local_in_image(local)


@pytest.mark.parametrize("kind", ["CAHV", "CAHVOR"])
def test_compiled_in_view_keeps_what_the_numpy_test_keeps(kind):
    view = _view(kind)
    rng = np.random.default_rng(2)
    points = np.column_stack([
        X0 + rng.uniform(-70.0, 70.0, 20000), Y0 + rng.uniform(-70.0, 70.0, 20000),
        -2500.0 + rng.uniform(-10.0, 5.0, 20000),
    ])  # fmt: skip
    points[:50, 2] = np.nan
    expected = _numpy_keep(points, view)
    assert 0.02 < expected.mean() < 0.5  # some points in view, most not
    np.testing.assert_array_equal(in_view(points, view), expected)


@pytest.mark.parametrize("kind", ["CAHV", "CAHVOR"])
@pytest.mark.parametrize("dtype", [np.uint8, np.bool_])
def test_view_mask_tests_each_selected_cell_centre_at_its_height(kind, dtype):
    view = _view(kind)
    window = view.window
    selected = (np.random.default_rng(3).random(window.shape) < 0.7).astype(dtype)
    got = view_mask(selected, window.data, window.transform, view)
    rows, cols = np.nonzero(selected)
    x, y = window.colrow_to_xy(cols, rows)
    keep = _numpy_keep(np.column_stack([x, y, window.data[rows, cols].astype(np.float64)]), view)
    expected = np.zeros(window.shape, dtype=np.uint8)
    expected[rows[keep], cols[keep]] = 1
    assert got.dtype == np.uint8 and expected.sum() > 100
    np.testing.assert_array_equal(got, expected)


def test_band_mode_is_not_the_frustum_test():
    band, frustum = _view("CAHV", "band"), _view("CAHV")
    window = band.window
    selected = np.ones(window.shape, dtype=np.uint8)
    by_band = view_mask(selected, window.data, window.transform, band)
    by_frustum = view_mask(selected, window.data, window.transform, frustum)
    assert by_band.sum() > 0 and not np.array_equal(by_band, by_frustum)
