"""Dense geometry members (opt-in, ``output.members``): the sample's geometry per pixel, in
both directions.

On the ground image's dense grid (every ``output.dense_stride``-th pixel, default the ray
stride; pixel (i, j) is image line i * stride, sample j * stride):

- ``range`` (H', W') float32: metres along the ray from its origin to its first terrain hit;
  ``depth`` float32: metres along the camera axis (A) from the camera centre to the hit. NaN
  for sky and for rays that leave the DEM window, meet nodata or pass ``geometry.radius``
  (metres along the ray).
- ``hits`` (H', W', 3) float64: the hit's map x, y (dataset CRS, map units) and elevation z
  (metres above the areoid).
- ``ortho_view`` (uint8) and ``dem_view`` (float32 metres, NaN invalid): the ortho and DEM
  rasters themselves (their own grids, not the chips: no second resampling, and hits off the
  chip count) sampled bilinearly at each hit: the map seen from the rover, wherever a ray
  meets the map within ``geometry.radius``; the ortho scaled to uint8 as its chip is;
  ``view_valid`` (uint8 0/255): a hit with ortho and DEM data around it.

On the chip grid (S x S, the chip's affine):

- ``ground_on_map`` (uint8, the ground image's bands): the ground image sampled (bilinear) at
  the image point of each visible chip pixel's terrain point (map x, y of its centre, the DEM
  chip's height), i.e. the nearest ray through it; ``ground_on_map_cover`` (uint8 0/255):
  visible (the viewshed chip: line of sight and the exact view test) and inside the image;
- ``ground_px`` (S, S, 2) float32: the image point of each visible chip pixel (sample, line;
  NaN where not covered), the map ``mars_pairs.raster.transfer.image_to_chip`` uses (8
  bytes a chip pixel raw, 2 MiB for a 512 px chip, ~84 KiB stored where 95 % of the chip is
  unseen).

Each member is a lossless one-strip zstd TIFF, ``<field>.tif`` (``store.dense_codec``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.pipeline.sample.ground import GroundImage
from mars_pairs.pipeline.sample.view import View, strided_rays
from mars_pairs.raster.chips import ChipGrid, ChipReader
from mars_pairs.raster.terrain import DemWindow
from mars_pairs.raster.transfer import sample_at
from mars_pairs.store.dense_codec import dense_member, encode_dense
from mars_pairs.store.members import DENSE_MEMBERS, MEMBER_FILES


@dataclass(frozen=True)
class DenseRays:
    """Rays of every ``stride``-th pixel: ``range`` and ``depth`` (H', W') metres, ``hits``
    (H', W', 3) map x, y (map units) and z (metres); NaN where a ray hits nothing."""

    range: np.ndarray
    depth: np.ndarray
    hits: np.ndarray
    stride: int


def dense_rays(view: View, stride: int, max_range_m: float) -> DenseRays:
    """Cast every ``stride``-th pixel's ray of ``view.camera`` over ``view.window`` (or reuse
    ``view.rays`` and ``view.hits`` when they were cast at that stride).

    Ray parameter t (metres along the true ray: directions are map images of unit local NED
    vectors) from hits: t = (hit - o) . d / |d|^2. Depth: (o_local + t d_local - C) . A in
    the camera's local NED frame (metres), A the unit camera axis.
    """
    camera = view.camera
    shape = (len(range(0, camera.height, stride)), len(range(0, camera.width, stride)))
    rays = view.rays if view.rays is not None and view.rays.stride == stride else None
    if rays is None:
        rays = strided_rays(camera, stride)
    origins, dirs, o_local, d_local = rays.origins, rays.dirs, rays.o_local, rays.d_local
    if view.hits is not None and view.grid_shape == shape and view.rays is rays:
        hits = view.hits
    else:
        cx, cy = (float(v) for v in camera.center_map[:2])
        hits, _ = cast_rays(origins, dirs, view.window, max_range=max_range_m, observer_xy=(cx, cy))
    t = np.einsum("ij,ij->i", hits - origins, dirs) / np.einsum("ij,ij->i", dirs, dirs)
    axis = np.asarray(camera.camera.a, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    c = np.asarray(camera.camera.c, dtype=np.float64)
    depth = (o_local - c) @ axis + t * (d_local @ axis)
    return DenseRays(
        t.reshape(shape).astype(np.float32),
        depth.reshape(shape).astype(np.float32),
        hits.reshape(*shape, 3),
        stride,
    )


def map_from_rover(
    rays: DenseRays, crs: str, ortho: ChipReader, dem: DemWindow
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ortho_view uint8, dem_view float32 metres, valid bool) on the dense grid: the ortho
    raster sampled bilinearly on its own grid at each ray's hit (map x, y in ``crs``, the
    dataset's; one windowed read, ``ChipReader.read_points``) and scaled to 0..255 by its
    ``value_range`` (as its chip); the DEM window the rays were cast over (``dem``, the same
    CRS as the hits) sampled bilinearly there, no read; valid where both have data around
    the hit, else 0 and NaN."""
    x, y = rays.hits[..., 0], rays.hits[..., 1]
    ortho_values = ortho.read_points(x, y, crs)
    col, row = dem.xy_to_colrow(x, y)
    dem_view = sample_at(dem.data, col, row, nearest=False)[0]
    valid = np.isfinite(ortho_values) & np.isfinite(dem_view)
    ortho_view = ortho.value_range().to_uint8(ortho_values)  # NaN -> 0
    invalid = ~valid
    ortho_view[invalid] = 0
    dem_view = np.asarray(dem_view, dtype=np.float32)
    dem_view[invalid] = np.nan
    return ortho_view, dem_view, valid


def chip_points(grid: ChipGrid, dem: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(N, 3) map points of chip pixels (``rows``, ``cols``): their centres' x, y (map units)
    and the DEM chip's elevation there (metres; NaN nodata)."""
    t = grid.transform
    u, v = cols + 0.5, rows + 0.5
    x = t.a * u + t.b * v + t.c
    y = t.d * u + t.e * v + t.f
    return np.column_stack([x, y, dem[rows, cols].astype(np.float64)])


def ground_pixels_of_chip(
    camera: MapCamera, grid: ChipGrid, dem: np.ndarray, visible: np.ndarray
) -> np.ndarray:
    """(S, S, 2) float32 image pixel (sample, line; centres at integers) of each visible chip
    pixel's terrain point, projected through the camera with the planet's curvature; NaN
    where ``visible`` (bool, the viewshed chip) is False or the point falls off the image."""
    return chip_ground_points(camera, grid, dem, visible).ground_px


@dataclass(frozen=True)
class ChipGroundPoints:
    """``ground_px`` (S, S, 2) float32 (see :func:`ground_pixels_of_chip`) and the chip
    pixels it covers: ``rows``, ``cols`` (N,) in row-major order and their image pixels
    ``px`` (N, 2) float32 (``ground_px[rows, cols]``)."""

    ground_px: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    px: np.ndarray


def chip_ground_points(
    camera: MapCamera, grid: ChipGrid, dem: np.ndarray, visible: np.ndarray
) -> ChipGroundPoints:
    """:func:`ground_pixels_of_chip` with the covered chip pixels (one scan of the chip)."""
    out = np.full((*visible.shape, 2), np.nan, dtype=np.float32)
    seen = np.flatnonzero(visible)  # (np.nonzero of a 2-D mask: 20x the time)
    seen = seen[np.isfinite(np.ravel(dem)[seen])]
    rows, cols = np.divmod(seen, visible.shape[1])
    px32 = np.empty((0, 2), dtype=np.float32)
    if len(rows):
        points = chip_points(grid, dem, rows, cols)
        px, inside = project_inside(camera, camera.local_points(points, MARS_RADIUS_M))
        rows, cols, px32 = rows[inside], cols[inside], px[inside].astype(np.float32)
        out[rows, cols] = px32  # finite: project_inside's points
    return ChipGroundPoints(out, rows, cols, px32)


def project_inside(camera: MapCamera, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) image pixels (sample, line) of (N, 3) points in the camera model's local frame
    (``MapCamera.local_points``), and whether each falls inside the image."""
    px = camera.camera.project(local)
    with np.errstate(invalid="ignore"):
        inside = (
            np.isfinite(px).all(axis=1)
            & (px[:, 0] >= -0.5)
            & (px[:, 0] <= camera.width - 0.5)
            & (px[:, 1] >= -0.5)
            & (px[:, 1] <= camera.height - 0.5)
        )
    return px, inside


def ground_on_map(pixels: np.ndarray, ground_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(colours uint8 (S, S[, C]), cover bool (S, S)): the ground image ``pixels`` (H, W[, C]
    uint8) sampled bilinearly at ``ground_px``; 0 where not covered."""
    rows, cols = np.divmod(np.flatnonzero(np.isfinite(ground_px[..., 0])), ground_px.shape[1])
    return colours_on_map(pixels, ground_px.shape[:2], rows, cols, ground_px[rows, cols])


def colours_on_map(
    pixels: np.ndarray, shape: tuple[int, ...], rows: np.ndarray, cols: np.ndarray, px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ground_on_map` from the covered chip pixels (``rows``, ``cols``) of a chip of
    ``shape`` (S, S) and their image pixels ``px`` (N, 2): ``ChipGroundPoints``. ``pixels``
    (H, W, 4) are RGB and padding (``GroundImage.pixels``): the colours have 3 bands."""
    values, ok = sample_at(pixels, px[:, 0], px[:, 1], nearest=False, fill=0)
    bands = pixels.shape[2:]
    if bands == (4,):  # RGBX
        values, bands = values[:, :3], (3,)
    colours = np.zeros(tuple(shape) + bands, dtype=np.uint8)
    cover = np.zeros(tuple(shape), dtype=bool)
    colours[rows, cols] = np.rint(values).clip(0, 255).astype(np.uint8)
    cover[rows, cols] = ok
    return colours, cover


def dense_members(
    view: View,
    grid: ChipGrid,
    chips: dict[str, Any],
    ground: GroundImage,
    members: tuple[str, ...],
    stride: int,
    max_range_m: float,
    ortho: ChipReader,
) -> tuple[dict[str, bytes], dict[str, Any]]:
    """The member bytes of ``members`` (see the module docstring) and their meta entries;
    ``ground``: the ground member (its decoded pixels when kept, else its bytes decoded);
    ``ortho``: the ortho raster (the map seen from the rover samples it, and the DEM window
    ``view.window``)."""
    out: dict[str, bytes] = {}
    meta: dict[str, Any] = {"dense_members": list(members)}
    wanted = set(members)
    if wanted & {"range", "depth", "hits", "ortho_view", "dem_view"}:
        rays = dense_rays(view, stride, max_range_m)
        meta["dense_stride"] = stride
        meta["dense_shape"] = list(rays.range.shape)
        if "range" in wanted:
            out["range"] = encode_dense("range", rays.range)
        if "depth" in wanted:
            out["depth"] = encode_dense("depth", rays.depth)
        if "hits" in wanted:
            out["hits"] = encode_dense("hits", rays.hits)
        if wanted & {"ortho_view", "dem_view"}:
            ortho_view, dem_view, valid = map_from_rover(rays, grid.crs, ortho, view.window)
            if "ortho_view" in wanted:
                out["ortho_view"] = encode_dense("ortho_view", ortho_view)
            out["view_valid"] = encode_dense("view_valid", valid.view(np.uint8) * np.uint8(255))
            if "dem_view" in wanted:
                out["dem_view"] = encode_dense("dem_view", dem_view)
    if wanted & {"ground_on_map", "ground_px"}:
        visible = np.asarray(chips["viewshed"]) > 0
        points = chip_ground_points(view.camera, grid, chips["dem"], visible)
        if "ground_on_map" in wanted:
            assert ground.pixels is not None  # build_sample keeps them when ground_on_map is on
            shape = points.ground_px.shape[:2]
            colours, cover = colours_on_map(
                ground.pixels, shape, points.rows, points.cols, points.px
            )
            out["ground_on_map"] = encode_dense("ground_on_map", colours)
            cover_255 = cover.view(np.uint8) * np.uint8(255)
            out["ground_on_map_cover"] = encode_dense("ground_on_map_cover", cover_255)
        if "ground_px" in wanted:
            out["ground_px"] = encode_dense("ground_px", points.ground_px)
    files = {dense_member(f): data for f, data in out.items()}
    order = [f for m in DENSE_MEMBERS for f in MEMBER_FILES[m]]
    return {f: files[f] for f in dict.fromkeys(order) if f in files}, meta
