"""A camera placed on the map: camera centre and pixel rays in a projected CRS."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

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
    site_to_local_ned,
)
from mars_pairs.geometry.labelled import LabelledImage
from mars_pairs.geometry.places import Pose

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
    def from_observation(
        cls, obs: LabelledImage, pose: Pose, crs: object | None = None
    ) -> MapCamera:
        """Place ``obs``'s camera at ``pose`` in ``crs`` (default: the pose's table CRS)."""
        if pose.quaternion is None:
            raise PlacesError(f"{obs.label_path}: no rover attitude in the label or PLACES table")
        target = crs_string(crs) if crs is not None else pose.crs
        rot = quaternion_to_matrix(pose.quaternion)  # ROVER_NAV_FRAME -> SITE_FRAME
        if pose.site_lonlat is not None:  # SITE_FRAME is level at the site origin
            rot = site_to_local_ned(*pose.site_lonlat, pose.longitude, pose.latitude) @ rot
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
        local: FloatArray = rel @ self._inverse_jacobian_t
        return local

    @cached_property
    def _inverse_jacobian_t(self) -> FloatArray:
        """The Jacobian's inverse, transposed (map -> local NED), computed once per camera."""
        inv_t: FloatArray = np.linalg.inv(self.jacobian).T
        return inv_t

    @property
    def inverse_jacobian_t(self) -> FloatArray:
        """The Jacobian's inverse, transposed, C-contiguous: local NED = (map - origin) @ it."""
        return np.ascontiguousarray(self._inverse_jacobian_t)

    def project_map(self, points_map: ArrayLike) -> FloatArray:
        """Map points (..., 3) -> pixels (..., 2) as (sample, line); NaN behind the camera."""
        return self.camera.project(self.map_to_local(points_map))

    # -- the map grid against true north and true metres ----------------------------------------
    def map_scale_range(self) -> tuple[float, float]:
        """Smallest and largest horizontal map scale at the rover (map units per true metre).

        The singular values of the Jacobian's horizontal block: 1 for a CRS true to scale at
        the rover in every direction; eqc with lat_ts = 0 at 18.4 N gives (1.0, 1.054).
        """
        s = np.linalg.svd(self.jacobian[:2, :2], compute_uv=False)
        return float(s.min()), float(s.max())

    def grid_azimuth_deg(self, true_azimuth_deg: ArrayLike) -> FloatArray:
        """Azimuths clockwise from true north (degrees) -> clockwise from grid north (+y).

        Maps the direction through the local Jacobian, so grid convergence (23 deg in
        sinusoidal at Jezero) and anisotropic scale (eqc off its lat_ts) are both applied.
        """
        az = np.radians(np.asarray(true_azimuth_deg, dtype=np.float64))
        north_east = np.stack([np.cos(az), np.sin(az)], axis=-1)
        grid = north_east @ self.jacobian[:2, :2].T  # (x east, y north) map units
        az_grid: FloatArray = np.degrees(np.arctan2(grid[..., 0], grid[..., 1])) % 360.0
        return az_grid

    def local_points(self, points_map: ArrayLike, planet_radius: float) -> FloatArray:
        """Map points (..., 3) -> local NED metres at the rover, with the planet's curvature.

        Map z is elevation above the sphere; in the rover's tangent plane a point at horizontal
        distance d lies a further d^2 / (2 R) below (``planet_radius`` R metres; 0: none), the
        same convention as the terrain kernels.
        """
        local = self.map_to_local(points_map)
        if planet_radius:
            d2 = local[..., 0] ** 2 + local[..., 1] ** 2
            local = local.copy()
            local[..., 2] += d2 / (2.0 * planet_radius)
        return local

    def in_image(self, points_map: ArrayLike, planet_radius: float) -> NDArray[np.bool_]:
        """Whether map points (..., 3) lie in front of the camera and project inside the image.

        Inside means within the image's outer pixel edges: sample in [-0.5, width - 0.5] and
        line in [-0.5, height - 0.5] (pixel centres at integers).
        """
        return self.local_in_image(self.local_points(points_map, planet_radius))

    def local_in_image(self, local: ArrayLike) -> NDArray[np.bool_]:
        """``in_image`` of points (..., 3) already in local NED metres (``local_points``)."""
        px = self.camera.project(local)
        with np.errstate(invalid="ignore"):
            return (
                np.isfinite(px[..., 0])
                & (px[..., 0] >= -0.5)
                & (px[..., 0] <= self.width - 0.5)
                & (px[..., 1] >= -0.5)
                & (px[..., 1] <= self.height - 0.5)
            )
