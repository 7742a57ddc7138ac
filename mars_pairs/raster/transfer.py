"""Moving rasters between a ground image and its orbital chip, occlusion honoured.

Two pixel maps tie the views together (both built by ``mars_pairs.pipeline.sample.dense`` and stored
as members):

- ``ground_px`` (S, S, 2) float32 on the chip grid: the ground-image pixel (sample, line;
  first pixel centre at (0, 0), full image resolution) where each chip pixel's terrain point
  (its map x, y and the DEM chip's height) is seen; NaN where the chip pixel is not visible
  from the camera (line of sight and the image's frustum: the viewshed chip) or off the image.
- ``chip_px`` (H', W', 2) on the image's dense grid (every ``stride``-th pixel): the chip pixel
  (column, row; pixel-edge coordinates, first pixel centre at (0.5, 0.5)) of each ray's first
  terrain hit; NaN for sky, rays leaving the DEM or the radius. ``corr`` is this map at the
  ray stride; ``hits`` give it at the dense stride through the chip's affine.

``image_to_chip`` carries a raster on the ground image grid onto the chip through
``ground_px``; ``chip_to_image`` carries a chip raster into the image through ``chip_px``.
Labels (classes, masks) go ``nearest``; values (colours, heights) bilinear. Both return the
moved raster and its validity mask (True where a value was carried).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from mars_pairs.errors import ArgumentError


@njit(cache=True)
def _sample_points(
    src: NDArray[Any], u: NDArray[np.float64], v: NDArray[np.float64], nearest: bool, fill: float
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Values of ``src`` (H, W, C, any numeric dtype) as float32 at grid points (u, v) (N,)
    = (col, row) with cell centres at integers; rows of ``fill`` and valid False where a
    point is NaN, off the grid or (bilinear) next to a NaN value. Serial: a sample's points
    take ~1 ms, less than a parallel region's start on a busy machine."""
    h, w, nc = src.shape
    n = u.shape[0]
    out = np.empty((n, nc), dtype=np.float32)
    valid = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        x = u[i]
        y = v[i]
        for k in range(nc):
            out[i, k] = fill
        if not (x >= -0.5 and y >= -0.5 and x <= w - 0.5 and y <= h - 0.5):
            continue
        if nearest:
            c = min(math.floor(x + 0.5), w - 1)
            r = min(math.floor(y + 0.5), h - 1)
            ok = True
            for k in range(nc):
                ok = ok and src[r, c, k] == src[r, c, k]
            if ok:
                for k in range(nc):
                    out[i, k] = np.float64(src[r, c, k])
                valid[i] = True
            continue
        x = min(max(x, 0.0), w - 1.0)
        y = min(max(y, 0.0), h - 1.0)
        c0 = min(int(x), w - 2) if w > 1 else 0
        r0 = min(int(y), h - 2) if h > 1 else 0
        c1 = min(c0 + 1, w - 1)
        r1 = min(r0 + 1, h - 1)
        fx = x - c0
        fy = y - r0
        ok = True
        for k in range(nc):
            v00 = np.float64(src[r0, c0, k])
            v01 = np.float64(src[r0, c1, k])
            v10 = np.float64(src[r1, c0, k])
            v11 = np.float64(src[r1, c1, k])
            val = (v00 * (1 - fx) + v01 * fx) * (1 - fy) + (v10 * (1 - fx) + v11 * fx) * fy
            out[i, k] = val
            ok = ok and val == val
        if ok:
            valid[i] = True
        else:
            for k in range(nc):
                out[i, k] = fill
    return out, valid


def sample_at(
    raster: NDArray[Any], u: NDArray[Any], v: NDArray[Any], *, nearest: bool, fill: float = math.nan
) -> tuple[NDArray[Any], NDArray[np.bool_]]:
    """``raster`` (H, W) or (H, W, C) at points (u, v) of any shape, in its grid coordinates
    (column, row; pixel centres at integers): (values of shape u.shape [+ (C,)], valid).

    Nearest keeps the raster's dtype (``fill`` where invalid, cast); bilinear gives float32
    (``fill``, NaN by default, where invalid: off the raster or next to a NaN value).
    """
    arr = np.asarray(raster)
    if arr.ndim not in (2, 3):
        raise ArgumentError(f"raster must be (H, W) or (H, W, C), got shape {arr.shape}")
    if arr.dtype == np.bool_ or arr.dtype.kind not in "uif":
        arr = arr.astype(np.uint8 if arr.dtype == np.bool_ else np.float64)
    # the kernel reads the raster's own dtype (one compiled version per dtype): no float copy
    src = np.ascontiguousarray(arr.reshape(*arr.shape[:2], -1))
    uu = np.ascontiguousarray(np.asarray(u, dtype=np.float64).ravel())
    vv = np.ascontiguousarray(np.asarray(v, dtype=np.float64).ravel())
    if uu.shape != vv.shape:
        raise ArgumentError(f"u {np.shape(u)} and v {np.shape(v)} differ in shape")
    fill32 = np.float32(0.0 if (nearest and math.isnan(fill)) else fill)
    values, valid = _sample_points(src, uu, vv, nearest, fill32)
    shape = tuple(np.shape(u)) + (() if arr.ndim == 2 else (arr.shape[2],))
    values = values.reshape(shape)
    if nearest:
        if np.issubdtype(arr.dtype, np.integer) or arr.dtype == np.bool_:
            values = np.rint(values).astype(arr.dtype)
        else:
            values = values.astype(arr.dtype)
    return values, valid.reshape(np.shape(u))


def image_to_chip(
    raster: NDArray[Any],
    ground_px: NDArray[Any],
    *,
    nearest: bool,
    stride: int = 1,
    fill: float = math.nan,
) -> tuple[NDArray[Any], NDArray[np.bool_]]:
    """A ground-image raster (H, W[, C]) carried onto the chip grid through ``ground_px``
    (S, S, 2: image sample, line of each chip pixel, full-resolution pixel centres at
    integers; NaN = not visible). ``stride``: the raster holds every ``stride``-th image
    pixel (pixel (i, j) at image line i * stride, sample j * stride). Returns (S, S[, C])
    values and the coverage mask: visible chip pixels whose image point lies on the raster.
    """
    px = np.asarray(ground_px, dtype=np.float64)
    return sample_at(raster, px[..., 0] / stride, px[..., 1] / stride, nearest=nearest, fill=fill)


def chip_to_image(
    raster: NDArray[Any], chip_px: NDArray[Any], *, nearest: bool, fill: float = math.nan
) -> tuple[NDArray[Any], NDArray[np.bool_]]:
    """A chip raster (S, S[, C]) carried into the image grid of ``chip_px`` (H', W', 2: chip
    column, row of each image pixel's first terrain hit, pixel-edge coordinates; NaN for no
    hit, so occluded terrain is never reached). Returns (H', W'[, C]) values and validity:
    a hit on the chip with a finite value there."""
    px = np.asarray(chip_px, dtype=np.float64)
    return sample_at(raster, px[..., 0] - 0.5, px[..., 1] - 0.5, nearest=nearest, fill=fill)
