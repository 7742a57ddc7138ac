"""GeoParquet 1.1 metadata of the manifest: footprint CRS, dataset bbox, bbox covering column."""

from __future__ import annotations

import json
from typing import Any

import pyarrow as pa
from pyproj import CRS

BBOX_FIELDS = ("xmin", "ymin", "xmax", "ymax")
BBOX_TYPE = pa.struct([(name, pa.float64()) for name in BBOX_FIELDS])


def geo_metadata(crs: str, bbox: list[float] | None) -> dict[bytes, bytes]:
    """GeoParquet 1.1 metadata for the ``footprint`` column: CRS as PROJJSON, the dataset
    ``bbox`` (from ``footprints_bbox``) and the ``bbox`` covering column."""
    column: dict[str, Any] = {
        "encoding": "WKB",
        "geometry_types": ["Polygon"],
        "crs": json.loads(CRS.from_user_input(crs).to_json()),
        "covering": {"bbox": {name: ["bbox", name] for name in BBOX_FIELDS}},
    }
    if bbox is not None:
        column["bbox"] = bbox
    meta = {"version": "1.1.0", "primary_column": "footprint", "columns": {"footprint": column}}
    return {b"geo": json.dumps(meta).encode()}


def footprint_bounds(footprint: Any) -> dict[str, float] | None:
    """The ``bbox`` column value of a footprint polygon (map units), None for no footprint."""
    if footprint is None:
        return None
    return dict(zip(BBOX_FIELDS, (float(v) for v in footprint.bounds), strict=True))


def footprints_bbox(table: pa.Table) -> list[float] | None:
    """[xmin, ymin, xmax, ymax] over every row's footprint bbox; None when there is none."""
    import pyarrow.compute as pc

    if table.num_rows == 0 or table["bbox"].null_count == table.num_rows:
        return None
    box = pc.struct_field
    col = table["bbox"]
    return [
        pc.min(box(col, "xmin")).as_py(),
        pc.min(box(col, "ymin")).as_py(),
        pc.max(box(col, "xmax")).as_py(),
        pc.max(box(col, "ymax")).as_py(),
    ]
