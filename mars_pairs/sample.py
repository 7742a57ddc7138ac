"""One observation -> one dataset sample: locate, viewshed, ray cast, chips, encoded members.

Stages (named in failure rows and timed): label, image, locate, terrain, viewshed, raycast,
chips, encode.
"""

from __future__ import annotations

import io
import json
import math
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image

from mars_pairs.chips import ChipGrid, ChipReader, resample_array
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
from mars_pairs.terrain import DemWindow, Terrain


class StageError(Exception):
    """A failure at a named stage of one observation; becomes a row of failures.parquet."""

    def __init__(self, stage: str, error: BaseException) -> None:
        self.stage, self.error = stage, error
        super().__init__(f"{stage}: {type(error).__name__}: {error}")


@dataclass
class Sample:
    """A built sample: its manifest row (without member locations), member bytes, timings."""

    key: str
    row: dict[str, Any]
    members: dict[str, bytes] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class SampleContext:
    """What the observations of a build share, opened once per worker process."""

    config: BuildConfig
    places: Places
    terrain: Terrain
    ortho: ChipReader
    dem: ChipReader
    crs_wkt: str = ""
    _window: DemWindow | None = None
    _window_key: tuple[int, int, float] | None = None

    @classmethod
    def open(cls, config: BuildConfig) -> SampleContext:
        """Open the PLACES table and the rasters named by ``config``."""
        places = Places.from_csv(config.inputs.places)
        terrain = Terrain.open(config.inputs.dem)
        return cls(config, places, terrain, ChipReader(config.inputs.ortho),
                   ChipReader(config.inputs.dem), terrain.crs.to_wkt())  # fmt: skip

    def dem_window(self, x: float, y: float, radius: float, snap: float = 32.0) -> DemWindow:
        """A DEM window holding everything within ``radius`` of map point (x, y).

        The window is centred on (x, y) snapped to a ``snap``-unit grid and reaches ``snap``
        further, so the images of one stop share one read, and a sample never depends on
        which images a worker built before it (same window for the same position).
        """
        key = (round(x / snap), round(y / snap), radius)
        if self._window is None or key != self._window_key:
            x0, y0 = key[0] * snap, key[1] * snap
            self._window = self.terrain.read_dem_window(x0, y0, radius + snap, check_observer=False)
            self._window_key = key
        return self._window

    def close(self) -> None:
        """Close the rasters."""
        self.terrain.close()
        self.ortho.close()
        self.dem.close()


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


def sample_key(obs: Observation) -> str:
    """The WebDataset key of an observation: mission and product id, no dots."""
    return f"{obs.mission}_{obs.product_id}".replace(".", "_").lower()


class _Stages:
    """Names the running stage (for failure rows) and times each one."""

    def __init__(self) -> None:
        self.name = "label"
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        self.name = name
        start = time.perf_counter()
        yield
        self.seconds[name] = time.perf_counter() - start


def build_sample(label: Path, ctx: SampleContext) -> Sample:
    """Run every stage for one label; raises StageError naming the failing stage."""
    stage = _Stages()
    try:
        with stage("label"):
            obs = read_observation(label)
        with stage("image"):
            ground_name, ground, ground_size = _ground_member(obs, ctx.config.output.image_encoding)
        with stage("locate"):
            pose = ctx.places.locate(obs)
            camera = MapCamera.from_observation(obs, pose, ctx.terrain.crs)
        view = _view(obs, pose, camera, ctx, stage)
        with stage("chips"):
            grid, chips = _cut_chips(view, ctx, obs)
        with stage("encode"):
            row = _row(obs, pose, view, grid, ctx)
            members = _encode(
                chips, _correspondence(view, grid), _meta(row, obs, view, grid, ctx, ground_size)
            )
    except (MarsPairsError, ValueError, OSError) as exc:
        raise StageError(stage.name, exc) from exc
    row["ground_member"] = ground_name
    return Sample(row["key"], row, {ground_name: ground, **members}, stage.seconds)


# -- stages -----------------------------------------------------------------------------------
def _ground_member(obs: Observation, encoding: str) -> tuple[str, bytes, tuple[int, int]]:
    """The ground image member: original bytes for JPEG/PNG, else decoded (pdr) and encoded."""
    path = obs.image_path
    if path is None or not Path(path).is_file():
        raise MarsPairsError(f"{obs.label_path}: no image file beside the label")
    suffix = Path(path).suffix.lower()
    if suffix in (".jpg", ".jpeg", ".png"):
        data = Path(path).read_bytes()
        with Image.open(io.BytesIO(data)) as im:
            size = im.size
        return ("ground.png" if suffix == ".png" else "ground.jpg"), data, size
    import pdr  # only decoded products (IMG) need it

    arr = np.asarray(pdr.read(str(obs.label_path))["IMAGE"])
    if arr.ndim == 3 and arr.shape[0] in (1, 3):
        arr = np.moveaxis(arr, 0, -1)
    arr = np.squeeze(arr)
    if arr.dtype != np.uint8:
        lo, hi = np.nanpercentile(arr, [0.5, 99.5])
        arr = np.clip((arr - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG" if encoding == "png" else "JPEG")
    return f"ground.{encoding}", buf.getvalue(), (arr.shape[1], arr.shape[0])


def _view(obs: Observation, pose: Pose, camera: MapCamera, ctx: SampleContext,
          stage: _Stages) -> View:  # fmt: skip
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
            mask = compute_viewshed(window, cx, cy, height=height, radius=geo.radius,
                                    az_band=az_band, el_band=el_band,
                                    planet_radius=MARS_RADIUS_M)  # fmt: skip
    if geo.viewshed in ("raycast", "both"):
        with stage("raycast"):
            origins, dirs = camera.pixel_rays(camera.pixel_grid(stride))
            hits, _ = cast_rays(origins, dirs, window, max_range=geo.radius, observer_xy=(cx, cy))
            if mask is None:
                mask = _mask_from_hits(hits, window)
    assert mask is not None
    return View(camera, float(height), window, mask, hits, grid_shape)


def _mask_from_hits(hits: np.ndarray, window: DemWindow) -> np.ndarray:
    """The DEM cells that ray hits land in (uint8 on the window grid)."""
    mask = np.zeros(window.data.shape, dtype=np.uint8)
    ok = np.isfinite(hits[:, 0])
    col, row = window.xy_to_colrow(hits[ok, 0], hits[ok, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (row >= 0) & (col < mask.shape[1]) & (row < mask.shape[0])
    mask[row[inside], col[inside]] = 1
    return mask


def _cut_chips(view: View, ctx: SampleContext, obs: Observation) -> tuple[ChipGrid, dict[str, Any]]:
    """Ortho, DEM and viewshed chips around the rover (north-up or heading-up)."""
    spec = ctx.config.chips
    rover = view.camera.origin_map
    rotation = 0.0
    if spec.orientation == "heading-up":
        rotation = view.camera.pointing_az_el()[0]
    grid = ChipGrid.around(float(rover[0]), float(rover[1]), spec.size_m, spec.size_px,
                           ctx.crs_wkt, rotation_deg=rotation)  # fmt: skip
    ortho = ctx.ortho.read(grid)
    dem = ctx.dem.read(grid)
    vis = resample_array(view.mask, view.window.transform, ctx.crs_wkt, grid, nearest=True)
    return grid, {
        "ortho": np.nan_to_num(ortho, nan=0.0).clip(0, 255).astype(np.uint8),
        "dem": dem.astype(np.float32),
        "viewshed": (np.nan_to_num(vis) > 0.5).astype(np.uint8) * 255,
    }


def _correspondence(view: View, grid: ChipGrid) -> np.ndarray:
    """Chip pixel (column, row) of each strided ground pixel's ray hit; NaN for no hit."""
    if view.hits is None:
        return np.zeros((0, 0, 2), dtype=np.float32)
    chip_px = grid.to_pixel(view.hits[:, 0], view.hits[:, 1]).astype(np.float32)
    return chip_px.reshape(*view.grid_shape, 2)


def _row_spans(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of ``mask`` with a set cell, and each one's first and last set column."""
    rows = np.flatnonzero(mask.any(axis=1))
    sub = mask[rows]
    first = np.argmax(sub, axis=1)
    last = sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    return rows, first, last


def _footprint(view: View) -> shapely.Polygon | None:
    """Convex hull of the visible cells (their corners) and the camera position, map CRS."""
    rows, first, last = _row_spans(view.mask)
    if len(rows) == 0:
        return None
    cols = np.concatenate([first - 0.5, last + 0.5, first - 0.5, last + 0.5])
    rr = np.concatenate([rows - 0.5, rows - 0.5, rows + 0.5, rows + 0.5])
    x, y = view.window.colrow_to_xy(cols, rr)
    centre = view.camera.center_map
    points = shapely.multipoints(
        np.column_stack([np.append(x, centre[0]), np.append(y, centre[1])])
    )
    hull = shapely.convex_hull(points)
    return hull if isinstance(hull, shapely.Polygon) else hull.buffer(0.5)


def _view_statistics(view: View) -> dict[str, Any]:
    """Visible cell count, area (true m2) and farthest visible range (m), ray hit fraction."""
    visible = int(np.count_nonzero(view.mask))
    cam = view.camera
    # map units -> true metres through the local Jacobian (scale factors, R / (R + h))
    area_scale = 1.0 / abs(float(np.linalg.det(cam.jacobian[:2, :2])))
    cell_area = abs(view.window.transform.a * view.window.transform.e)
    max_range = 0.0
    if visible:
        # map_to_local is affine, so distance from the camera is convex along a row and the
        # farthest visible cell of a row is one of its visible span's two ends: exact
        rows, first, last = _row_spans(view.mask)
        x, y = view.window.colrow_to_xy(np.concatenate([first, last]), np.tile(rows, 2))
        local = cam.map_to_local(np.column_stack([x, y, np.full_like(x, cam.center_map[2])]))
        centre = cam.map_to_local(cam.center_map)
        max_range = float(np.hypot(local[:, 0] - centre[0], local[:, 1] - centre[1]).max())
    hit_fraction = None
    if view.hits is not None:
        hit_fraction = float(np.isfinite(view.hits[:, 0]).mean())
    return {"visible_cells": visible, "viewshed_area_m2": float(visible * cell_area * area_scale),
            "max_visible_range_m": max_range, "ray_hit_fraction": hit_fraction}  # fmt: skip


def _row(obs: Observation, pose: Pose, view: View, grid: ChipGrid,
         ctx: SampleContext) -> dict[str, Any]:  # fmt: skip
    """The manifest row (member locations are added when the shard is written)."""
    cfg = ctx.config
    rover_x, rover_y = (float(v) for v in view.camera.origin_map[:2])
    az, el = view.camera.pointing_az_el()
    hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
    footprint = _footprint(view)
    xmin, ymin, xmax, ymax = grid.bounds()
    split = assign_splits([rover_x], [rover_y], cfg.splits.block_m, cfg.splits.ratios,
                          cfg.splits.seed)[0]  # fmt: skip
    hilbert = int(hilbert_index([rover_x], [rover_y], ctx.terrain.bounds)[0])
    return {
        "key": sample_key(obs), "mission": obs.mission, "instrument": obs.instrument,
        "product_id": obs.product_id, "label_path": str(obs.label_path), "sol": obs.sol,
        "site": obs.rmc.site, "drive": obs.rmc.drive, "pose": obs.rmc.pose,
        "time": obs.start_time, "latitude": pose.latitude, "longitude": pose.longitude,
        "easting": rover_x, "northing": rover_y, "elevation": pose.elevation_m,
        "azimuth_deg": obs.azimuth_deg if obs.azimuth_deg is not None else az,
        "elevation_deg": obs.elevation_deg if obs.elevation_deg is not None else el,
        "hfov_deg": obs.hfov_deg if obs.hfov_deg is not None else hfov,
        "vfov_deg": obs.vfov_deg if obs.vfov_deg is not None else vfov,
        "width": obs.width, "height": obs.height, "localization": pose.source,
        **_view_statistics(view),
        "footprint": None if footprint is None else shapely.to_wkb(footprint),
        "chip_xmin": xmin, "chip_ymin": ymin, "chip_xmax": xmax, "chip_ymax": ymax,
        "chip_rotation_deg": grid.rotation_deg, "split": split, "hilbert": hilbert,
    }  # fmt: skip


def _meta(row: dict[str, Any], obs: Observation, view: View, grid: ChipGrid, ctx: SampleContext,
          ground_size: tuple[int, int]) -> dict[str, Any]:  # fmt: skip
    """meta.json: the row's plain values plus what a reader needs to use the members."""
    meta = {k: v for k, v in row.items() if k not in ("footprint", "time")}
    meta.update(
        time=obs.start_time.isoformat() if obs.start_time else None,
        crs=ctx.crs_wkt,
        chip_transform=list(grid.transform)[:6],
        ray_stride=ctx.config.geometry.ray_stride,
        ground_size=list(ground_size),
        observer_height_m=view.height,
        camera_center_map=[float(v) for v in view.camera.center_map],
        camera_model_type=obs.camera.model_type,
    )
    return meta


def _png(arr: np.ndarray) -> bytes:
    """Lossless PNG. zlib's run-length strategy: on orthoimage chips (texture, few long
    repeats) ~1.4x faster than level 1 and ~10% smaller, as small as level 9."""
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG", compress_type=zlib.Z_RLE)
    return buf.getvalue()


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _encode(chips: dict[str, Any], corr: np.ndarray, meta: dict[str, Any]) -> dict[str, bytes]:
    """Member bytes, WebDataset field names."""
    return {
        "ortho.png": _png(chips["ortho"]),
        "dem.npy": _npy(chips["dem"]),
        "viewshed.png": _png(chips["viewshed"]),
        "corr.npy": _npy(corr),
        "meta.json": json.dumps(meta, sort_keys=True).encode(),
    }
