"""Raster masks as polygons: the cells of a mask vectorized (``rasterio.features.shapes``) into
one (multi)polygon in the raster's CRS, holes and separate patches kept, then simplified."""

from __future__ import annotations

import numpy as np
import shapely
from affine import Affine
from rasterio import features
from shapely.geometry.base import BaseGeometry

from mars_pairs.store.cellmask import set_box

#: The simplification tolerance as a fraction of the raster's cell (map units): the outline
#: moves by at most a quarter cell, below the DEM cell the footprint is measured on.
SIMPLIFY_CELLS = 0.25


def mask_outline(
    mask: np.ndarray, transform: Affine, tolerance: float | None = None
) -> shapely.Polygon | shapely.MultiPolygon | None:
    """The set cells of ``mask`` (uint8 or bool, 1 = in) as a polygon or multipolygon in the
    CRS of ``transform`` (cell edges: each cell is its whole square), 4-connected patches as
    separate parts, holes kept; simplified (topology kept) by ``tolerance`` map units, default
    ``SIMPLIFY_CELLS`` of the larger cell side. None when no cell is set.

    Only the bounding box of the set cells is traced (a view covers a fraction of its window).
    """
    data = np.asarray(mask).astype(np.uint8, copy=False)
    found = set_box(data)
    if found is None:
        return None
    r0, r1, c0, c1 = found
    sub = np.ascontiguousarray(data[r0:r1, c0:c1])
    sub_transform = transform * Affine.translation(c0, r0)
    polygons = [
        shapely.Polygon(
            np.asarray(geom["coordinates"][0]), [np.asarray(h) for h in geom["coordinates"][1:]]
        )
        for geom, value in features.shapes(sub, mask=sub > 0, transform=sub_transform)
        if value > 0
    ]
    if tolerance is None:
        tolerance = SIMPLIFY_CELLS * max(abs(transform.a), abs(transform.e))
    shape: shapely.Polygon | shapely.MultiPolygon = (
        polygons[0] if len(polygons) == 1 else shapely.MultiPolygon(polygons)
    )
    simple: BaseGeometry = shape
    if tolerance > 0:
        simple = shapely.simplify(shape, tolerance, preserve_topology=True)
    if not simple.is_valid:
        simple = shapely.make_valid(simple)
    kept = [g for g in getattr(simple, "geoms", [simple]) if isinstance(g, shapely.Polygon)]
    if isinstance(simple, shapely.Polygon | shapely.MultiPolygon):
        return simple
    return kept[0] if len(kept) == 1 else shapely.MultiPolygon(kept)


def outline_parts(shape: shapely.Polygon | shapely.MultiPolygon | None) -> int:
    """The number of separate patches (polygons) of an outline; 0 for None."""
    if shape is None:
        return 0
    return len(shape.geoms) if isinstance(shape, shapely.MultiPolygon) else 1
