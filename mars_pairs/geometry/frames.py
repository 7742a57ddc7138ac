"""Coordinate frames: quaternions, rover/site frames, the Mars sphere and map projections.

Frames used throughout mars-pairs:
- ROVER_NAV_FRAME: x forward, y right, z down; metres; origin at ground level under the rover.
- SITE_FRAME: x north, y east, z down (NED); metres; a tangent plane at the site origin.
- lon/lat: planetocentric degrees on the Mars sphere (R = 3 396 190 m), east-positive longitude.
- map: a projected CRS (x easting, y northing in the CRS's units), z = elevation above the
  areoid in metres (up).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import CRS, Transformer

# re-exported: importers name these constants from frames
from mars_pairs.geometry.body import M2020_PLACES_CRS as M2020_PLACES_CRS
from mars_pairs.geometry.body import MARS_LONLAT as MARS_LONLAT
from mars_pairs.geometry.body import MARS_RADIUS_M as MARS_RADIUS_M
from mars_pairs.geometry.body import MSL_PLACES_CRS as MSL_PLACES_CRS

FloatArray = NDArray[np.float64]


# -- quaternions and angles ---------------------------------------------------------------------
def quaternion_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrix of a Hamilton quaternion q = (s, v1, v2, v3); normalised first.

    For the labels' rover quaternion this is the rotation ROVER_NAV_FRAME -> SITE_FRAME:
    v_site = R @ v_rover.
    """
    s, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
            [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
            [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(m: ArrayLike) -> FloatArray:
    """Hamilton quaternion (s, v1, v2, v3), s >= 0, of a rotation matrix."""
    r = np.asarray(m, dtype=np.float64)
    tr = np.trace(r)
    if tr > 0:
        k = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * k, (r[2, 1] - r[1, 2]) / k, (r[0, 2] - r[2, 0]) / k, (r[1, 0] - r[0, 1]) / k]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k_ = (i + 1) % 3, (i + 2) % 3
        k = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k_, k_])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (r[k_, j] - r[j, k_]) / k
        q[1 + i] = 0.25 * k
        q[1 + j] = (r[j, i] + r[i, j]) / k
        q[1 + k_] = (r[k_, i] + r[i, k_]) / k
    out = np.asarray(q)
    return out if out[0] >= 0 else -out


def azimuth_elevation_deg(v_ned: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Azimuth (clockwise from north, 0..360) and elevation (up) in degrees of NED vectors."""
    v = np.asarray(v_ned, dtype=np.float64)
    n, e, d = v[..., 0], v[..., 1], v[..., 2]
    az = np.degrees(np.arctan2(e, n)) % 360.0
    el = np.degrees(np.arctan2(-d, np.hypot(n, e)))
    return az, el


def direction_from_az_el(az_deg: ArrayLike, el_deg: ArrayLike) -> FloatArray:
    """Unit NED vectors for azimuth (clockwise from north) and elevation (up), degrees."""
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)], axis=-1)


# -- the Mars sphere and local tangent planes ----------------------------------------------------
def _unit_sphere(lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def _ned_basis(lon_deg: float, lat_deg: float) -> FloatArray:
    """Rows: north, east, down unit vectors (planet-fixed Cartesian) at lon/lat."""
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    down = -_unit_sphere(lon_deg, lat_deg)
    return np.stack([north, east, down])


def site_to_local_ned(
    site_lon_deg: float, site_lat_deg: float, lon_deg: float, lat_deg: float
) -> FloatArray:
    """Rotation (3 x 3) from NED axes at the site origin to NED axes at lon/lat (degrees).

    SITE_FRAME is level at its origin; the rover's quaternion is relative to it. At a rover
    d metres away the two levels differ by d / R (168 m: 0.003 deg, which moves a grazing
    ray's ground hit at 200 m by ~0.5 m). v_local = M @ v_site.
    """
    m: FloatArray = _ned_basis(lon_deg, lat_deg) @ _ned_basis(site_lon_deg, site_lat_deg).T
    return m


@dataclass(frozen=True)
class TangentFrame:
    """A local NED tangent frame (like SITE_FRAME) at a point of the Mars sphere.

    ``lon_deg``/``lat_deg``: planetocentric degrees of the origin; ``height_m``: its elevation
    above the sphere (areoid) in metres. Conversions are exact on the sphere.
    """

    lon_deg: float
    lat_deg: float
    height_m: float = 0.0
    radius_m: float = MARS_RADIUS_M

    def ned_to_lonlat(self, ned: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """NED metres (..., 3) -> (lon deg, lat deg, height m above the sphere)."""
        basis = _ned_basis(self.lon_deg, self.lat_deg)
        origin = _unit_sphere(self.lon_deg, self.lat_deg) * (self.radius_m + self.height_m)
        p = origin + np.asarray(ned, dtype=np.float64) @ basis
        r = np.linalg.norm(p, axis=-1)
        lat = np.degrees(np.arcsin(p[..., 2] / r))
        lon = np.degrees(np.arctan2(p[..., 1], p[..., 0]))
        return lon, lat, r - self.radius_m

    def lonlat_to_ned(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, height_m: ArrayLike = 0.0
    ) -> FloatArray:
        """(lon deg, lat deg, height m) -> NED metres (..., 3) in this frame."""
        basis = _ned_basis(self.lon_deg, self.lat_deg)
        origin = _unit_sphere(self.lon_deg, self.lat_deg) * (self.radius_m + self.height_m)
        p = _unit_sphere(lon_deg, lat_deg) * (self.radius_m + np.asarray(height_m))[..., None]
        ned: FloatArray = (p - origin) @ basis.T
        return ned


# -- map projections ------------------------------------------------------------------------------
@lru_cache(maxsize=64)
def _transformer(src: str, dst: str) -> Transformer:
    return Transformer.from_crs(CRS.from_user_input(src), CRS.from_user_input(dst), always_xy=True)


def crs_string(crs: object) -> str:
    """A hashable text form (WKT or PROJ string) of a CRS: text, pyproj or rasterio CRS, EPSG."""
    if isinstance(crs, str):
        return crs
    to_wkt = getattr(crs, "to_wkt", None)
    if to_wkt is not None:
        return str(to_wkt())
    return CRS.from_user_input(crs).to_wkt()


def lonlat_to_map(
    lon_deg: ArrayLike, lat_deg: ArrayLike, crs: object
) -> tuple[FloatArray, FloatArray]:
    """Planetocentric lon/lat (degrees, Mars sphere) -> map x, y in ``crs`` units."""
    x, y = _transformer(MARS_LONLAT, crs_string(crs)).transform(
        np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
    )
    return np.asarray(x), np.asarray(y)


def map_to_lonlat(x: ArrayLike, y: ArrayLike, crs: object) -> tuple[FloatArray, FloatArray]:
    """Map x, y in ``crs`` units -> planetocentric lon/lat degrees on the Mars sphere."""
    lon, lat = _transformer(crs_string(crs), MARS_LONLAT).transform(
        np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    )
    return np.asarray(lon), np.asarray(lat)


def map_to_map(
    x: ArrayLike, y: ArrayLike, src_crs: object, dst_crs: object
) -> tuple[FloatArray, FloatArray]:
    """Map coordinates from one CRS to another (through the Mars sphere)."""
    xs, ys = _transformer(crs_string(src_crs), crs_string(dst_crs)).transform(
        np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    )
    return np.asarray(xs), np.asarray(ys)


def local_map_jacobian(
    lon_deg: float, lat_deg: float, crs: object, height_m: float = 0.0, step_m: float = 1.0
) -> FloatArray:
    """Jacobian (3 x 3) from local NED metres at lon/lat/height to map (x, y, z up).

    Columns: d(map)/d(north), d(map)/d(east), d(map)/d(down). It carries the projection's
    local scale factors and grid convergence (eqc at Gale's latitude stretches east by 0.3 %),
    and the radius ratio R / (R + height): a metre at -4.5 km spans 1.0013 m of the sphere.
    """
    frame = TangentFrame(lon_deg, lat_deg, height_m)
    offsets = np.array([[step_m, 0, 0], [-step_m, 0, 0], [0, step_m, 0], [0, -step_m, 0]])
    lon, lat, _ = frame.ned_to_lonlat(offsets)
    x, y = lonlat_to_map(lon, lat, crs)
    jac = np.zeros((3, 3))
    jac[0, 0] = (x[0] - x[1]) / (2 * step_m)
    jac[1, 0] = (y[0] - y[1]) / (2 * step_m)
    jac[0, 1] = (x[2] - x[3]) / (2 * step_m)
    jac[1, 1] = (y[2] - y[3]) / (2 * step_m)
    jac[2, 2] = -1.0
    return jac


def ned_to_map(
    ned: ArrayLike, origin_lon: float, origin_lat: float, origin_height_m: float, crs: object
) -> FloatArray:
    """NED metres from an origin (lon/lat degrees, height m) -> map (x, y, z up metres), exactly."""
    frame = TangentFrame(origin_lon, origin_lat, origin_height_m)
    lon, lat, h = frame.ned_to_lonlat(ned)
    x, y = lonlat_to_map(lon, lat, crs)
    return np.stack([x, y, h], axis=-1)
