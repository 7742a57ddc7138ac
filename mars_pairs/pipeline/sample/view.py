"""The view of one observation, in pure steps: the camera anchored on the DEM (one function for
the build and ``viewshed --label``), its line of sight and its per-pixel ray hits; the build
runs and times them as stages (``build_sample.view_stages``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace

import numpy as np
from affine import Affine

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.frames import azimuth_elevation_deg
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Pose
from mars_pairs.kernels.frustum import frustum_keep, frustum_mask
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.viewshed import compute_viewshed
from mars_pairs.observation import Observation
from mars_pairs.raster.terrain import DemWindow, Terrain

_AZ_MARGIN_DEG = 2.0  # the kernel's wedge is a prefilter: the exact test follows
_EL_MARGIN_DEG = 1.0


@dataclass(frozen=True)
class AnchoredView:
    """The camera anchored on the DEM, the DEM window around it and the view's exact test; all
    in the DEM's CRS (map x, y in map units, z in metres).

    ``camera`` stands at the rover origin: the whole rover is shifted by ``dem_offset_m`` =
    DEM(rover origin) - PLACES elevation (metres), so its origin stands on the DEM (or, with an
    observer height, its centre that many metres above it); ``height`` is the camera centre's
    height above the DEM at the rover origin (m). ``window`` holds the DEM within
    ``radius_m`` (true metres) of the camera centre plus two cells. ``mode`` ("frustum" or
    "band") and ``bands`` (true-north azimuth and elevation bands of the image, degrees) are
    the view test of ``in_view``.
    """

    camera: MapCamera
    height: float
    dem_offset_m: float
    window: DemWindow
    radius_m: float
    mode: str
    bands: tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class StridedRays:
    """The rays of every ``stride``-th pixel (rows of ``MapCamera.pixel_grid(stride)``):
    ``o_local``, ``d_local`` (N, 3) origins and unit directions in the camera model's local
    NED frame (metres); ``origins``, ``dirs`` (N, 3) the same on the map (map x, y in map
    units, z in metres; a direction is the map image of the unit local vector)."""

    stride: int
    o_local: np.ndarray
    d_local: np.ndarray
    origins: np.ndarray
    dirs: np.ndarray


def strided_rays(camera: MapCamera, stride: int) -> StridedRays:
    """The rays of ``camera`` through every ``stride``-th pixel (``StridedRays``)."""
    o_local, d_local = camera.camera.unproject(camera.pixel_grid(stride))
    origins = camera.origin_map + o_local @ camera.jacobian.T
    return StridedRays(stride, o_local, d_local, origins, d_local @ camera.jacobian.T)


@dataclass(frozen=True)
class Sight:
    """What the camera sees on ``AnchoredView.window``'s grid (uint8, 1 = yes): ``los`` the line
    of sight alone, ``mask`` the cells that also pass the exact view test (see ``VIEW_MASKS``).
    """

    los: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True)
class View(AnchoredView):
    """An observation's view over the terrain: the anchored view (frames and units as in
    ``AnchoredView``) with what it sees.

    ``los`` (uint8 on ``window``'s grid) the line of sight alone, before the view test;
    ``mask`` (uint8, same grid) the cells in view (see ``VIEW_MASKS``); ``hits`` (N, 3) the
    ray/terrain intersections of the strided pixels (map x, y in map units, z in metres; NaN
    for no hit), None when no rays were cast; ``grid_shape`` their (rows, cols) in the image;
    ``rays`` the rays cast (``StridedRays``), None when none were.
    """

    los: np.ndarray
    mask: np.ndarray
    hits: np.ndarray | None
    grid_shape: tuple[int, int]
    rays: StridedRays | None = None

    @classmethod
    def seeing(
        cls,
        anchored: AnchoredView,
        sight: Sight,
        hits: np.ndarray | None = None,
        grid_shape: tuple[int, int] = (0, 0),
        rays: StridedRays | None = None,
    ) -> View:
        """The view of ``anchored`` with its ``sight`` and ray ``hits`` (``grid_shape``) of
        ``rays``."""
        parts = {f.name: getattr(anchored, f.name) for f in fields(AnchoredView)}
        return cls(
            **parts, los=sight.los, mask=sight.mask, hits=hits, grid_shape=grid_shape, rays=rays
        )


#: reads the DEM window holding everything within a reach (map units) of map point (x, y)
WindowReader = Callable[[float, float, float], DemWindow]


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


def anchor_view(
    camera: MapCamera,
    pose: Pose,
    terrain: Terrain,
    read_window: WindowReader,
    radius_m: float,
    observer_height: float | None,
    mode: str,
) -> AnchoredView:
    """``camera`` (map CRS of ``terrain``) anchored on the DEM at its rover origin, and the DEM
    window its view needs, read by ``read_window`` (x, y, reach in map units).

    The reach is ``radius_m`` (true metres) at the largest map scale around the camera, plus
    two DEM cells. ``observer_height``: the camera centre's height above the DEM at the rover
    origin (m); None: the label's, the rover standing on the DEM. TerrainError when the rover
    origin is off the DEM or over nodata (``Terrain.elevation_at``).
    """
    ox, oy = (float(v) for v in camera.origin_map[:2])
    terrain.require_inside(ox, oy, "point")  # before the window is read around the camera
    # anchoring moves the camera up or down only: its map x, y and the reach are known now,
    # and the ground under the rover comes from the window (no read of its own)
    cx, cy = (float(v) for v in camera.center_map[:2])
    reach = radius_m * camera.map_scale_range()[1] + 2.0 * max(terrain.res)
    window = read_window(cx, cy, reach)
    ground = terrain.elevation_at(ox, oy, within=window)
    camera, offset, height = anchor_camera(camera, pose, ground, observer_height)
    # the exact band the image covers, from its border rays (true north)
    bands = camera.view_band_deg()
    return AnchoredView(camera, height, offset, window, radius_m, mode, bands)


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


def in_view(points_map: np.ndarray, view: AnchoredView) -> np.ndarray:
    """Which map points (N, 3: x, y map units, z metres) the view keeps, tested exactly.

    In true metres in the rover's local frame: horizontal range from the camera centre at most
    the view radius, and in "frustum" mode the point projects inside the image through the
    camera model; in "band" mode its true azimuth/elevation lies inside the image's band.
    Line of sight is not tested here (the kernel's mask says that). Frustum mode with a
    CAHV or CAHVOR camera runs in one compiled pass (``kernels.frustum.frustum_keep``).
    """
    camera = view.camera
    compiled = _frustum_arguments(view)
    if compiled is not None:
        points = np.ascontiguousarray(points_map, dtype=np.float64).reshape(-1, 3)
        return frustum_keep(points, *compiled)
    local = camera.local_points(points_map, MARS_RADIUS_M)
    rel = local - camera.map_to_local(camera.center_map)
    keep = np.hypot(rel[:, 0], rel[:, 1]) <= view.radius_m
    if view.mode == "frustum":
        return keep & camera.local_in_image(local)
    (az0, az1), (el0, el1) = view.bands
    az, el = azimuth_elevation_deg(rel)
    if (az0, az1) != (0.0, 360.0):
        keep &= (az - az0) % 360.0 <= (az1 - az0) % 360.0
    return keep & (el >= el0) & (el <= el1)


#: ``kernels.frustum``'s arguments after the points: origin, inverse Jacobian (transposed),
#: planet radius, camera centre (local NED), radius, camera vectors, CAHVOR, width, height
FrustumArguments = tuple[
    np.ndarray, np.ndarray, float, np.ndarray, float, np.ndarray, bool, int, int
]


def _frustum_arguments(view: AnchoredView) -> FrustumArguments | None:
    """The arguments of ``kernels.frustum`` after the points for the view's test, or None
    when the test is not the compiled one's (band mode; a CAHVORE camera)."""
    camera = view.camera
    model = camera.camera
    if view.mode != "frustum" or model.model_type not in ("CAHV", "CAHVOR"):
        return None
    distorted = model.model_type == "CAHVOR"
    none = np.zeros(3)
    o = model.o if distorted and model.o is not None else none
    r = model.r if distorted and model.r is not None else none
    cam = np.stack([model.c, model.a, model.h, model.v, o, r])
    centre = camera.map_to_local(camera.center_map)
    return (
        np.ascontiguousarray(camera.origin_map, dtype=np.float64), camera.inverse_jacobian_t,
        MARS_RADIUS_M, centre, float(view.radius_m), cam, distorted, camera.width, camera.height,
    )  # fmt: skip


def view_mask(
    selected: np.ndarray, heights: np.ndarray, transform: Affine, view: AnchoredView
) -> np.ndarray:
    """uint8 on a grid (``transform``: pixel corners -> map x, y of the view's CRS): 1 where
    ``selected`` is nonzero and the cell's centre at its height (``heights``: metres, NaN for
    none) passes ``in_view``."""
    compiled = _frustum_arguments(view)
    if compiled is not None:
        coefficients = np.array(tuple(transform)[:6], dtype=np.float64)
        return frustum_mask(
            np.ascontiguousarray(selected), np.ascontiguousarray(heights), coefficients,
            *compiled,
        )  # fmt: skip
    mask = np.zeros(selected.shape, dtype=np.uint8)
    rows, cols = _nonzero_in_bbox(selected)
    if len(rows):
        x, y = transform @ (cols + 0.5, rows + 0.5)  # type: ignore[operator]  # affine's hints: floats, not arrays
        points = np.column_stack([x, y, heights[rows, cols].astype(np.float64)])
        keep = in_view(points, view)
        mask[rows[keep], cols[keep]] = 1
    return mask


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


def exact_mask(los: np.ndarray, view: AnchoredView) -> np.ndarray:
    """The cells of ``los`` (line-of-sight visible, uint8 on the window grid) in the view."""
    return view_mask(los, view.window.data, view.window.transform, view)


def line_of_sight(view: AnchoredView, cell: float) -> Sight:
    """The kernel's line of sight from the camera centre over ``view.window`` (in a
    conservative grid wedge around the image's bands) and those cells that pass the exact view
    test. ``cell``: the DEM's largest pixel size, map units."""
    camera = view.camera
    cx, cy, cz = (float(v) for v in camera.center_map)
    grid_az, grid_el = kernel_bands(camera, *view.bands)
    los = compute_viewshed(
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
    return Sight(los, exact_mask(los, view))


def ray_grid_shape(camera: MapCamera, stride: int) -> tuple[int, int]:
    """(rows, cols) of the image pixels taken every ``stride`` pixels (``pixel_grid``)."""
    return len(range(0, camera.height, stride)), len(range(0, camera.width, stride))


def ray_hits(view: AnchoredView, stride: int, rays: StridedRays | None = None) -> np.ndarray:
    """The terrain hits (N, 3: map x, y in map units, z in metres; NaN for no hit) of every
    ``stride``-th pixel's ray (``rays`` when given, else ``strided_rays``), within
    ``view.radius_m`` (true metres) of the camera centre."""
    camera = view.camera
    cx, cy = (float(v) for v in camera.center_map[:2])
    rays = strided_rays(camera, stride) if rays is None else rays
    hits, _ = cast_rays(
        rays.origins, rays.dirs, view.window, max_range=view.radius_m, observer_xy=(cx, cy)
    )
    return hits


def sight_of_hits(hits: np.ndarray, window: DemWindow) -> Sight:
    """The sight of rays alone: the cells their hits land in are both line of sight and view."""
    mask = mask_from_hits(hits, window)
    return Sight(mask, mask)


def label_view(
    obs: Observation,
    pose: Pose,
    terrain: Terrain,
    radius_m: float,
    observer_height: float | None = None,
    mode: str = "frustum",
) -> View:
    """One image's view over ``terrain`` (the ``mars-pairs viewshed --label`` job): the camera
    anchored as the build anchors it (``anchor_view``), on a DEM window centred on the camera
    centre (``Terrain.read_dem_window``: TerrainError when the centre is off the DEM or over
    nodata), line of sight and the exact ``mode`` test; no rays cast. ``radius_m``: true
    metres; ``observer_height``: metres above the DEM at the rover origin, None: the label's.
    """
    camera = MapCamera.from_observation(obs, pose, terrain.crs)
    anchored = anchor_view(
        camera, pose, terrain, terrain.read_dem_window, radius_m, observer_height, mode
    )
    return View.seeing(anchored, line_of_sight(anchored, max(terrain.res)))


def mask_from_hits(hits: np.ndarray, window: DemWindow) -> np.ndarray:
    """The DEM cells that ray hits land in (uint8 on the window grid)."""
    mask = np.zeros(window.shape, dtype=np.uint8)
    ok = np.isfinite(hits[:, 0])
    col, row = window.xy_to_colrow(hits[ok, 0], hits[ok, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (row >= 0) & (col < mask.shape[1]) & (row < mask.shape[0])
    mask[row[inside], col[inside]] = 1
    return mask
