"""Where a sample lies: its chips' CRS, bounds, affine transform and rotation; its keypoints.

A sample carries, as torchgeo samples do, ``crs`` (the dataset CRS as WKT), ``bounds``
(float64 [4]: xmin, ymin, xmax, ymax of the chip in map units, axis-aligned) and
``transform`` (float64 [6]: the affine a, b, c, d, e, f in rasterio's order, chip pixel
(column, row) with a pixel-edge origin -> map x, y), and ``rotation`` (float64 scalar:
the map azimuth, degrees clockwise from grid north, of the chip's up direction; 0 north-up).

``corr`` are keypoints: ``corr[:, i, j]`` is the chip pixel (column, row) hit by the ray of
ground pixel (line i*k, sample j*k) of the label's image (k the ray stride, NaN for no hit).
``corr_ground[:, i, j]`` is that ground pixel's centre as (x, y) in the sample's ground
image, pixel-edge coordinates (a pixel's centre at +0.5): the pair moves with the images
under :mod:`mars_pairs.torch.transforms`.
"""

from __future__ import annotations

import math

import numpy as np

#: The manifest columns a sample's georeferencing is made of.
GEO_COLUMNS = ("chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax", "chip_rotation_deg")


def chip_transform(
    bounds: tuple[float, float, float, float], rotation_deg: float, size_px: int
) -> tuple[float, float, float, float, float, float]:
    """The affine (a, b, c, d, e, f), chip pixel -> map, of a square chip of ``size_px``
    pixels whose axis-aligned map ``bounds`` (map units) and ``rotation_deg`` (azimuth of its
    up direction, degrees clockwise from grid north) the manifest holds.

    The chip's side is the bounds' width over |cos t| + |sin t| (a square turned by t spans
    that much more); columns run along (cos t, -sin t), rows along (-sin t, -cos t).
    """
    xmin, ymin, xmax, ymax = bounds
    t = math.radians(rotation_deg)
    side = (xmax - xmin) / (abs(math.cos(t)) + abs(math.sin(t)))
    res = side / size_px
    a, d = res * math.cos(t), -res * math.sin(t)
    b, e = -res * math.sin(t), -res * math.cos(t)
    half = size_px / 2.0
    cx, cy = (xmin + xmax) / 2.0, (ymin + ymax) / 2.0
    return (a, b, cx - (a + b) * half, d, e, cy - (d + e) * half)


def rotation_of(transform: tuple[float, ...] | np.ndarray) -> float:
    """The map azimuth (degrees clockwise from grid north, in [0, 360)) of a chip's up
    direction (decreasing rows) under an affine (a, b, c, d, e, f)."""
    b, e = float(transform[1]), float(transform[4])
    return math.degrees(math.atan2(-b, -e)) % 360.0


def bounds_of(
    transform: tuple[float, ...] | np.ndarray, height: int, width: int
) -> tuple[float, float, float, float]:
    """Axis-aligned map bounds (xmin, ymin, xmax, ymax) of a ``height`` x ``width`` chip."""
    a, b, c, d, e, f = (float(v) for v in transform[:6])
    cols = np.array([0.0, width, width, 0.0])
    rows = np.array([0.0, 0.0, height, height])
    xs, ys = a * cols + b * rows + c, d * cols + e * rows + f
    return (float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max()))


def corr_ground_grid(
    grid_hw: tuple[int, int],
    stride: int,
    image_wh: tuple[int, int],
    ground_hw: tuple[int, int],
) -> np.ndarray:
    """float32 [2, h, w]: (x, y) of each corr cell's ground pixel in a ``ground_hw`` image.

    Cell (i, j) is the label image's pixel (line i*stride, sample j*stride) of an image of
    ``image_wh`` (width, height) pixels; its centre scales to the ground image's size.
    """
    h, w = grid_hw
    width, height = image_wh
    sx, sy = ground_hw[1] / width, ground_hw[0] / height
    x = (np.arange(w, dtype=np.float64) * stride + 0.5) * sx
    y = (np.arange(h, dtype=np.float64) * stride + 0.5) * sy
    out = np.empty((2, h, w), dtype=np.float32)
    out[0] = x[None, :]
    out[1] = y[:, None]
    return out
