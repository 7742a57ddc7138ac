"""One label -> one catalogue row: the build's stages up to the view (label, image size, PLACES,
camera anchored on the DEM, line of sight over the frustum), then the view's outline; no chips,
no pixels decoded.

Stages (named in failure rows as the build names them): label, image, locate, terrain,
viewshed, footprint. The image stage checks the image's size from its header (JPEG/PNG: the
size the file declares, a uniform downscale re-expresses the camera as the build does;
IMG products: the file is there and the label's size is taken); the build's full decode is
left to the build. The view is the line of sight of ``geometry.view_mask`` (the build's
``viewshed`` stage, whatever ``geometry.viewshed`` says: rays are not cast), on the DEM
window the build reads (``SampleContext.dem_window``), so its cells are the build's.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image

from mars_pairs.errors import ImageError, MarsPairsError, PlacesError, StageError
from mars_pairs.geometry.attitude import image_centre_pointing_deg
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.observation import Observation
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.footprint import footprint_outline, view_statistics
from mars_pairs.pipeline.sample.ground import fit_to_label
from mars_pairs.pipeline.sample.key import sample_key
from mars_pairs.pipeline.sample.record import relative_label_path
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.view import View, anchor_view, line_of_sight
from mars_pairs.raster.outline import outline_parts
from mars_pairs.store.cellmask import pack_cells
from mars_pairs.store.geoparquet import footprint_bounds
from mars_pairs.store.splits import hilbert_index

_BROWSE = (".jpg", ".jpeg", ".png")
#: vertices of the wedge's arc per degree of azimuth
_ARC_STEP_DEG = 1.0


def checked_size(obs: Observation) -> Observation:
    """``obs`` for its image's size, read from the image's header (no pixel decoded):
    unchanged when it is the label's, re-expressed for a uniform downscale
    (``ground.fit_to_label``); ImageError naming the file otherwise, or when the image is
    missing or unreadable."""
    path = obs.image_path
    if path is None or not Path(path).is_file():
        raise ImageError(f"{obs.label_path}: no image file beside the label")
    path = Path(path)
    if path.suffix.lower() not in _BROWSE or path == obs.label_path:
        return obs  # a PDS product: its array is the label's (read by the build)
    try:
        with Image.open(path) as im:
            size = im.size
    except Exception as exc:  # Pillow raises many types on a damaged header
        raise ImageError(f"{path}: cannot read the image header: {exc}") from exc
    return fit_to_label(obs, (int(size[0]), int(size[1])), path)[0]


def catalog_entry(label: Path, ctx: SampleContext) -> dict[str, Any]:
    """The catalogue row of one label (``store.catalog_schema.CATALOG_SCHEMA``); StageError
    naming the failing stage."""
    stage = Stages()
    try:
        with stage("label"):
            obs = read_observation(label)
        with stage("image"):
            obs = checked_size(obs)
        with stage("locate"):
            pose = ctx.places.locate(obs)
            camera = MapCamera.from_observation(obs, pose, ctx.crs_wkt)
        geo = ctx.config.geometry
        with stage("terrain"):
            anchored = anchor_view(
                camera, pose, ctx.terrain, ctx.dem_window, geo.radius, geo.observer_height,
                geo.view_mask,
            )  # fmt: skip
        with stage("viewshed"):
            view = View.seeing(anchored, line_of_sight(anchored, max(ctx.terrain.res)))
        with stage("footprint"):
            if pose.quaternion is None:
                raise PlacesError(f"{obs.label_path}: no rover attitude")
            row = _row(obs, view, ctx, pose.quaternion)
            row.update(localization=pose.source, places_pose=pose.pose)
    except (MarsPairsError, ValueError, OSError) as exc:
        raise StageError(stage.name, exc) from exc
    return row


def visible_ranges(view: View) -> tuple[float | None, float | None]:
    """Median and largest horizontal range (true metres, rover's local frame, curvature as the
    view test takes it) from the camera centre to the centres of the cells in view."""
    rows, cols = np.nonzero(view.mask)
    if not len(rows):
        return None, None
    x, y = view.window.colrow_to_xy(cols, rows)
    points = np.column_stack([x, y, view.window.data[rows, cols].astype(np.float64)])
    cam = view.camera
    rel = cam.local_points(points, MARS_RADIUS_M) - cam.map_to_local(cam.center_map)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    return float(np.median(dist)), float(dist.max())


def _true_area(outline: Any, cam: MapCamera) -> float:
    """The outline's area in true square metres (map area through the local Jacobian)."""
    if outline is None:
        return 0.0
    return float(outline.area / abs(float(np.linalg.det(cam.jacobian[:2, :2]))))


def wedge_polygon(view: View) -> shapely.Polygon:
    """The frustum's horizontal wedge (map CRS): from the camera centre out to ``radius_m``
    (true metres) across the image's true-north azimuth band; the full disc when the band is
    the whole circle."""
    cam = view.camera
    (az0, az1), _ = view.bands
    width = (az1 - az0) % 360.0
    full = (az0, az1) == (0.0, 360.0) or width == 0.0
    if full:
        width = 360.0
    steps = max(math.ceil(width / _ARC_STEP_DEG), 2)
    az = np.radians(az0 + np.linspace(0.0, width, steps + 1))
    ne = view.radius_m * np.column_stack([np.cos(az), np.sin(az)])  # north, east metres
    xy = ne @ cam.jacobian[:2, :2].T + cam.center_map[:2]
    ring = xy if full else np.vstack([cam.center_map[:2], xy])
    return shapely.Polygon(ring)


def _row(obs: Observation, view: View, ctx: SampleContext, quat: np.ndarray) -> dict[str, Any]:
    cfg = ctx.config
    cam = view.camera
    cx, cy, cz = (float(v) for v in cam.center_map)
    lon, lat = map_to_lonlat([cx], [cy], ctx.crs_wkt)
    az, el = image_centre_pointing_deg(obs.camera, obs.width, obs.height, quat)
    hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
    outline = footprint_outline(view)
    median, far = visible_ranges(view)
    stats = view_statistics(view)
    image = relative_label_path(obs.image_path, cfg.inputs.labels) if obs.image_path else None
    return {
        "key": sample_key(obs), "product_id": obs.product_id, "mission": obs.mission,
        "instrument": obs.instrument, "sol": obs.sol, "site": obs.rmc.site,
        "drive": obs.rmc.drive, "pose": obs.rmc.pose, "time": obs.start_time, "lmst": obs.lmst,
        "camera_x": cx, "camera_y": cy, "camera_z": cz,
        "camera_lon": float(lon[0]), "camera_lat": float(lat[0]),
        "easting": float(cam.origin_map[0]), "northing": float(cam.origin_map[1]),
        "azimuth_deg": az, "elevation_deg": el,
        "label_azimuth_deg": obs.azimuth_deg, "label_elevation_deg": obs.elevation_deg,
        "hfov_deg": obs.hfov_deg if obs.hfov_deg is not None else hfov,
        "vfov_deg": obs.vfov_deg if obs.vfov_deg is not None else vfov,
        "width": obs.width, "height": obs.height, "camera_model": obs.camera.model_type,
        "label_path": relative_label_path(obs.label_path, cfg.inputs.labels),
        "image_path": image, "dem_offset_m": view.dem_offset_m,
        "radius_m": float(view.radius_m), "view_mask": view.mode,
        "visible_cells": stats["visible_cells"], "visible_area_m2": _true_area(outline, cam),
        "median_range_m": median, "max_range_m": far,
        "footprint_parts": outline_parts(outline),
        "footprint": None if outline is None else shapely.to_wkb(outline),
        "wedge": shapely.to_wkb(wedge_polygon(view)),
        "camera_point": shapely.to_wkb(shapely.Point(cx, cy)),
        "view_cells": pack_cells(view.mask, view.window.transform),
        "bbox": footprint_bounds(outline),
        "hilbert": int(hilbert_index([cx], [cy], ctx.terrain.bounds)[0]),
    }  # fmt: skip
