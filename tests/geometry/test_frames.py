"""Quaternions, tangent frames and map projections against independent formulas."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mars_pairs.geometry.frames import (
    M2020_PLACES_CRS,
    MARS_RADIUS_M,
    MSL_PLACES_CRS,
    TangentFrame,
    azimuth_elevation_deg,
    direction_from_az_el,
    local_map_jacobian,
    lonlat_to_map,
    map_to_lonlat,
    map_to_map,
    matrix_to_quaternion,
    ned_to_map,
    quaternion_to_matrix,
)

quats = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).filter(lambda q: np.linalg.norm(q) > 0.1)


@settings(max_examples=100, deadline=None)
@given(quats)
def test_quaternion_matrix_is_a_rotation_and_round_trips(q: tuple[float, ...]) -> None:
    r = quaternion_to_matrix(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(r)), r, atol=1e-9)


def test_yaw_quaternion_turns_forward_to_the_heading() -> None:
    # a rover yawed 90 degrees (facing east): its forward axis is east in the site frame
    half = np.radians(90.0) / 2
    r = quaternion_to_matrix([np.cos(half), 0, 0, np.sin(half)])
    np.testing.assert_allclose(r @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)
    az, el = azimuth_elevation_deg(r @ [1.0, 0, 0])
    assert az == pytest.approx(90.0) and el == pytest.approx(0.0)


def test_az_el_round_trip() -> None:
    az = np.array([0.0, 45.0, 181.0, 359.5])
    el = np.array([-30.0, 0.0, 12.0, 80.0])
    a2, e2 = azimuth_elevation_deg(direction_from_az_el(az, el))
    np.testing.assert_allclose(a2, az, atol=1e-9)
    np.testing.assert_allclose(e2, el, atol=1e-9)


def test_tangent_frame_round_trip_and_curvature() -> None:
    frame = TangentFrame(77.45, 18.44, -2569.9)
    ned = np.array([[100.0, -250.0, 3.0], [4000.0, 3000.0, -20.0]])
    lon, lat, h = frame.ned_to_lonlat(ned)
    np.testing.assert_allclose(frame.lonlat_to_ned(lon, lat, h), ned, atol=1e-6)
    # 5 km along the tangent plane rises d^2 / 2R above the sphere
    _, _, h5 = frame.ned_to_lonlat(np.array([5000.0, 0.0, 0.0]))
    assert h5 - (-2569.9) == pytest.approx(5000.0**2 / (2 * MARS_RADIUS_M), rel=1e-3)


def test_m2020_places_projection_matches_design_formula() -> None:
    lat, lon = 18.444795784, 77.452019258
    x, y = lonlat_to_map(lon, lat, M2020_PLACES_CRS)
    assert y == pytest.approx(MARS_RADIUS_M * np.radians(lat), abs=1e-3)
    assert x == pytest.approx(
        MARS_RADIUS_M * np.radians(lon) * np.cos(np.radians(18.4663)), abs=1e-3
    )
    lon2, lat2 = map_to_lonlat(x, y, M2020_PLACES_CRS)
    assert (lon2, lat2) == pytest.approx((lon, lat), abs=1e-10)


def test_gale_scale_factor_is_three_metres_per_kilometre() -> None:
    jac = local_map_jacobian(137.4, -4.6, MSL_PLACES_CRS)
    assert jac[0, 1] == pytest.approx(1 / np.cos(np.radians(4.6)), rel=1e-6)  # east stretch
    assert jac[1, 0] == pytest.approx(1.0, rel=1e-9)  # north true to scale
    assert (jac[0, 1] - 1) * 1000 == pytest.approx(3.2, abs=0.1)


def test_ned_to_map_moves_a_kilometre_east_by_the_scaled_easting() -> None:
    out = ned_to_map(np.array([0.0, 1000.0, 0.0]), 137.4, -4.6, -4500.0, MSL_PLACES_CRS)
    x0, y0 = lonlat_to_map(137.4, -4.6, MSL_PLACES_CRS)
    # 1 km at 4.5 km below the sphere spans R / (R - 4500) km of it, stretched by 1 / cos(lat)
    expected = 1000.0 / np.cos(np.radians(4.6)) * MARS_RADIUS_M / (MARS_RADIUS_M - 4500.0)
    assert out[0] - x0 == pytest.approx(expected, abs=0.01)
    assert out[1] - y0 == pytest.approx(0.0, abs=0.2)  # great circle bends off the parallel


def test_the_same_point_has_different_eastings_in_jezero_crses() -> None:
    ts0 = M2020_PLACES_CRS.replace("+lat_ts=18.4663", "+lat_ts=0")
    x, y = map_to_map(4354557.816, 1093309.691, M2020_PLACES_CRS, ts0)
    assert x == pytest.approx(4354557.816 / np.cos(np.radians(18.4663)), rel=1e-9)
    assert y == pytest.approx(1093309.691)


def test_site_frame_levels_differ_by_the_arc_to_the_rover() -> None:
    from mars_pairs.geometry.body import MARS_RADIUS_M
    from mars_pairs.geometry.frames import site_to_local_ned

    assert np.allclose(site_to_local_ned(77.45, 18.44, 77.45, 18.44), np.eye(3), atol=1e-15)
    # a rover 168 m east of its site origin: the levels differ by the arc, 168 / R
    dlon = np.degrees(168.0 / (MARS_RADIUS_M * np.cos(np.radians(18.44))))
    m = site_to_local_ned(77.45, 18.44, 77.45 + dlon, 18.44)
    down_site_in_local = m @ np.array([0.0, 0.0, 1.0])
    tilt = np.arccos(np.clip(down_site_in_local[2], -1.0, 1.0))
    assert abs(tilt - 168.0 / MARS_RADIUS_M) < 1e-9
    # the site's "down" (towards the centre from a point to the west) leans east here
    assert down_site_in_local[1] > 1e-5
    # and the whole turn is the longitude step about the spin axis (meridians converge)
    angle = np.arccos((np.trace(m) - 1.0) / 2.0)
    assert abs(angle - np.radians(dlon)) < 1e-9
