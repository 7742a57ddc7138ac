"""Stage view: the camera anchored on the DEM, its viewshed and its per-pixel ray hits."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mars_pairs.errors import MarsPairsError
from mars_pairs.geometry.frames import MARS_RADIUS_M
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Pose
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.viewshed import compute_viewshed
from mars_pairs.pds.observation import Observation
from mars_pairs.pipeline.context import SampleContext
from mars_pairs.pipeline.stages import Stages
from mars_pairs.raster.terrain import DemWindow


@dataclass
class View:
    """An observation's view over the terrain, in the DEM's CRS.

    ``camera`` is anchored so that its centre stands ``height`` metres above the DEM;
    ``mask`` (uint8 on ``window``'s grid) marks the visible cells; ``hits`` (N, 3) are the
    ray/terrain intersections of the strided pixels (NaN for no hit), ``grid_shape`` their
    (rows, cols) in the image.
    """

    camera: MapCamera
    height: float
    window: DemWindow
    mask: np.ndarray
    hits: np.ndarray | None
    grid_shape: tuple[int, int]


def compute_view(
    obs: Observation, pose: Pose, camera: MapCamera, ctx: SampleContext, stage: Stages
) -> View:
    """Terrain window, anchored camera, viewshed over the image's band, and ray hits."""
    geo = ctx.config.geometry
    with stage("terrain"):
        cx, cy, cz = (float(v) for v in camera.center_map)
        ground_z = ctx.terrain.elevation_at(cx, cy)  # TerrainError off the DEM
        if not math.isfinite(ground_z):
            raise MarsPairsError(f"{ctx.config.inputs.dem}: no DEM data under the camera")
        window = ctx.dem_window(cx, cy, geo.radius + 2.0)
        height = geo.observer_height
        if height is None:  # the camera centre's height above the rover origin
            height = cz - pose.elevation_m
        # anchor the camera to the DEM: its centre stands `height` above the terrain under it
        lift = np.array([0.0, 0.0, ground_z + height - cz])
        camera = replace(camera, origin_map=camera.origin_map + lift)
        # the exact band the image covers, from its border rays
        az_band, el_band = camera.view_band_deg()
    mask = hits = None
    stride = geo.ray_stride
    grid_shape = (len(range(0, camera.height, stride)), len(range(0, camera.width, stride)))
    if geo.viewshed in ("wedge", "both"):
        with stage("viewshed"):
            mask = compute_viewshed(
                window,
                cx,
                cy,
                height=height,
                radius=geo.radius,
                az_band=az_band,
                el_band=el_band,
                planet_radius=MARS_RADIUS_M,
            )
    if geo.viewshed in ("raycast", "both"):
        with stage("raycast"):
            origins, dirs = camera.pixel_rays(camera.pixel_grid(stride))
            hits, _ = cast_rays(origins, dirs, window, max_range=geo.radius, observer_xy=(cx, cy))
            if mask is None:
                mask = mask_from_hits(hits, window)
    assert mask is not None
    return View(camera, float(height), window, mask, hits, grid_shape)


def mask_from_hits(hits: np.ndarray, window: DemWindow) -> np.ndarray:
    """The DEM cells that ray hits land in (uint8 on the window grid)."""
    mask = np.zeros(window.data.shape, dtype=np.uint8)
    ok = np.isfinite(hits[:, 0])
    col, row = window.xy_to_colrow(hits[ok, 0], hits[ok, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (row >= 0) & (col < mask.shape[1]) & (row < mask.shape[0])
    mask[row[inside], col[inside]] = 1
    return mask
