"""Rover attitude: PLACES roll/pitch/yaw as a quaternion, and where a camera's image centre looks.

Frames: the rover attitude rotates ROVER_NAV_FRAME (x forward, y right, z down) into SITE_FRAME
(x north, y east, z down): v_site = R v_rover. PLACES tables give it as roll, pitch, yaw in
degrees, the Z-Y-X (yaw, then pitch, then roll) Euler angles of that rotation:
R = Rz(yaw) Ry(pitch) Rx(roll). Checked on the real tables: it reproduces the quaternion columns
of Perseverance's ``best_interp.csv`` (9188 rows) and of Curiosity's ``localized_interp.csv``
to 0.01 degree, and the rover quaternions of the sol-1429 Mastcam labels.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.frames import azimuth_elevation_deg, quaternion_to_matrix

FloatArray = NDArray[np.float64]


def rpy_to_quaternion(roll_deg: ArrayLike, pitch_deg: ArrayLike, yaw_deg: ArrayLike) -> FloatArray:
    """Hamilton quaternion(s) (..., 4) = (s, v1, v2, v3), s >= 0, of R = Rz(yaw) Ry(pitch) Rx(roll).

    Angles in degrees (PLACES ``roll``, ``pitch``, ``yaw``); the rotation is ROVER_NAV_FRAME ->
    SITE_FRAME, the same as the labels' ``ORIGIN_ROTATION_QUATERNION``.
    """
    half = np.radians(np.stack(np.broadcast_arrays(roll_deg, pitch_deg, yaw_deg), axis=-1)) / 2
    cr, cp, cy = np.cos(half[..., 0]), np.cos(half[..., 1]), np.cos(half[..., 2])
    sr, sp, sy = np.sin(half[..., 0]), np.sin(half[..., 1]), np.sin(half[..., 2])
    q = np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )
    return np.where(q[..., :1] < 0, -q, q)


def image_centre_pixel(width: int, height: int) -> FloatArray:
    """The centre of a width x height image as (sample, line), pixel centres at integers
    (the first pixel's centre at (0, 0), the JPL camera-model convention)."""
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0])


def image_centre_pointing_deg(
    camera: CameraModel, width: int, height: int, quaternion: ArrayLike
) -> tuple[float, float]:
    """Azimuth (clockwise from north) and elevation (up) in degrees, SITE_FRAME, of the ray
    through the image centre.

    ``camera``: vectors in ROVER_NAV_FRAME, H and V in pixels of the width x height product;
    ``quaternion``: the rover attitude (s, v1, v2, v3), ROVER_NAV_FRAME -> SITE_FRAME. For a
    subframe this differs from the camera's axis and from the labels' instrument pointing.
    """
    _, ray = camera.unproject(image_centre_pixel(width, height)[None, :])
    az, el = azimuth_elevation_deg(quaternion_to_matrix(quaternion) @ ray[0])
    return float(az), float(el)
