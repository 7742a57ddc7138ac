"""One hillshade: the synthetic ortho's and the pictures' shading are lambert_shading."""

from __future__ import annotations

import numpy as np

from mars_pairs.raster.shading import lambert_shading
from mars_pairs.synth.terrain import hillshade as synth_hillshade
from mars_pairs.viz.common import hillshade as picture_hillshade


def slope_aspect_shading(z: np.ndarray, res: float, azimuth: float, altitude: float) -> np.ndarray:
    """The textbook slope/aspect form (an independent derivation): sin(alt) cos(slope) +
    cos(alt) sin(slope) cos(azimuth - aspect), aspect the downhill direction from north."""
    gy, gx = np.gradient(z, res)  # rows go south
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, alt = np.radians(azimuth), np.radians(altitude)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.clip(shade, 0, None)


def test_lambert_shading_is_the_slope_aspect_form() -> None:
    z = np.random.default_rng(0).normal(0, 3, (40, 50)).cumsum(0).cumsum(1)
    for azimuth, altitude in ((315, 35), (90, 10), (200, 60)):
        got = lambert_shading(z, 2.0, azimuth, altitude)
        np.testing.assert_allclose(got, slope_aspect_shading(z, 2.0, azimuth, altitude), atol=1e-12)


def test_a_slope_facing_the_light_is_lit_and_flat_ground_is_sin_elevation() -> None:
    east = np.tile(np.arange(20.0), (20, 1))  # rises to the east: faces west
    assert np.isclose(lambert_shading(east, 1.0, 270, 45)[5, 5], 1.0)  # sun along the normal
    assert lambert_shading(east, 1.0, 90, 30)[5, 5] == 0.0  # faces away from an east sun
    flat = lambert_shading(np.zeros((5, 5)), 1.0, 10, 30)
    np.testing.assert_allclose(flat, 0.5)


def test_the_synthetic_ortho_and_the_pictures_share_it() -> None:
    z = np.random.default_rng(1).normal(0, 1, (30, 30)).cumsum(1)
    np.testing.assert_array_equal(
        synth_hillshade(z, 1.5, 300, 32), lambert_shading(z, 1.5, 300, 32) / np.sin(np.radians(32))
    )
    holed = z.copy()
    holed[3, 4] = np.nan
    shown = picture_hillshade(holed, 1.5, 300, 32)
    assert np.isnan(shown[3, 4]) and np.isfinite(np.delete(shown.ravel(), 3 * 30 + 4)).all()
    np.testing.assert_array_equal(shown[20:, 20:], lambert_shading(z, 1.5, 300, 32)[20:, 20:])
