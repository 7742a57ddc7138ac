"""The study's single-image job: a viewshed GeoTIFF that QGIS shows as it is."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from mars_pairs.geometry.frames import MARS_RADIUS_M
from mars_pairs.kernels.viewshed import compute_viewshed
from mars_pairs.raster.terrain import DemWindow, Terrain
from mars_pairs.store.atomic import atomic_path

NODATA = 255
COLOURS = {0: (60, 60, 60, 90), 1: (40, 220, 90, 255), NODATA: (0, 0, 0, 0)}


@dataclass(frozen=True)
class ViewshedRequest:
    """Observer and band for one viewshed, in the DEM's CRS (x, y map units; metres; degrees).

    ``height`` is above the terrain (or an absolute elevation when ``height_is_absolute``);
    ``az_band`` is (start, end) clockwise from north; ``el_band`` (low, high) from horizontal.
    """

    x: float
    y: float
    height: float
    radius: float
    az_band: tuple[float, float] | None = None
    el_band: tuple[float, float] | None = None
    height_is_absolute: bool = False


def compute_request(terrain: Terrain, req: ViewshedRequest) -> tuple[np.ndarray, DemWindow]:
    """Viewshed of a request on the DEM window around the observer: (uint8 codes, window).

    Codes: 1 visible, 0 not visible, 255 outside the radius or no DEM data.
    """
    window = terrain.read_dem_window(req.x, req.y, req.radius)
    mask = compute_viewshed(
        window,
        req.x,
        req.y,
        height=req.height,
        height_is_absolute=req.height_is_absolute,
        radius=req.radius,
        az_band=req.az_band,
        el_band=req.el_band,
        planet_radius=MARS_RADIUS_M,
    )
    x, y = window.centres_xy()
    outside = (np.hypot(x - req.x, y - req.y) > req.radius) | ~np.isfinite(window.data)
    codes = np.where(outside, NODATA, mask).astype(np.uint8)
    return codes, window


def write_viewshed_geotiff(path: str | Path, codes: np.ndarray, transform: Any, crs: Any) -> None:
    """A compressed, tiled GeoTIFF of viewshed ``codes`` (1 visible, 0 hidden, 255 nodata) on
    the grid ``transform`` (affine, pixel corners -> CRS x, y) in ``crs``, with a colour
    table; written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    profile = {
        "driver": "GTiff",
        "width": codes.shape[1],
        "height": codes.shape[0],
        "count": 1,
        "dtype": "uint8",
        "crs": crs,
        "transform": transform,
        "nodata": NODATA,
        "compress": "deflate",
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "photometric": "palette",
    }
    with atomic_path(path) as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.write(codes, 1)
        dst.write_colormap(1, COLOURS)
        dst.update_tags(1, visible="1", not_visible="0", nodata=str(NODATA))
        dst.set_band_description(1, "viewshed (1 visible, 0 hidden)")
