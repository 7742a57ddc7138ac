"""One observation -> one dataset sample: locate, viewshed, ray cast, chips, encoded members.

Stages (named in failure rows): label, image, locate, terrain, viewshed, raycast, chips, encode.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from rasterio.enums import Resampling
from shapely import MultiPoint, Polygon, to_wkb

from mars_pairs.chips import ChipGrid, read_chip, resample_array
from mars_pairs.config import BuildConfig
from mars_pairs.errors import MarsPairsError
from mars_pairs.frames import MARS_RADIUS_M
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.viewshed import compute_viewshed
from mars_pairs.labels import read_observation
from mars_pairs.mapcam import MapCamera
from mars_pairs.observation import Observation
from mars_pairs.places import Places, Pose
from mars_pairs.splits import assign_splits, hilbert_index
from mars_pairs.terrain import Terrain


class StageError(Exception):
    """A failure at a named stage of one observation; becomes a row of failures.parquet."""

    def __init__(self, stage: str, error: BaseException) -> None:
        self.stage, self.error = stage, error
        super().__init__(f"{stage}: {type(error).__name__}: {error}")


@dataclass
class Sample:
    """A built sample: its manifest row (without member locations) and its member bytes."""

    key: str
    row: dict[str, Any]
    members: dict[str, bytes] = field(default_factory=dict)


@dataclass
class SampleContext:
    """What every observation of a build shares: config, PLACES table and terrain (per process)."""

    config: BuildConfig
    places: Places
    terrain: Terrain

    @classmethod
    def open(cls, config: BuildConfig) -> SampleContext:
        """Open the PLACES table and the rasters named by ``config``."""
        places = Places.from_csv(config.inputs.places)
        terrain = Terrain.open(config.inputs.dem, config.inputs.ortho)
        return cls(config, places, terrain)

    def close(self) -> None:
        """Close the rasters."""
        self.terrain.close()


def sample_key(obs: Observation) -> str:
    """The WebDataset key of an observation: mission and product id, no dots."""
    return f"{obs.mission}_{obs.product_id}".replace(".", "_").lower()


# -- stages -----------------------------------------------------------------------------------
def _ground_bytes(obs: Observation, encoding: str) -> tuple[str, bytes, tuple[int, int]]:
    """The ground image member: original bytes for JPEG/PNG, else decoded and encoded."""
    path = obs.image_path
    if path is None or not Path(path).is_file():
        raise MarsPairsError(f"{obs.label_path}: no image file beside the label")
    suffix = Path(path).suffix.lower()
    if suffix in (".jpg", ".jpeg", ".png"):
        data = Path(path).read_bytes()
        with Image.open(io.BytesIO(data)) as im:
            size = im.size
        return ("ground.jpg" if suffix != ".png" else "ground.png"), data, size
    import pdr  # decoded products (IMG) only

    arr = np.asarray(pdr.read(str(obs.label_path))["IMAGE"])
    if arr.ndim == 3 and arr.shape[0] in (1, 3):
        arr = np.moveaxis(arr, 0, -1)
    arr = np.squeeze(arr)
    if arr.dtype != np.uint8:
        lo, hi = np.nanpercentile(arr, [0.5, 99.5])
        arr = np.clip((arr - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    buf = io.BytesIO()
    fmt = "PNG" if encoding == "png" else "JPEG"
    Image.fromarray(arr).save(buf, format=fmt)
    return f"ground.{encoding}", buf.getvalue(), (arr.shape[1], arr.shape[0])


def _pointing(obs: Observation, cam: MapCamera) -> tuple[float, float, float, float]:
    """Azimuth, elevation, hFOV, vFOV (degrees): the label's, else from the camera model."""
    az_m, el_m = cam.pointing_az_el()
    hf_m, vf_m = obs.camera.fov_deg(obs.width, obs.height)
    az = obs.azimuth_deg if obs.azimuth_deg is not None else az_m
    el = obs.elevation_deg if obs.elevation_deg is not None else el_m
    hf = obs.hfov_deg if obs.hfov_deg is not None else hf_m
    vf = obs.vfov_deg if obs.vfov_deg is not None else vf_m
    return float(az), float(el), float(hf), float(vf)


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _true_area_scale(cam: MapCamera) -> float:
    """Square metres of ground per square map unit near the rover."""
    return 1.0 / abs(float(np.linalg.det(cam.jacobian[:2, :2])))


def build_sample(label: Path, ctx: SampleContext) -> Sample:
    """Run every stage for one label; raises StageError naming the failing stage."""
    cfg = ctx.config
    stage = "label"
    try:
        obs = read_observation(label)
        stage = "image"
        ground_name, ground, ground_size = _ground_bytes(obs, cfg.output.image_encoding)
        stage = "locate"
        pose = ctx.places.locate(obs)
        cam = MapCamera.from_observation(obs, pose, ctx.terrain.crs)
        stage = "terrain"
        row, members = _geometry(obs, pose, cam, ctx, ground_size)
    except StageError:
        raise
    except (MarsPairsError, ValueError, OSError) as exc:
        raise StageError(stage, exc) from exc
    members = {ground_name: ground, **members}
    row["ground_member"] = ground_name
    return Sample(row["key"], row, members)


def _geometry(
    obs: Observation, pose: Pose, cam: MapCamera, ctx: SampleContext, ground_size: tuple[int, int]
) -> tuple[dict[str, Any], dict[str, bytes]]:
    cfg = ctx.config
    geo = cfg.geometry
    rover_x, rover_y = float(cam.origin_map[0]), float(cam.origin_map[1])
    centre = cam.center_map
    radius = geo.radius
    window = ctx.terrain.read_dem_window(float(centre[0]), float(centre[1]), radius + 2.0)
    ground_z = ctx.terrain.elevation_at(float(centre[0]), float(centre[1]))
    if not math.isfinite(ground_z):
        raise MarsPairsError(f"{ctx.config.inputs.dem}: no DEM data under the camera")
    height = (
        geo.observer_height
        if geo.observer_height is not None
        else float(centre[2] - pose.elevation_m)
    )
    # anchor the camera to the DEM: its centre stands `height` above the terrain under it
    lift = np.array([0.0, 0.0, ground_z + height - centre[2]])
    cam = replace(cam, origin_map=cam.origin_map + lift)
    az, el, hfov, vfov = _pointing(obs, cam)
    # the exact band the image covers, from its border rays (wider than az +/- hFOV/2 when
    # the camera looks up or down)
    az_band, el_band = cam.view_band_deg()

    stage = "viewshed"
    try:
        mask = None
        if geo.viewshed in ("wedge", "both"):
            mask = compute_viewshed(
                window,
                float(centre[0]),
                float(centre[1]),
                height=height,
                radius=radius,
                az_band=az_band,
                el_band=el_band,
                planet_radius=MARS_RADIUS_M,
            )
        stage = "raycast"
        hits = ranges = None
        pixels = None
        if geo.viewshed in ("raycast", "both"):
            pixels = cam.pixel_grid(geo.ray_stride)
            origins, dirs = cam.pixel_rays(pixels)
            hits, ranges = cast_rays(
                origins,
                dirs,
                window,
                max_range=radius,
                observer_xy=(float(centre[0]), float(centre[1])),
            )
            if mask is None:
                mask = _mask_from_hits(hits, window)
        stage = "chips"
        row, members = _chips(
            obs,
            pose,
            cam,
            ctx,
            window,
            mask,
            hits,
            ranges,
            pixels,
            (az, el, hfov, vfov),
            ground_size,
            (rover_x, rover_y),
        )
    except MarsPairsError as exc:
        raise StageError(stage, exc) from exc
    except (ValueError, OSError) as exc:
        raise StageError(stage, exc) from exc
    return row, members


def _mask_from_hits(hits: np.ndarray, window: Any) -> np.ndarray:
    mask = np.zeros(window.data.shape, dtype=np.uint8)
    ok = np.isfinite(hits[:, 0])
    col, row = window.xy_to_colrow(hits[ok, 0], hits[ok, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (row >= 0) & (col < mask.shape[1]) & (row < mask.shape[0])
    mask[row[inside], col[inside]] = 1
    return mask


def _chips(
    obs: Observation,
    pose: Pose,
    cam: MapCamera,
    ctx: SampleContext,
    window: Any,
    mask: np.ndarray,
    hits: np.ndarray | None,
    ranges: np.ndarray | None,
    pixels: np.ndarray | None,
    pointing: tuple[float, float, float, float],
    ground_size: tuple[int, int],
    rover_xy: tuple[float, float],
) -> tuple[dict[str, Any], dict[str, bytes]]:
    cfg = ctx.config
    az, el, hfov, vfov = pointing
    crs = ctx.terrain.crs
    rotation = az if cfg.chips.orientation == "heading-up" else 0.0
    grid = ChipGrid.around(
        rover_xy[0], rover_xy[1], cfg.chips.size_m, cfg.chips.size_px, crs, rotation_deg=rotation
    )
    ortho = read_chip(str(cfg.inputs.ortho), grid, resampling=Resampling.bilinear)
    dem = read_chip(str(cfg.inputs.dem), grid, resampling=Resampling.bilinear)
    vis = resample_array(mask, window.transform, crs, grid, Resampling.nearest, nodata=0.0)
    ortho_u8 = np.nan_to_num(ortho, nan=0.0).clip(0, 255).astype(np.uint8)
    vis_u8 = (vis > 0.5).astype(np.uint8) * 255

    # statistics of the viewshed, in true metres
    area_scale = _true_area_scale(cam)
    cell_area = abs(window.transform.a * window.transform.e)
    rows_v, cols_v = np.nonzero(mask)
    vx, vy = window.colrow_to_xy(cols_v, rows_v)
    centre = cam.center_map
    if len(vx):
        local = cam.map_to_local(np.stack([vx, vy, np.full_like(vx, centre[2])], axis=-1))
        max_range = float(np.hypot(local[:, 0], local[:, 1]).max())
    else:
        max_range = 0.0

    corr = np.zeros((0, 0, 2), dtype=np.float32)
    footprint_pts = np.stack([vx, vy], axis=-1) if len(vx) else np.zeros((0, 2))
    hit_fraction = None
    if hits is not None and pixels is not None:
        k = cfg.geometry.ray_stride
        ny, nx = len(np.arange(0, cam.height, k)), len(np.arange(0, cam.width, k))
        chip_px = grid.to_pixel(hits[:, 0], hits[:, 1]).astype(np.float32)
        corr = chip_px.reshape(ny, nx, 2)
        ok = np.isfinite(hits[:, 0])
        hit_fraction = float(ok.mean())
        footprint_pts = hits[ok, :2]
    footprint = _footprint(footprint_pts, (float(centre[0]), float(centre[1])))
    xmin, ymin, xmax, ymax = grid.bounds()
    split = assign_splits(
        [rover_xy[0]], [rover_xy[1]], cfg.splits.block_m, cfg.splits.ratios, cfg.splits.seed
    )[0]
    b = ctx.terrain.bounds
    hilbert = int(hilbert_index([rover_xy[0]], [rover_xy[1]], (b[0], b[1], b[2], b[3]))[0])
    key = sample_key(obs)
    row: dict[str, Any] = {
        "key": key,
        "mission": obs.mission,
        "instrument": obs.instrument,
        "product_id": obs.product_id,
        "label_path": str(obs.label_path),
        "sol": obs.sol,
        "site": obs.rmc.site,
        "drive": obs.rmc.drive,
        "pose": obs.rmc.pose,
        "time": obs.start_time,
        "latitude": pose.latitude,
        "longitude": pose.longitude,
        "easting": rover_xy[0],
        "northing": rover_xy[1],
        "elevation": pose.elevation_m,
        "azimuth_deg": az,
        "elevation_deg": el,
        "hfov_deg": hfov,
        "vfov_deg": vfov,
        "width": obs.width,
        "height": obs.height,
        "localization": pose.source,
        "viewshed_area_m2": float(len(vx) * cell_area * area_scale),
        "visible_cells": len(vx),
        "max_visible_range_m": max_range,
        "ray_hit_fraction": hit_fraction,
        "footprint": footprint,
        "chip_xmin": xmin,
        "chip_ymin": ymin,
        "chip_xmax": xmax,
        "chip_ymax": ymax,
        "chip_rotation_deg": rotation,
        "split": split,
        "hilbert": hilbert,
    }
    meta = {k: v for k, v in row.items() if k not in ("footprint", "time")}
    meta.update(
        time=obs.start_time.isoformat() if obs.start_time else None,
        crs=str(crs),
        chip_transform=list(grid.transform)[:6],
        ray_stride=cfg.geometry.ray_stride,
        ground_size=list(ground_size),
        camera_center_map=[float(v) for v in cam.center_map],
        camera_model_type=obs.camera.model_type,
    )
    members = {
        "ortho.png": _png(ortho_u8),
        "dem.npy": _npy(dem.astype(np.float32)),
        "viewshed.png": _png(vis_u8),
        "corr.npy": _npy(corr),
        "meta.json": json.dumps(meta, sort_keys=True).encode(),
    }
    return row, members


def _footprint(points: np.ndarray, camera_xy: tuple[float, float]) -> bytes | None:
    """WKB of the convex hull of the visible ground and the camera position (map CRS)."""
    if len(points) == 0:
        return None
    hull = MultiPoint(np.vstack([points, [camera_xy]])).convex_hull
    if not isinstance(hull, Polygon):
        hull = hull.buffer(0.5)
    return to_wkb(hull)
