"""GeoParquet 1.1 metadata of the manifest: its geometry columns (``footprint``, the primary,
``rover_point`` and ``chip_box``), a named CRS as PROJJSON, the bboxes and the ``bbox``
covering column of the footprints."""

from __future__ import annotations

import json
from typing import Any

import pyarrow as pa
from pyproj import CRS

BBOX_FIELDS = ("xmin", "ymin", "xmax", "ymax")
BBOX_TYPE = pa.struct([(name, pa.float64()) for name in BBOX_FIELDS])

#: The manifest's GeoParquet geometry columns (WKB, dataset CRS, map units) and their types.
GEOMETRY_COLUMNS = {"footprint": "Polygon", "rover_point": "Point", "chip_box": "Polygon"}
PRIMARY_COLUMN = "footprint"

#: Mars sphere radius (metres) of the IAU 2015 Mars 2000 sphere.
_MARS_SPHERE_M = 3396190.0
#: IAU_2015 codes tried for an exact match of the dataset CRS (eqc clon 0, the sphere).
_IAU_CODES = ("49910", "49900")


def named_crs(crs: Any) -> dict[str, Any]:
    """The PROJJSON of ``crs`` (WKT, PROJ text or a pyproj/rasterio CRS) with a name.

    The IAU_2015 definition when the CRS is one (e.g. IAU_2015:49910, equirectangular clon 0
    on the Mars sphere); otherwise the CRS as given, an unnamed Mars equidistant cylindrical
    CRS named for its parameters ("Mars 2000 Equidistant Cylindrical (lat_ts 18.4663,
    lon_0 0), sphere R 3396190 m") and an unnamed geographic base CRS, datum and sphere named
    after the Mars 2000 sphere."""
    crs = CRS.from_user_input(crs if isinstance(crs, str) else str(crs.to_wkt()))
    for code in _IAU_CODES:
        try:
            iau = CRS.from_authority("IAU_2015", code)
        except Exception:  # an older PROJ database without the IAU codes
            break
        if crs.equals(iau, ignore_axis_order=True):
            return iau.to_json_dict()
    doc: dict[str, Any] = crs.to_json_dict()
    radius = crs.ellipsoid.semi_major_metre if crs.ellipsoid is not None else None
    sphere = (
        crs.ellipsoid is not None
        and crs.ellipsoid.semi_major_metre == crs.ellipsoid.semi_minor_metre
    )
    mars = radius is not None and abs(radius - _MARS_SPHERE_M) < 1.0
    body = f"sphere R {radius:.0f} m" if sphere else f"ellipsoid a {radius:.0f} m"
    if _unnamed(doc.get("name")):
        doc["name"] = _projected_name(crs, body) if mars else f"Unnamed CRS ({crs.to_proj4()})"
    base = doc.get("base_crs")
    if mars and isinstance(base, dict):
        if _unnamed(base.get("name")):
            base["name"] = "Mars 2000 (sphere), planetocentric" if sphere else "Mars 2000"
        datum = base.get("datum")
        if isinstance(datum, dict):
            if _unnamed(datum.get("name")):
                datum["name"] = "Mars 2000 (sphere)" if sphere else "Mars 2000"
            ell = datum.get("ellipsoid")
            if isinstance(ell, dict) and _unnamed(ell.get("name")):
                ell["name"] = "Mars 2000 IAU sphere" if sphere else "Mars 2000 IAU"
    return doc


def crs_name(crs: Any) -> str:
    """The name ``named_crs`` gives ``crs``."""
    return str(named_crs(crs)["name"])


def _unnamed(name: Any) -> bool:
    return not name or str(name).lower() in ("unknown", "unnamed", "undefined")


def _projected_name(crs: CRS, body: str) -> str:
    import warnings

    op = crs.coordinate_operation
    if op is None:
        return f"Mars 2000 {crs.type_name}, {body}"
    params = {p.name: p.value for p in op.params}
    if "Equidistant Cylindrical" in op.method_name or "Equirectangular" in op.method_name:
        lat_ts = params.get("Latitude of 1st standard parallel", 0.0)
        lon_0 = params.get("Longitude of natural origin", 0.0)
        return f"Mars 2000 Equidistant Cylindrical (lat_ts {lat_ts:g}, lon_0 {lon_0:g}), {body}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        proj = crs.to_proj4()
    return f"Mars 2000 {op.method_name} ({proj}), {body}"


def geo_metadata(
    crs: Any, bbox: list[float] | None, bboxes: dict[str, list[float] | None] | None = None
) -> dict[bytes, bytes]:
    """GeoParquet 1.1 metadata of the manifest's geometry columns (``GEOMETRY_COLUMNS``,
    primary ``footprint``): the CRS as named PROJJSON (``named_crs``), the footprint's
    dataset ``bbox`` (from ``footprints_bbox``) and ``bbox`` covering column; ``bboxes``:
    the other columns' bboxes ([xmin, ymin, xmax, ymax], map units; ``geometry_bboxes``)."""
    projjson = named_crs(crs)
    columns: dict[str, Any] = {}
    for name, kind in GEOMETRY_COLUMNS.items():
        column: dict[str, Any] = {"encoding": "WKB", "geometry_types": [kind], "crs": projjson}
        box = bbox if name == PRIMARY_COLUMN else (bboxes or {}).get(name)
        if name == PRIMARY_COLUMN:
            column["covering"] = {"bbox": {n: ["bbox", n] for n in BBOX_FIELDS}}
        if box is not None:
            column["bbox"] = [float(v) for v in box]
        columns[name] = column
    meta = {"version": "1.1.0", "primary_column": PRIMARY_COLUMN, "columns": columns}
    return {b"geo": json.dumps(meta).encode()}


def table_geo_metadata(table: pa.Table, crs: Any) -> dict[bytes, bytes]:
    """``geo_metadata`` of a manifest table (every bbox computed from its rows), the geometry
    columns it lacks left out (a query's selection of columns)."""
    meta = geo_metadata(crs, footprints_bbox(table), geometry_bboxes(table))
    doc = json.loads(meta[b"geo"])
    doc["columns"] = {k: v for k, v in doc["columns"].items() if k in table.column_names}
    if PRIMARY_COLUMN not in doc["columns"] and doc["columns"]:
        doc["primary_column"] = next(iter(doc["columns"]))
    if "bbox" not in table.column_names and PRIMARY_COLUMN in doc["columns"]:
        doc["columns"][PRIMARY_COLUMN].pop("covering", None)
    return {b"geo": json.dumps(doc).encode()}


#: The columns whose extremes ``table_geo_metadata`` reads (the ``bbox`` struct's fields too).
_EXTREME_COLUMNS = ("easting", "northing", "chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax")


def geo_extremes(table: pa.Table) -> pa.Table:
    """A table of at most two rows, the columns of ``table`` (types kept, metadata and
    nullability not), whose :func:`table_geo_metadata` is ``table``'s: the minimum and the
    maximum of each column (and ``bbox`` field) the bboxes come from, null elsewhere. The
    extremes of concatenated extremes are those of the concatenated tables, so a manifest
    written a batch at a time gets its metadata from one small table."""
    import pyarrow.compute as pc

    schema = pa.schema([(f.name, f.type) for f in table.schema])
    if table.num_rows == 0:
        return schema.empty_table()
    columns = []
    for field in schema:
        col = table[field.name]
        if field.name in _EXTREME_COLUMNS:
            values = pa.array([pc.min(col).as_py(), pc.max(col).as_py()], field.type)
        elif field.name == "bbox" and col.null_count < len(col):
            low = {n: pc.min(pc.struct_field(col, n)).as_py() for n in BBOX_FIELDS}
            high = {n: pc.max(pc.struct_field(col, n)).as_py() for n in BBOX_FIELDS}
            values = pa.array([low, high], field.type)
        else:
            values = pa.nulls(2, field.type)
        columns.append(values)
    return pa.Table.from_arrays(columns, schema=schema)


def geometry_bboxes(table: pa.Table) -> dict[str, list[float] | None]:
    """[xmin, ymin, xmax, ymax] (map units) of ``rover_point`` (from easting/northing) and
    ``chip_box`` (from chip_xmin..chip_ymax) over the table's rows; None without rows."""
    import pyarrow.compute as pc

    def box(xmin: str, ymin: str, xmax: str, ymax: str) -> list[float] | None:
        names = table.column_names
        if table.num_rows == 0 or not all(c in names for c in (xmin, ymin, xmax, ymax)):
            return None
        values = [
            pc.min(table[xmin]).as_py(),
            pc.min(table[ymin]).as_py(),
            pc.max(table[xmax]).as_py(),
            pc.max(table[ymax]).as_py(),
        ]
        return None if any(v is None for v in values) else values

    return {
        "rover_point": box("easting", "northing", "easting", "northing"),
        "chip_box": box("chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax"),
    }


def footprint_bounds(footprint: Any) -> dict[str, float] | None:
    """The ``bbox`` column value of a footprint polygon (map units), None for no footprint."""
    if footprint is None:
        return None
    return dict(zip(BBOX_FIELDS, (float(v) for v in footprint.bounds), strict=True))


def footprints_bbox(table: pa.Table) -> list[float] | None:
    """[xmin, ymin, xmax, ymax] over every row's footprint bbox; None when there is none."""
    import pyarrow.compute as pc

    if (
        table.num_rows == 0
        or "bbox" not in table.column_names
        or table["bbox"].null_count == table.num_rows
    ):
        return None
    box = pc.struct_field
    col = table["bbox"]
    return [
        pc.min(box(col, "xmin")).as_py(),
        pc.min(box(col, "ymin")).as_py(),
        pc.max(box(col, "xmax")).as_py(),
        pc.max(box(col, "ymax")).as_py(),
    ]


def describe_crs(text: str | None) -> tuple[str, str]:
    """The dataset CRS (``text``: WKT, PROJJSON or PROJ text, as dataset.json or the
    manifest's GeoParquet metadata hold it) in words (:func:`crs_description`) and its first
    axis unit ("m" for metres); ("unknown CRS", "map units") without a text and ("unreadable
    CRS", "map units") when pyproj cannot read it."""
    from pyproj.exceptions import CRSError

    if not text:
        return "unknown CRS", "map units"
    try:
        crs = CRS.from_user_input(text)
    except CRSError:
        return "unreadable CRS", "map units"
    unit = crs.axis_info[0].unit_name if crs.axis_info else "map units"
    return crs_description(crs), "m" if unit in ("metre", "meter") else unit


def crs_description(crs: CRS) -> str:
    """A pyproj CRS in words: its name, or (for an unnamed one, as GDAL writes many Mars
    CRSs) its projection method, body and non-zero parameters."""
    if crs.name and crs.name.lower() != "unknown":
        return str(crs.name)
    op = crs.coordinate_operation
    words = [op.method_name if op is not None else "unnamed CRS"]
    ellipsoid = crs.ellipsoid
    if ellipsoid is not None:
        if ellipsoid.name and ellipsoid.name.lower() != "unknown":
            words.append(f"on {ellipsoid.name}")
        elif ellipsoid.inverse_flattening == 0:
            words.append(f"on a sphere of radius {ellipsoid.semi_major_metre:.0f} m")
        else:
            words.append(f"on an ellipsoid of semi-major axis {ellipsoid.semi_major_metre:.0f} m")
    params = [p for p in (op.params if op is not None else []) if p.value]
    if params:
        words.append("(" + ", ".join(f"{p.name.lower()} {p.value:g}" for p in params) + ")")
    return " ".join(words)
