"""The footprint catalogue's tables: ``catalog.parquet`` (one row per image, GeoParquet 1.1:
the visible footprint the primary geometry, the frustum's wedge and the camera point beside
it, a ``bbox`` covering column, the CRS named as the dataset's) and ``pairs.parquet`` (one row
per pair of images whose footprints intersect). The rows are built by ``pipeline.catalog``;
read by ``store.catalog.Catalog``."""

from __future__ import annotations

import json
from typing import Any

import pyarrow as pa

from mars_pairs.store.cellmask import CELLS_TYPE
from mars_pairs.store.geoparquet import BBOX_FIELDS, BBOX_TYPE, named_crs

CATALOG_FIELDS: list[tuple[str, pa.DataType]] = [
    ("key", pa.string()),
    ("product_id", pa.string()),
    ("mission", pa.string()),
    ("instrument", pa.string()),
    ("sol", pa.int32()),
    ("site", pa.int32()),
    ("drive", pa.int32()),
    ("pose", pa.int32()),
    ("time", pa.timestamp("ms", tz="UTC")),  # the label's start time, UTC
    ("lmst", pa.string()),  # local mean solar time of day, "HH:MM:SS[.fff]" (null: none)
    ("camera_x", pa.float64()),  # camera centre, map CRS, map units
    ("camera_y", pa.float64()),
    ("camera_z", pa.float64()),  # metres above the areoid, the rover standing on the DEM
    ("camera_lon", pa.float64()),  # camera centre, degrees east, the CRS's geographic base
    ("camera_lat", pa.float64()),  # degrees north
    ("easting", pa.float64()),  # rover origin, map units
    ("northing", pa.float64()),
    ("azimuth_deg", pa.float64()),  # image centre ray, clockwise from true north
    ("elevation_deg", pa.float64()),
    ("label_azimuth_deg", pa.float64()),  # the label's own derived pointing (null: none)
    ("label_elevation_deg", pa.float64()),
    ("hfov_deg", pa.float64()),
    ("vfov_deg", pa.float64()),
    ("width", pa.int32()),  # image pixels (after the size check)
    ("height", pa.int32()),
    ("camera_model", pa.string()),  # CAHV, CAHVOR, CAHVORE
    ("label_path", pa.string()),  # relative to the labels root
    ("image_path", pa.string()),  # relative to the labels root
    ("localization", pa.string()),  # "places" or "label"
    ("places_pose", pa.int32()),
    ("dem_offset_m", pa.float64()),  # DEM - PLACES elevation at the rover origin
    ("radius_m", pa.float64()),  # the view's radius, true metres
    ("view_mask", pa.string()),  # frustum or band
    ("visible_cells", pa.int64()),  # DEM cells in view
    ("visible_area_m2", pa.float64()),  # true square metres
    ("median_range_m", pa.float64()),  # horizontal range of the visible cells, true metres
    ("max_range_m", pa.float64()),
    ("footprint_parts", pa.int32()),  # separate patches of the footprint (near and far)
    ("footprint", pa.binary()),  # WKB (multi)polygon, map CRS: the visible ground
    ("wedge", pa.binary()),  # WKB polygon, map CRS: the frustum's wedge to radius_m
    ("camera_point", pa.binary()),  # WKB point, map CRS: the camera centre
    ("view_cells", CELLS_TYPE),  # the DEM cells in view, a bitmask (store.cellmask)
    ("bbox", BBOX_TYPE),  # the footprint's bounds (GeoParquet covering)
    ("hilbert", pa.int64()),  # Hilbert index of the camera centre over the DEM: the row order
]
CATALOG_SCHEMA = pa.schema(CATALOG_FIELDS)

#: catalog.parquet's geometry columns and their GeoParquet types.
CATALOG_GEOMETRY = {
    "footprint": ["Polygon", "MultiPolygon"],
    "wedge": ["Polygon"],
    "camera_point": ["Point"],
}

PAIR_FIELDS: list[tuple[str, pa.DataType]] = [
    ("key_a", pa.string()),  # key_a < key_b
    ("key_b", pa.string()),
    ("intersection_m2", pa.float64()),  # true square metres (map area over the map scale)
    ("iou", pa.float64()),  # intersection over union of the two footprints
    ("distance_m", pa.float64()),  # between the two camera centres, true metres (3-D)
    ("heading_diff_deg", pa.float64()),  # centre-ray azimuth difference, [0, 180]
    ("same_position", pa.bool_()),  # one rover position: same mission, site, drive and pose
]
PAIR_SCHEMA = pa.schema(PAIR_FIELDS)
#: the dataset's pairs add each sample's split, and whether they differ
DATASET_PAIR_SCHEMA = pa.schema(
    [*PAIR_FIELDS, ("split_a", pa.string()), ("split_b", pa.string()), ("cross_split", pa.bool_())]
)


def catalog_geo_metadata(crs: Any, bbox: list[float] | None) -> dict[bytes, bytes]:
    """GeoParquet 1.1 metadata of catalog.parquet: ``footprint`` primary with the ``bbox``
    covering and the dataset ``bbox`` ([xmin, ymin, xmax, ymax] map units), ``wedge`` and
    ``camera_point``; every column's CRS the named PROJJSON of ``crs`` (``named_crs``)."""
    projjson = named_crs(crs)
    columns: dict[str, Any] = {}
    for name, kinds in CATALOG_GEOMETRY.items():
        column: dict[str, Any] = {"encoding": "WKB", "geometry_types": kinds, "crs": projjson}
        if name == "footprint":
            column["covering"] = {"bbox": {n: ["bbox", n] for n in BBOX_FIELDS}}
            if bbox is not None:
                column["bbox"] = [float(v) for v in bbox]
        columns[name] = column
    meta = {"version": "1.1.0", "primary_column": "footprint", "columns": columns}
    return {b"geo": json.dumps(meta).encode()}


def rows_table(rows: list[dict[str, Any]], schema: pa.Schema) -> pa.Table:
    """``rows`` (dicts by column name) as a table of ``schema``."""
    return pa.Table.from_pylist(rows, schema=schema)
