"""Stage view: the camera anchored on the DEM, its viewshed and its per-pixel ray hits."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mars_pairs.errors import MarsPairsError
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.frames import azimuth_elevation_deg
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Pose
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.viewshed import compute_viewshed
from mars_pairs.observation import Observation
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.raster.terrain import DemWindow, Terrain

_AZ_MARGIN_DEG = 2.0  # the kernel's wedge is a prefilter: the exact test follows
_EL_MARGIN_DEG = 1.0


@dataclass
class View:
    """An observation's view over the terrain, in the DEM's CRS.

    ``camera`` is anchored at the rover origin: the whole rover is shifted by
    ``dem_offset_m`` = DEM(rover origin) - PLACES elevation (metres), so its origin stands on
    the DEM; ``height`` is the camera centre's height above the DEM at the rover origin (m).
    ``mask`` (uint8 on ``window``'s grid) marks the cells in view (see ``VIEW_MASKS``);
    ``hits`` (N, 3) are the ray/terrain intersections of the strided pixels (map x, y, z; NaN
    for no hit), ``grid_shape`` their (rows, cols) in the image.
    """

    camera: MapCamera
    height: float
    window: DemWindow
    mask: np.ndarray
    hits: np.ndarray | None
    grid_shape: tuple[int, int]
    dem_offset_m: float = 0.0
    radius_m: float = math.inf
    mode: str = "frustum"
    bands: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 360.0), (-90.0, 90.0))
    los: np.ndarray | None = None  # line of sight alone (uint8, window grid), before the view test


def anchor_camera(
    camera: MapCamera, pose: Pose, ground_at_origin: float, observer_height: float | None
) -> tuple[MapCamera, float, float]:
    """The camera with the rover standing on the DEM: (camera, dem_offset_m, height_m).

    ``ground_at_origin``: DEM elevation (m) at the rover origin. The rover (camera centre and
    rays) moves up by DEM - PLACES elevation; with ``observer_height`` the camera centre is
    put that many metres above the DEM at the rover origin instead.
    """
    offset = ground_at_origin - pose.elevation_m
    lift = offset
    if observer_height is not None:
        lift = ground_at_origin + observer_height - float(camera.center_map[2])
    moved = replace(camera, origin_map=camera.origin_map + np.array([0.0, 0.0, lift]))
    return moved, float(offset), float(moved.center_map[2] - ground_at_origin)


def kernel_bands(
    camera: MapCamera, az_band: tuple[float, float], el_band: tuple[float, float]
) -> tuple[tuple[float, float] | None, tuple[float, float]]:
    """The true-north az/el band as a conservative band of the kernel's grid frame.

    The kernel measures azimuth from grid north and elevation with map-unit distances; the
    band edges go through the local Jacobian (convergence, anisotropic scale) and widen by a
    margin. None: all azimuths.
    """
    k_min, k_max = camera.map_scale_range()
    lo, hi = el_band
    el_lo = min(math.degrees(math.atan(math.tan(math.radians(lo)) / k)) for k in (k_min, k_max))
    el_hi = max(math.degrees(math.atan(math.tan(math.radians(hi)) / k)) for k in (k_min, k_max))
    el = (max(el_lo - _EL_MARGIN_DEG, -90.0), min(el_hi + _EL_MARGIN_DEG, 90.0))
    start, end = az_band
    width = (end - start) % 360.0
    if width == 0.0 or width + 2 * _AZ_MARGIN_DEG >= 360.0 or (start, end) == (0.0, 360.0):
        return None, el
    g_start, g_end = camera.grid_azimuth_deg(np.array([start, end]))
    return ((float(g_start) - _AZ_MARGIN_DEG) % 360.0, (float(g_end) + _AZ_MARGIN_DEG) % 360.0), el


def in_view(points_map: np.ndarray, view: View) -> np.ndarray:
    """Which map points (N, 3: x, y map units, z metres) the view keeps, tested exactly.

    In true metres in the rover's local frame: horizontal range from the camera centre at most
    the view radius, and in "frustum" mode the point projects inside the image through the
    camera model; in "band" mode its true azimuth/elevation lies inside the image's band.
    Line of sight is not tested here (the kernel's mask says that).
    """
    camera = view.camera
    rel = camera.local_points(points_map, MARS_RADIUS_M) - camera.map_to_local(camera.center_map)
    keep = np.hypot(rel[:, 0], rel[:, 1]) <= view.radius_m
    if view.mode == "frustum":
        return keep & camera.in_image(points_map, MARS_RADIUS_M)
    (az0, az1), (el0, el1) = view.bands
    az, el = azimuth_elevation_deg(rel)
    if (az0, az1) != (0.0, 360.0):
        keep &= (az - az0) % 360.0 <= (az1 - az0) % 360.0
    return keep & (el >= el0) & (el <= el1)


def _nonzero_in_bbox(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.nonzero(mask), scanning only the bounding box of its set cells (a view wedge
    covers a fraction of the square DEM window: ~3x faster than a plain nonzero)."""
    any_row = np.flatnonzero(mask.any(axis=1))
    if not any_row.size:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    r0, r1 = int(any_row[0]), int(any_row[-1]) + 1
    any_col = np.flatnonzero(mask[r0:r1].any(axis=0))
    c0, c1 = int(any_col[0]), int(any_col[-1]) + 1
    rows, cols = np.nonzero(mask[r0:r1, c0:c1])
    return rows + r0, cols + c0


def exact_mask(los: np.ndarray, view: View) -> np.ndarray:
    """The cells of ``los`` (line-of-sight visible, uint8 on the window grid) in the view."""
    mask = np.zeros_like(los, dtype=np.uint8)
    rows, cols = _nonzero_in_bbox(los)
    if len(rows):
        x, y = view.window.colrow_to_xy(cols, rows)
        points = np.column_stack([x, y, view.window.data[rows, cols].astype(np.float64)])
        keep = in_view(points, view)
        mask[rows[keep], cols[keep]] = 1
    return mask


def apply_line_of_sight(view: View, cell: float) -> None:
    """Fill ``view.los`` (the kernel's line of sight from the camera centre, in a conservative
    grid wedge) and ``view.mask`` (those cells that pass the exact view test). ``cell``: the
    DEM's largest pixel size, map units."""
    camera = view.camera
    cx, cy, cz = (float(v) for v in camera.center_map)
    grid_az, grid_el = kernel_bands(camera, *view.bands)
    view.los = compute_viewshed(
        view.window,
        cx,
        cy,
        height=cz,
        height_is_absolute=True,
        radius=view.radius_m * camera.map_scale_range()[1] + cell,
        az_band=grid_az,
        el_band=grid_el,
        planet_radius=MARS_RADIUS_M,
    )
    view.mask = exact_mask(view.los, view)


def label_view(
    obs: Observation,
    pose: Pose,
    terrain: Terrain,
    radius_m: float,
    observer_height: float | None = None,
    mode: str = "frustum",
) -> View:
    """One image's view mask over ``terrain`` (the ``mars-pairs viewshed --label`` job): the
    camera anchored at the rover origin, line of sight and the exact ``mode`` test."""
    camera = MapCamera.from_observation(obs, pose, terrain.crs)
    ox, oy = (float(v) for v in camera.origin_map[:2])
    camera, offset, height = anchor_camera(
        camera, pose, terrain.elevation_at(ox, oy), observer_height
    )
    cx, cy = (float(v) for v in camera.center_map[:2])
    cell = max(terrain.res)
    window = terrain.read_dem_window(cx, cy, radius_m * camera.map_scale_range()[1] + 2 * cell)
    empty = np.zeros(window.data.shape, dtype=np.uint8)
    view = View(
        camera, height, window, empty, None, (0, 0), offset, radius_m, mode,
        camera.view_band_deg(),
    )  # fmt: skip
    apply_line_of_sight(view, cell)
    return view


def compute_view(
    obs: Observation, pose: Pose, camera: MapCamera, ctx: SampleContext, stage: Stages
) -> View:
    """Terrain window, the camera anchored at the rover origin, its view mask and ray hits."""
    geo = ctx.config.geometry
    with stage("terrain"):
        ox, oy = (float(v) for v in camera.origin_map[:2])
        ground = ctx.terrain.elevation_at(ox, oy)  # TerrainError off the DEM
        if not math.isfinite(ground):
            raise MarsPairsError(f"{ctx.config.inputs.dem}: no DEM data under the rover")
        camera, offset, height = anchor_camera(camera, pose, ground, geo.observer_height)
        cx, cy = (float(v) for v in camera.center_map[:2])
        k_max = camera.map_scale_range()[1]
        radius_map = geo.radius * k_max  # the window and kernel work in map units
        window = ctx.dem_window(cx, cy, radius_map + 2.0 * max(ctx.terrain.res))
        # the exact band the image covers, from its border rays (true north)
        az_band, el_band = camera.view_band_deg()
    stride = geo.ray_stride
    grid_shape = (len(range(0, camera.height, stride)), len(range(0, camera.width, stride)))
    empty = np.zeros(window.data.shape, dtype=np.uint8)
    view = View(
        camera,
        height,
        window,
        empty,
        None,
        grid_shape,
        offset,
        geo.radius,
        geo.view_mask,
        (az_band, el_band),
    )
    if geo.viewshed in ("wedge", "both"):
        with stage("viewshed"):
            apply_line_of_sight(view, max(ctx.terrain.res))
    if geo.viewshed in ("raycast", "both"):
        with stage("raycast"):
            origins, dirs = camera.pixel_rays(camera.pixel_grid(stride))
            view.hits, _ = cast_rays(
                origins, dirs, window, max_range=geo.radius, observer_xy=(cx, cy)
            )
            if geo.viewshed == "raycast":
                view.mask = view.los = mask_from_hits(view.hits, window)
    return view


def mask_from_hits(hits: np.ndarray, window: DemWindow) -> np.ndarray:
    """The DEM cells that ray hits land in (uint8 on the window grid)."""
    mask = np.zeros(window.data.shape, dtype=np.uint8)
    ok = np.isfinite(hits[:, 0])
    col, row = window.xy_to_colrow(hits[ok, 0], hits[ok, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (row >= 0) & (col < mask.shape[1]) & (row < mask.shape[0])
    mask[row[inside], col[inside]] = 1
    return mask
