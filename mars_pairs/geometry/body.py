"""The Mars body: radii and the CRS strings of the Mars sphere and the PLACES maps.

One definition of each constant; every other module imports them from here.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

#: Mars sphere radius (metres), IAU 2015 (the radius of every Mars map CRS used here).
MARS_RADIUS_M = 3396190.0
#: the elevations a Mars surface may have, metres above the areoid (Hellas floor ~ -8.2 km,
#: Olympus Mons ~ +21.9 km), with a margin: a DEM or PLACES value outside is not Mars
MARS_ELEVATION_M = (-12_000.0, 30_000.0)
#: the largest viewshed radius (metres) a config or a command takes: ~3.4 degrees of Mars
MAX_RADIUS_M = 200_000.0
#: Mars IAU ellipsoid radii (metres): equatorial, polar.
MARS_EQUATORIAL_RADIUS_M, MARS_POLAR_RADIUS_M = 3396190.0, 3376200.0
#: Planetocentric longitude/latitude on the Mars sphere, east-positive.
MARS_LONLAT = "+proj=longlat +R=3396190 +no_defs +type=crs"
_EQC = "+proj=eqc +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs +type=crs"
#: Perseverance PLACES and Jezero maps: equirectangular, true scale at 18.4663 N.
M2020_PLACES_CRS = _EQC.replace("+proj=eqc", "+proj=eqc +lat_ts=18.4663")
#: Curiosity PLACES and Gale maps: equirectangular, true scale at the equator.
MSL_PLACES_CRS = _EQC.replace("+proj=eqc", "+proj=eqc +lat_ts=0")
#: GeoJSON's CRS name for the Mars sphere, planetocentric, east longitude.
MARS_LONLAT_AUTHORITY = "IAU_2015:49900"


def great_circle_m(lat1: ArrayLike, lon1: ArrayLike, lat2: ArrayLike, lon2: ArrayLike) -> Any:
    """Great-circle distance (metres) on the Mars sphere (:data:`MARS_RADIUS_M`) between
    points given as planetocentric latitude and east longitude (degrees; numbers or arrays,
    broadcast: a number or an array of distances)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dp, dl = p2 - p1, np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dp / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return 2 * MARS_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0, 1)))
