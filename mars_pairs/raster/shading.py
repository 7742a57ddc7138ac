"""Hillshading of an elevation grid: the one shading of the synthetic ortho and the pictures.

Frames and units: a north-up grid (row 0 north, columns east) of square cells ``res_m``
metres wide, elevations in metres; the light's azimuth in degrees clockwise from north (the
grid's up), its elevation in degrees above the horizon.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def lambert_shading(z: F64, res_m: float, azimuth_deg: float, elevation_deg: float) -> F64:
    """The cosine of each cell's angle of incidence (surface normal against the direction to
    the light), clipped at 0 (cells facing away): in [0, 1], flat ground sin(elevation).
    Slopes are central differences (``np.gradient``; one-sided at the edges); ``z`` finite."""
    gy, gx = np.gradient(z, res_m)  # gy: d/d(row) = -d/d(north)
    dz_de, dz_dn = gx, -gy
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    sun = np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])  # E, N, U
    norm = np.sqrt(dz_de**2 + dz_dn**2 + 1.0)
    shade: F64 = (-dz_de * sun[0] - dz_dn * sun[1] + sun[2]) / norm
    lit: F64 = np.clip(shade, 0.0, None)
    return lit
