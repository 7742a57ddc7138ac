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
from mars_pairs.pipeline.sample.footprint import view_statistics
from mars_pairs.pipeline.sample.ground import fit_to_label
from mars_pairs.pipeline.sample.key import sample_key
from mars_pairs.pipeline.sample.record import relative_label_path
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.view import View, anchor_view, line_of_sight
from mars_pairs.raster.outline import mask_outline, outline_parts
from mars_pairs.store.cellmask import pack_cells
from mars_pairs.store.geoparquet import footprint_bounds
from mars_pairs.store.splits import hilbert_index

_BROWSE = (".jpg", ".jpeg", ".png")
#: vertices of the wedge's arc per degree of azimuth
_ARC_STEP_DEG = 1.0
#: sub-cells per DEM cell side on which the view test draws the footprint's outline: the
#: image's edges cut DEM cells, and a whole-cell outline misses half a cell along them (IoU
#: 0.25 against the chip for a narrow view); line of sight stays the DEM cell's. 8, not 4:
#: at a grazing view the far edge (the image's top edge on the ground) wanders with the
#: relief inside a cell, and on quarter cells the demo's grazing Mastcam-Z frames met their
#: chips at IoU 0.918-0.941 (>= 0.99 on eighth cells); the catalogue takes ~2x the time
SUBCELLS = 8


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


def fine_mask(view: View, sub: int = SUBCELLS) -> tuple[np.ndarray, Any]:
    """The view on a grid ``sub`` times finer than the DEM window's (uint8, 1 = in view) and
    its transform: a sub-cell is in view when its DEM cell is in line of sight
    (``view.los``) and its centre, at the DEM's bilinear height there, passes the exact view
    test (``view.in_view``), as a chip pixel is tested (``chips.chip_view``). Line of sight
    is one verdict per cell, so only the cells the view test's edge crosses are sub-tested:
    the cells in line of sight whose 3 x 3 neighbourhood holds a cell centre passing the
    view test and one failing it (tested at the cells in line of sight and those beside the
    view; the image's edges are straight at the cell's scale); every other cell in line of
    sight is whole, in or out as its centre."""
    from affine import Affine

    from mars_pairs.pipeline.sample.view import in_view

    full_los = view.los.astype(bool)
    near = np.flatnonzero(full_los.any(axis=1)), np.flatnonzero(full_los.any(axis=0))
    if not len(near[0]):
        return np.zeros((sub, sub), dtype=np.uint8), view.window.transform * Affine.scale(1 / sub)
    # the bounding box of the line of sight (one cell more), on which the rest works
    r0, c0 = max(int(near[0][0]) - 1, 0), max(int(near[1][0]) - 1, 0)
    r1, c1 = int(near[0][-1]) + 2, int(near[1][-1]) + 2
    los = full_los[r0:r1, c0:c1]
    mask = view.mask[r0:r1, c0:c1].astype(bool)
    # the view test at the centres of the cells out of sight beside the view, then its
    # edge: the cells in line of sight with a neighbour passing the test and one failing it
    passes, tested = mask.copy(), los | _any_around(mask)
    ring_r, ring_c = np.nonzero(tested & ~los)
    if len(ring_r):
        x, y = view.window.colrow_to_xy(ring_c + c0, ring_r + r0)
        z = view.window.data[ring_r + r0, ring_c + c0].astype(np.float64)
        passes[ring_r, ring_c] = in_view(np.column_stack([x, y, z]), view) & np.isfinite(z)
    edge = los & _any_around(passes) & _any_around(tested & ~passes)
    whole = mask & ~edge
    fine = np.repeat(np.repeat(whole, sub, axis=0), sub, axis=1).astype(np.uint8)
    rows, cols = np.nonzero(edge)
    if len(rows):
        offsets = (np.arange(sub) + 0.5) / sub - 0.5
        dy, dx = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
        rr = np.repeat(rows, sub * sub)
        cc = np.repeat(cols, sub * sub)
        fr = rr * sub + np.tile(np.repeat(np.arange(sub), sub), len(rows))
        fc = cc * sub + np.tile(np.tile(np.arange(sub), sub), len(rows))
        fx, fy = cc + c0 + np.tile(dx, len(rows)), rr + r0 + np.tile(dy, len(rows))
        x, y = view.window.colrow_to_xy(fx, fy)
        z = bilinear(view.window.data, fx, fy)
        keep = in_view(np.column_stack([x, y, z]), view) & np.isfinite(z)
        fine[fr[keep], fc[keep]] = 1
    shift = Affine.translation(c0, r0) * Affine.scale(1.0 / sub)
    return fine, view.window.transform * shift


def _any_around(mask: np.ndarray) -> np.ndarray:
    """Whether each cell's 3 x 3 neighbourhood in ``mask`` (bool; off the grid: out) holds
    a set cell."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    out: np.ndarray = np.logical_or.reduce(
        [padded[i : i + h, j : j + w] for i in range(3) for j in range(3)]
    )
    return out


def bilinear(data: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``data`` (rows, cols; cell centres at integers) at fractional (col, row), bilinear,
    clamped at the edges; NaN where a neighbour is NaN (as the chips' DEM reads)."""
    h, w = data.shape
    c = np.clip(col, 0.0, w - 1.0)
    r = np.clip(row, 0.0, h - 1.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), max(w - 2, 0))
    r0 = np.minimum(np.floor(r).astype(np.intp), max(h - 2, 0))
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    fc, fr = c - c0, r - r0
    d = data.astype(np.float64, copy=False)
    top = d[r0, c0] * (1 - fc) + d[r0, c1] * fc
    bottom = d[r1, c0] * (1 - fc) + d[r1, c1] * fc
    out: np.ndarray = top * (1 - fr) + bottom * fr
    return out


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
    fine, transform = fine_mask(view)
    outline = mask_outline(fine, transform)
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
