"""Orbital chips: a square grid around the rover, north-up or heading-up, read by window.

A chip grid is ``size_px`` x ``size_px`` pixels covering ``size_m`` x ``size_m`` map units,
centred on a map point (x, y in the dataset CRS). Heading-up grids are rotated so that the
camera azimuth points up the image (row 0 towards the azimuth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import rasterio
from affine import Affine
from numpy.typing import ArrayLike, NDArray
from rasterio.enums import Resampling
from rasterio.warp import reproject

from mars_pairs.frames import crs_string


@dataclass(frozen=True)
class ChipGrid:
    """A chip's pixel grid on the map: affine transform (pixel -> map), CRS and size.

    ``rotation_deg`` is the map azimuth (clockwise from grid north) of the chip's up direction.
    """

    transform: Affine
    crs: str
    size_px: int
    center_x: float
    center_y: float
    size_m: float
    rotation_deg: float = 0.0

    @classmethod
    def around(
        cls, x: float, y: float, size_m: float, size_px: int, crs: object, rotation_deg: float = 0.0
    ) -> ChipGrid:
        """A grid centred on map point (x, y) whose up direction is ``rotation_deg``."""
        res = size_m / size_px
        t = math.radians(rotation_deg)
        right = (math.cos(t), -math.sin(t))  # map direction of increasing column
        down = (-math.sin(t), -math.cos(t))  # map direction of increasing row
        a, b = res * right[0], res * down[0]
        d, e = res * right[1], res * down[1]
        half = size_px / 2.0
        c = x - (a + b) * half
        f = y - (d + e) * half
        return cls(Affine(a, b, c, d, e, f), crs_string(crs), size_px, x, y, size_m, rotation_deg)

    @property
    def resolution(self) -> float:
        """Map units per pixel."""
        return self.size_m / self.size_px

    def corners(self) -> NDArray[np.float64]:
        """Map coordinates (4, 2) of the outer corners: top-left, top-right, bottom-right, ..."""
        n = self.size_px
        return np.array([self.transform @ p for p in ((0, 0), (n, 0), (n, n), (0, n))])

    def bounds(self) -> tuple[float, float, float, float]:
        """Axis-aligned map bounds (xmin, ymin, xmax, ymax) of the chip."""
        c = self.corners()
        return (
            float(c[:, 0].min()),
            float(c[:, 1].min()),
            float(c[:, 0].max()),
            float(c[:, 1].max()),
        )

    def to_pixel(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Map points -> chip pixel coordinates (..., 2) as (column, row), pixel-edge origin."""
        inv = ~self.transform
        xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        col = inv.a * xs + inv.b * ys + inv.c
        row = inv.d * xs + inv.e * ys + inv.f
        return np.stack([col, row], axis=-1)


def read_chip(
    path: str, grid: ChipGrid, *, resampling: Resampling = Resampling.bilinear, band: int = 1
) -> NDArray[np.float32]:
    """Resample one band of a raster onto a chip grid; nodata and outside become NaN.

    GDAL's warper reads only the source blocks the chip touches, never the whole raster, and
    reprojects from the raster's CRS when it differs from the chip's.
    """
    out = np.full((grid.size_px, grid.size_px), np.nan, dtype=np.float32)
    with rasterio.open(path) as src:
        reproject(
            source=rasterio.band(src, band),
            destination=out,
            src_nodata=src.nodata,
            dst_transform=grid.transform,
            dst_crs=grid.crs,
            dst_nodata=np.nan,
            resampling=resampling,
            tolerance=0.0,
        )
    return out


def resample_array(
    values: NDArray[np.generic],
    transform: Affine,
    crs: object,
    grid: ChipGrid,
    resampling: Resampling = Resampling.nearest,
    nodata: float = np.nan,
) -> NDArray[np.float32]:
    """Resample an in-memory grid (e.g. a viewshed on the DEM window) onto a chip grid."""
    out = np.full((grid.size_px, grid.size_px), nodata, dtype=np.float32)
    reproject(
        source=np.asarray(values, dtype=np.float32),
        destination=out,
        src_transform=transform,
        src_crs=crs_string(crs),
        dst_transform=grid.transform,
        dst_crs=grid.crs,
        dst_nodata=nodata,
        resampling=resampling,
        tolerance=0.0,
    )
    return out
