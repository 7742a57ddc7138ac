"""Reading a footprint catalogue folder (``Catalog.open``): which images saw a point
(``saw``: exact polygon containment, or with ``per_cell`` the verdict each image's view gives
the DEM cell holding the point, with the range at which each saw it), which images saw
ground in a longitude/latitude box (``bbox``: the visible footprint polygon meets the box) and
which images saw the same ground as one image (``overlaps``, ranked by IoU).

Points and boxes are longitude first: (lon, lat) planetocentric degrees east/north on the
Mars sphere, turned into the catalogue's map CRS (named in its GeoParquet metadata) for the
test; a point on a footprint's edge counts as inside. A box (W, S, E, N) is the lon/lat box
of ``ManifestFilter.bbox_lonlat`` (W > E crosses the 180th meridian), its edges densified and
projected (``store.filter.map_shapes``); a footprint touching it counts. Ranges are
horizontal true metres on the Mars sphere from the camera centre (great circle at the
camera's height).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import shapely

from mars_pairs.errors import ArgumentError, DatasetError
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.geometry.frames import lonlat_to_map
from mars_pairs.store import fs
from mars_pairs.store.cellmask import cells_at
from mars_pairs.store.pairs import great_circle_m

SAW_COLUMNS = ("key", "product_id", "mission", "instrument", "sol", "camera_lon", "camera_lat")


def checked_point(point: Sequence[Any], what: str = "point") -> tuple[float, float]:
    """(lon, lat) as floats; ArgumentError in one line naming ``what`` for anything but two
    finite numbers with latitude in [-90, 90] and longitude in [-180, 360]."""
    try:
        values = [float(v) for v in point]
    except (TypeError, ValueError):
        raise ArgumentError(f"{what}: expected LON LAT numbers, got {point!r}") from None
    if len(values) != 2:
        raise ArgumentError(f"{what}: expected 2 numbers LON LAT, got {len(values)}")
    lon, lat = values
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise ArgumentError(f"{what}: LON LAT must be finite, got {lon} {lat}")
    if not -90.0 <= lat <= 90.0:
        raise ArgumentError(f"{what}: latitude {lat} outside [-90, 90] (give LON LAT)")
    if not -180.0 <= lon <= 360.0:
        raise ArgumentError(f"{what}: longitude {lon} outside [-180, 360]")
    return lon, lat


def geo_crs(schema: pa.Schema, path: fs.Location) -> Any:
    """The primary geometry column's CRS (PROJJSON) of a GeoParquet file's ``schema``."""
    meta = (schema.metadata or {}).get(b"geo")
    if meta is None:
        raise DatasetError(path, None, "no GeoParquet 'geo' metadata")
    doc = json.loads(meta)
    return doc["columns"][doc["primary_column"]]["crs"]


def points_in(geometry: np.ndarray, x: float, y: float, edge: bool = True) -> np.ndarray:
    """Indices of the (multi)polygons of ``geometry`` that hold map point (x, y) (inside, or
    on the boundary when ``edge``), through an STRtree."""
    valid = np.flatnonzero(~shapely.is_missing(geometry))
    tree = shapely.STRtree(geometry[valid])
    hits = tree.query(shapely.Point(x, y), predicate="intersects" if edge else "within")
    return np.sort(valid[hits])


class Catalog:
    """A footprint catalogue folder (``mars-pairs catalog``): ``table`` its catalog.parquet,
    ``crs`` the map CRS (PROJJSON), ``folder`` where it is (a local folder, or an fsspec URL:
    ``s3://bucket/prefix``)."""

    def __init__(self, folder: fs.Location, table: pa.Table, crs: Any) -> None:
        self.folder = folder
        self.table = table
        self.crs = crs
        self._geometry: np.ndarray | None = None

    @classmethod
    def open(cls, folder: str | Path) -> Catalog:
        """The catalogue in ``folder`` (a local folder or an fsspec URL, whose catalogue is
        read only once its catalog.json, published last, is there); DatasetError naming the
        file when it is not one."""
        root = fs.dataset_root(folder)
        if not is_catalog(root):
            raise DatasetError(root, None, "no catalog.parquet (not a footprint catalogue folder)")
        path = fs.join(root, "catalog.parquet")
        if fs.is_url(root) and not fs.is_file(fs.join(root, "catalog.json")):
            raise DatasetError(
                root, None, "no catalog.json (a catalogue being published, or not one)"
            )
        table = fs.read_parquet(path)
        return cls(root, table, geo_crs(table.schema, path))

    def __len__(self) -> int:
        return int(self.table.num_rows)

    @property
    def geometry(self) -> np.ndarray:
        """The footprints as shapely geometries (None: no visible ground), map CRS."""
        if self._geometry is None:
            self._geometry = shapely.from_wkb(
                self.table["footprint"].to_numpy(zero_copy_only=False)
            )
        return self._geometry

    def saw(self, lon: float, lat: float, per_cell: bool = False) -> pa.Table:
        """The images whose visible footprint holds the point (``lon``, ``lat``: degrees
        east/north, Mars sphere), nearest first: ``SAW_COLUMNS`` and ``range_m`` (horizontal
        true metres from the camera centre). ``per_cell``: the images whose view holds the
        DEM cell the point lies in (``view_cells``: each cell's verdict is its centre's, as
        ``viewshed --label`` writes it) instead of the footprint polygon. ArgumentError for
        a malformed point, or ``per_cell`` on a catalogue without ``view_cells``."""
        lon, lat = checked_point((lon, lat), "saw")
        x, y = lonlat_to_map([lon], [lat], json.dumps(self.crs))
        px, py = float(x[0]), float(y[0])
        if per_cell:
            if "view_cells" not in self.table.column_names:
                raise ArgumentError(
                    f"per-cell: {fs.join(self.folder, 'catalog.parquet')} has no view_cells column "
                    "(made by an older mars-pairs: rerun mars-pairs catalog)"
                )
            rows = cells_at(self.table["view_cells"], px, py)
        else:
            rows = points_in(self.geometry, px, py)
        hits = self.table.take(pa.array(rows, type=pa.int64())).select(list(SAW_COLUMNS))
        cam_lon = hits["camera_lon"].to_numpy(zero_copy_only=False)
        cam_lat = hits["camera_lat"].to_numpy(zero_copy_only=False)
        z = self.table["camera_z"].to_numpy(zero_copy_only=False)[rows]
        ranges = great_circle_m(
            cam_lon,
            cam_lat,
            np.full_like(cam_lon, lon),
            np.full_like(cam_lat, lat),
            MARS_RADIUS_M + z,
        )
        hits = hits.append_column("range_m", pa.array(ranges, type=pa.float64()))
        return hits.sort_by([("range_m", "ascending"), ("key", "ascending")])

    def bbox(self, west: float, south: float, east: float, north: float) -> pa.Table:
        """The images whose visible footprint polygon meets the box (``west``, ``south``,
        ``east``, ``north``: degrees east/north, Mars sphere; longitude first), in the
        catalogue's order: ``SAW_COLUMNS`` and ``visible_area_m2``. ArgumentError in one line
        for a malformed box (not 4 finite numbers, a latitude outside [-90, 90], S north of
        N)."""
        from mars_pairs.store.filter import ManifestFilter, map_shapes

        try:
            spec = ManifestFilter(bbox_lonlat=(west, south, east, north), by="footprint")
        except ArgumentError as exc:
            raise ArgumentError(str(exc).replace("bbox_lonlat:", "bbox:", 1)) from None
        (shape,) = map_shapes(spec, json.dumps(self.crs))
        geometry = self.geometry
        valid = np.flatnonzero(~shapely.is_missing(geometry))
        hits = shapely.STRtree(geometry[valid]).query(shape, predicate="intersects")
        rows = np.sort(valid[hits])
        columns = [*SAW_COLUMNS, "visible_area_m2"]
        return self.table.take(pa.array(rows, type=pa.int64())).select(columns)

    def overlaps(self, key: str) -> pa.Table:
        """The images that saw the same ground as image ``key`` (pairs.parquet), highest IoU
        first: ``key``, ``iou``, ``intersection_m2``, ``distance_m``, ``heading_diff_deg``,
        ``same_position``. ArgumentError for a key the catalogue does not hold."""
        if not pc.any(pc.equal(self.table["key"], key)).as_py():
            where = fs.join(self.folder, "catalog.parquet")
            raise ArgumentError(f"overlaps: no image {key!r} in {where}")
        path = fs.join(self.folder, "pairs.parquet")
        if not fs.is_file(path):
            raise DatasetError(self.folder, None, "no pairs.parquet (made without pairs)")
        source, filesystem = fs.parquet_source(path)
        keyed = (pc.field("key_a") == key) | (pc.field("key_b") == key)
        pairs = pq.read_table(source, filesystem=filesystem, filters=keyed)
        other = pc.if_else(pc.equal(pairs["key_a"], key), pairs["key_b"], pairs["key_a"])
        keep = ["iou", "intersection_m2", "distance_m", "heading_diff_deg", "same_position"]
        out = pairs.select(keep).add_column(0, "key", other)
        return out.sort_by([("iou", "descending"), ("key", "ascending")])


def is_catalog(root: fs.Location) -> bool:
    """Whether ``root`` (a folder or an fsspec URL) holds a footprint catalogue's
    catalog.parquet."""
    return fs.is_file(fs.join(root, "catalog.parquet"))


def catalog_ortho(root: Path) -> Path | None:
    """The ortho of the catalogue's config (catalog.json ``config.inputs.ortho``, relative to
    the folder), or None."""
    try:
        doc = json.loads((root / "catalog.json").read_text())
    except (OSError, ValueError):
        return None
    value = doc.get("config", {}).get("inputs", {}).get("ortho")
    return root / value if isinstance(value, str) else None
