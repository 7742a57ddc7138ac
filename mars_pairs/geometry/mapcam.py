"""A camera placed on the map: camera centre and pixel rays in a projected CRS."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.frames import (
    azimuth_elevation_deg,
    crs_string,
    local_map_jacobian,
    lonlat_to_map,
    quaternion_to_matrix,
)
from mars_pairs.geometry.places import Pose
from mars_pairs.pds.observation import Observation

FloatArray = NDArray[np.float64]

LOCAL_NED = "LOCAL_NED_AT_ROVER"


@dataclass(frozen=True)
class MapCamera:
    """An observation's camera tied to a map CRS.

    ``camera`` has its vectors in a north-east-down frame (metres) whose origin is the rover
    frame origin (ground under the rover). ``origin_map`` is that origin in the map CRS
    (x, y map units; z elevation above the areoid, metres). ``jacobian`` maps local NED metres
    to map (x, y, z up) near the rover: projection scale factors and grid convergence included;
    over a few kilometres its error is below 1e-4 of the range. Planet curvature is left to the
    terrain kernels (a point at horizontal distance d lies d^2 / 2R below the tangent plane).
    """

    camera: CameraModel
    origin_map: FloatArray
    jacobian: FloatArray
    crs: str
    width: int
    height: int

    @classmethod
    def from_observation(cls, obs: Observation, pose: Pose, crs: object | None = None) -> MapCamera:
        """Place ``obs``'s camera at ``pose`` in ``crs`` (default: the pose's table CRS)."""
        if pose.quaternion is None:
            raise PlacesError(f"{obs.label_path}: no rover attitude in the label or PLACES table")
        target = crs_string(crs) if crs is not None else pose.crs
        rot = quaternion_to_matrix(pose.quaternion)
        local = obs.camera.transformed(rot, np.zeros(3), LOCAL_NED)
        x, y = lonlat_to_map(pose.longitude, pose.latitude, target)
        origin = np.array([float(x), float(y), pose.elevation_m])
        jac = local_map_jacobian(pose.longitude, pose.latitude, target, pose.elevation_m)
        return cls(local, origin, jac, target, obs.width, obs.height)

    @property
    def center_map(self) -> FloatArray:
        """Camera centre in map coordinates (x, y map units; z metres above the areoid)."""
        return self.origin_map + self.jacobian @ self.camera.c

    def pointing_az_el(self) -> tuple[float, float]:
        """Azimuth (clockwise from north) and elevation of the camera axis, degrees."""
        az, el = azimuth_elevation_deg(self.camera.a)
        return float(az), float(el)

    def view_band_deg(
        self, samples_per_edge: int = 64
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        """The image's exact azimuth band and elevation band (degrees, local NED at the rover).

        From the rays through the image border: azimuth clockwise from north, as (start, end)
        taken clockwise (it may cross north, e.g. (355, 5)); elevation (low, high). When the
        nadir or zenith lies inside the image the azimuth band is the full circle (0, 360).
        """
        w, h = self.width - 0.5, self.height - 0.5
        t = np.linspace(0.0, 1.0, samples_per_edge)
        edges = np.concatenate([
            np.stack([-0.5 + t * (w + 0.5), np.full_like(t, -0.5)], axis=-1),
            np.stack([np.full_like(t, w), -0.5 + t * (h + 0.5)], axis=-1),
            np.stack([-0.5 + t * (w + 0.5), np.full_like(t, h)], axis=-1),
            np.stack([np.full_like(t, -0.5), -0.5 + t * (h + 0.5)], axis=-1),
        ])  # fmt: skip
        _, rays = self.camera.unproject(edges)
        az, el = azimuth_elevation_deg(rays)
        el_band = (float(el.min()), float(el.max()))
        for pole in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)):
            px = self.camera.project(self.camera.c + np.asarray(pole))
            if np.all(np.isfinite(px)) and -0.5 <= px[0] <= w and -0.5 <= px[1] <= h:
                return (0.0, 360.0), (el_band if pole[2] < 0 else (-90.0, el_band[1]))
        centre_az = self.pointing_az_el()[0]
        rel = (az - centre_az + 180.0) % 360.0 - 180.0
        return (
            (float(centre_az + rel.min()) % 360.0, float(centre_az + rel.max()) % 360.0),
            el_band,
        )

    def pixel_grid(self, stride: int = 1) -> FloatArray:
        """Pixel centres (N, 2) as (sample, line) on every ``stride``-th row and column."""
        xs = np.arange(0, self.width, stride, dtype=np.float64)
        ys = np.arange(0, self.height, stride, dtype=np.float64)
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx.ravel(), gy.ravel()], axis=-1)

    def pixel_rays(self, pixels: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Rays through pixels (N, 2): origins (N, 3) and directions (N, 3) in map coordinates.

        A direction is the map image of a unit NED vector, so a ray parameter t is a range in
        metres along the true ray.
        """
        origins, dirs = self.camera.unproject(pixels)
        o_map = self.origin_map + origins @ self.jacobian.T
        d_map = dirs @ self.jacobian.T
        return o_map, d_map

    def map_to_local(self, points_map: ArrayLike) -> FloatArray:
        """Map points (..., 3) -> local NED metres at the rover (inverse of the Jacobian)."""
        rel = np.asarray(points_map, dtype=np.float64) - self.origin_map
        return rel @ np.linalg.inv(self.jacobian).T

    def project_map(self, points_map: ArrayLike) -> FloatArray:
        """Map points (..., 3) -> pixels (..., 2) as (sample, line); NaN behind the camera."""
        return self.camera.project(self.map_to_local(points_map))
