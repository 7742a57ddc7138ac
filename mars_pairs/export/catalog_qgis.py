"""``mars-pairs export-qgis CATALOG``: a GeoPackage of a footprint catalogue folder, in its map
CRS (map units): the layers ``footprints`` (the visible ground, multipolygons), ``camera_wedges``
(the frustum's wedge to the view's radius), ``camera_positions`` (the camera centres) and
``pairs`` (a line from camera A's centre to camera B's for every row of pairs.parquet, with its
IoU, overlap, distance and heading difference). Every image layer carries the catalogue's
columns but the geometries and ``bbox``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import shapely

from mars_pairs.errors import DatasetError, MarsPairsError
from mars_pairs.store.atomic import atomic_path
from mars_pairs.store.catalog_schema import CATALOG_GEOMETRY

_DROPPED = {*CATALOG_GEOMETRY, "bbox"}


def catalog_crs_wkt(table: pa.Table, path: Path) -> str:
    """The map CRS of catalog.parquet (its GeoParquet PROJJSON) as WKT."""
    from pyproj import CRS

    meta = (table.schema.metadata or {}).get(b"geo")
    if meta is None:
        raise DatasetError(path, None, "no GeoParquet 'geo' metadata")
    doc = json.loads(meta)
    return str(CRS.from_json_dict(doc["columns"][doc["primary_column"]]["crs"]).to_wkt())


def _multi(geoms: np.ndarray) -> np.ndarray:
    """Polygons as one-part multipolygons (the footprints layer holds one geometry type)."""
    single = shapely.get_type_id(geoms) == shapely.GeometryType.POLYGON
    out: np.ndarray = geoms.copy()
    out[single] = [shapely.MultiPolygon([g]) for g in geoms[single]]
    return out


def export_catalog_geopackage(root: str | Path, out: Path) -> Path:
    """Write the GeoPackage ``out`` of catalogue folder ``root`` (layers as the module says),
    atomically; returns ``out``."""
    from pyogrio.raw import write_arrow

    root = Path(root)
    path = root / "catalog.parquet"
    table = pq.read_table(path)
    if table.num_rows == 0:
        raise MarsPairsError(f"{root}: the catalogue has no images")
    crs = catalog_crs_wkt(table, path)
    attributes = table.select([n for n in table.column_names if n not in _DROPPED])
    foot = shapely.from_wkb(table["footprint"].to_numpy(zero_copy_only=False))
    seen = ~shapely.is_missing(foot)
    xy = np.column_stack([table["camera_x"].to_numpy(), table["camera_y"].to_numpy()])
    wedges = shapely.from_wkb(table["wedge"].to_numpy(zero_copy_only=False))
    layers = [
        ("footprints", attributes.filter(pa.array(seen)), _multi(foot[seen]), "MultiPolygon"),
        ("camera_wedges", attributes, wedges, "Polygon"),
        ("camera_positions", attributes, shapely.points(xy), "Point"),
    ]
    pairs_path = root / "pairs.parquet"
    if pairs_path.is_file():
        pairs = pq.read_table(pairs_path)
        row = {k: i for i, k in enumerate(table["key"].to_pylist())}
        a = xy[[row[k] for k in pairs["key_a"].to_pylist()]]
        b = xy[[row[k] for k in pairs["key_b"].to_pylist()]]
        lines = shapely.linestrings(np.stack([a, b], axis=1)) if pairs.num_rows else np.array([])
        layers.append(("pairs", pairs, lines, "LineString"))
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, suffix=".gpkg") as tmp:  # the GPKG driver goes by the extension
        tmp.unlink(missing_ok=True)
        for i, (name, attrs, geoms, kind) in enumerate(layers):
            wkb = pa.array(shapely.to_wkb(np.asarray(geoms, dtype=object)), pa.binary())
            write_arrow(
                attrs.append_column("geometry", wkb), tmp, layer=name, driver="GPKG",
                geometry_name="geometry", geometry_type=kind, crs=crs, append=i > 0,
            )  # fmt: skip
    return out
