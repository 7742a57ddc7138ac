"""The footprint catalogue as a STAC Collection (STAC 1.1.0): ``collection.json``, one Item per
image in ``items.ndjson`` (one GeoJSON Feature a line) and in ``items.parquet``
(stac-geoparquet, GeoParquet 1.1 with the collection in its metadata).

Each Item:

- ``geometry``: the visible footprint in longitude/latitude, degrees east (planetocentric,
  east-positive, in the CRS's range) and north, on the Mars sphere R = 3396190 m (IAU 2015
  49900: on a sphere planetocentric and planetographic latitude agree), turned from the
  catalogue's map CRS by pyproj vertex by vertex (``geometry.frames.map_to_lonlat``);
  ``bbox`` its bounds. An image whose footprint is empty (no ground in view) has the camera
  centre as a Point.
- ``proj`` extension (v2.0.0): ``proj:code`` null (Mars has no EPSG code), the map CRS as
  ``proj:wkt2`` and ``proj:projjson`` (named as the catalogue's GeoParquet names it),
  ``proj:bbox`` and ``proj:geometry`` the footprint in map units.
- ``ssys`` extension (v1.1.0): ``ssys:targets: ["Mars"]``, ``ssys:target_class: "planet"``,
  ``ssys:local_time`` "Sol-NNNNNMHH:MM:SS[.fff]" (the local mean solar time) where the label
  gives one.
- ``datetime``: the label's start time, UTC; an image whose label gives no time is left out
  of the STAC files (counted in the collection's ``mars_pairs:without_time``).
- ``platform``/``instruments``, and the catalogue's columns under ``mars_pairs:`` (sol, rover
  position, pointing, ranges, visible area).
- assets ``label`` and ``image`` (and ``browse``, a .jpg/.png beside the label, where one
  exists when the catalogue is written), hrefs relative to the catalogue folder.
- links: ``via`` the PDS product (its label), and ``collection``/``parent``/``root``.

The Item order is the catalogue's row order; nothing depends on time or machine, so the same
catalogue gives the same bytes.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import shapely

from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.pds.common import browse_beside
from mars_pairs.store.atomic import atomic_path, atomic_write_bytes
from mars_pairs.store.geoparquet import named_crs

STAC_VERSION = "1.1.0"
PROJ_EXTENSION = "https://stac-extensions.github.io/projection/v2.0.0/schema.json"
SSYS_EXTENSION = "https://stac-extensions.github.io/ssys/v1.1.0/schema.json"
EXTENSIONS = [PROJ_EXTENSION, SSYS_EXTENSION]
#: the STAC files of a catalogue folder
STAC_FILES = ("collection.json", "items.ndjson", "items.parquet")
COLLECTION_ID = "mars-pairs-footprints"
_PLATFORM = {"msl": "curiosity", "m2020": "perseverance"}
_MEDIA = {
    ".lbl": "text/plain",
    ".xml": "application/xml",
    ".img": "application/octet-stream",
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".tif": "image/tiff",
    ".tiff": "image/tiff",
}
#: catalogue columns copied into each Item's properties as ``mars_pairs:<name>``
_COPIED = (
    "key", "sol", "site", "drive", "pose", "camera_lon", "camera_lat", "camera_z",
    "azimuth_deg", "elevation_deg", "hfov_deg", "vfov_deg", "width", "height", "camera_model",
    "localization", "radius_m", "visible_area_m2", "median_range_m", "max_range_m",
    "footprint_parts",
)  # fmt: skip


def _lonlat(geom: shapely.Geometry, crs: str) -> shapely.Geometry:
    """``geom`` (map CRS ``crs``, map units) with every vertex in lon/lat degrees, Mars
    sphere."""

    def move(xy: np.ndarray) -> np.ndarray:
        lon, lat = map_to_lonlat(xy[:, 0], xy[:, 1], crs)
        return np.column_stack([lon, lat])

    return shapely.transform(geom, move)


def _geojson(geom: shapely.Geometry) -> dict[str, Any]:
    """``geom`` as a GeoJSON geometry object."""
    doc: dict[str, Any] = json.loads(shapely.to_geojson(geom))
    return doc


def _bounds(geom: shapely.Geometry) -> list[float]:
    return [float(v) for v in shapely.bounds(geom)]


def _clean(value: Any) -> Any:
    """JSON-safe: NaN and infinities as None, numpy scalars as Python."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _asset(href_of: Path, folder: Path | None, roles: list[str], title: str) -> dict[str, Any]:
    """An asset of the file ``href_of``: its href relative to ``folder`` (None: absolute)."""
    href = (
        href_of.as_posix() if folder is None else Path(os.path.relpath(href_of, folder)).as_posix()
    )
    asset: dict[str, Any] = {"href": href, "title": title, "roles": roles}
    media = _MEDIA.get(href_of.suffix.lower())
    if media is not None:
        asset["type"] = media
    return asset


def stac_items(
    catalog: pa.Table, crs: str, folder: Path | None, labels_root: Path
) -> Iterator[dict[str, Any]]:
    """The Items of ``catalog`` (catalog.parquet's rows, map CRS ``crs``) in row order;
    assets' hrefs relative to ``folder`` (None: absolute paths), the catalogue's
    ``label_path``/``image_path`` relative to ``labels_root``. Rows without a time are
    skipped."""
    projjson = named_crs(crs)
    from pyproj import CRS

    wkt2 = CRS.from_json_dict(projjson).to_wkt("WKT2_2019")
    rows = catalog.to_pylist()
    footprints = shapely.from_wkb([r["footprint"] for r in rows])
    cameras = shapely.from_wkb([r["camera_point"] for r in rows])
    for row, foot, camera in zip(rows, footprints, cameras, strict=True):
        if row["time"] is None:
            continue
        map_geom = camera if foot is None or shapely.is_empty(foot) else foot
        geom = _lonlat(map_geom, crs)
        props: dict[str, Any] = {
            "datetime": row["time"].strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z",
            "platform": _PLATFORM.get(row["mission"], row["mission"]),
            "instruments": [row["instrument"].lower()],
            "mission": row["mission"],
            "proj:code": None,
            "proj:wkt2": wkt2,
            "proj:projjson": projjson,
            "proj:bbox": _bounds(map_geom),
            "proj:geometry": _geojson(map_geom),
            "ssys:targets": ["Mars"],
            "ssys:target_class": "planet",
        }
        if row["lmst"] is not None:
            props["ssys:local_time"] = f"Sol-{row['sol']:05d}M{row['lmst']}"
        props.update({f"mars_pairs:{name}": _clean(row[name]) for name in _COPIED})
        label = labels_root / row["label_path"]
        assets = {"label": _asset(label, folder, ["metadata"], "PDS label")}
        if row["image_path"] is not None:
            image = labels_root / row["image_path"]
            assets["image"] = _asset(image, folder, ["data"], "image")
        browse = browse_beside(label)
        if browse is not None and (row["image_path"] is None or browse != image):
            assets["browse"] = _asset(browse, folder, ["overview"], "browse image")
        yield {
            "type": "Feature",
            "stac_version": STAC_VERSION,
            "stac_extensions": EXTENSIONS,
            "id": row["key"],
            "geometry": _geojson(geom),
            "bbox": _bounds(geom),
            "properties": props,
            "assets": assets,
            "links": [
                {"rel": "via", "href": assets["label"]["href"], "title":
                 f"PDS product {row['product_id']}", **({"type": assets["label"]["type"]}
                 if "type" in assets["label"] else {})},
                {"rel": "collection", "href": "./collection.json", "type": "application/json"},
                {"rel": "parent", "href": "./collection.json", "type": "application/json"},
                {"rel": "root", "href": "./collection.json", "type": "application/json"},
            ],
            "collection": COLLECTION_ID,
        }  # fmt: skip


def stac_collection(
    items: list[dict[str, Any]], doc: dict[str, Any], skipped: int
) -> dict[str, Any]:
    """The Collection of ``items``: extent (lon/lat degrees on the Mars sphere, UTC), the
    license of catalog.json's ``doc``, summaries, the item files as assets."""
    if items:
        boxes = np.array([it["bbox"] for it in items])
        bbox = [*boxes[:, :2].min(axis=0).tolist(), *boxes[:, 2:].max(axis=0).tolist()]
        times = sorted(it["properties"]["datetime"] for it in items)
        interval = [times[0], times[-1]]
    else:
        bbox, interval = [-180.0, -90.0, 180.0, 90.0], [None, None]
    license_ = doc.get("license", "other")
    spdx = license_ if " " not in license_ and license_ else "other"
    sols = [it["properties"]["mars_pairs:sol"] for it in items]
    return {
        "type": "Collection",
        "stac_version": STAC_VERSION,
        "stac_extensions": EXTENSIONS,
        "id": COLLECTION_ID,
        "title": "Mars rover images by the ground they saw",
        "description": (
            "One Item per rover mast-camera image: its visible footprint on the Mars sphere "
            "(longitude/latitude degrees, R = 3396190 m), the map CRS of the catalogue in "
            "proj:wkt2/proj:projjson, the label, image and browse as assets. Made by "
            f"mars-pairs {doc.get('versions', {}).get('mars_pairs', '')}; license: {license_}."
        ),
        "license": spdx,
        "extent": {"spatial": {"bbox": [bbox]}, "temporal": {"interval": [interval]}},
        "summaries": {
            "platform": sorted({it["properties"]["platform"] for it in items}),
            "instruments": sorted({i for it in items for i in it["properties"]["instruments"]}),
            "mars_pairs:sol": {"minimum": min(sols), "maximum": max(sols)} if sols else [],
            "ssys:targets": ["Mars"],
        },
        "mars_pairs:without_time": skipped,
        "assets": {
            "items-ndjson": {
                "href": "./items.ndjson",
                "type": "application/x-ndjson",
                "roles": ["data"],
                "title": "the Items, one a line",
            },
            "items-parquet": {
                "href": "./items.parquet",
                "type": "application/vnd.apache.parquet",
                "roles": ["data"],
                "title": "the Items, stac-geoparquet",
            },
        },
        "links": [
            {"rel": "self", "href": "./collection.json", "type": "application/json"},
            {"rel": "root", "href": "./collection.json", "type": "application/json"},
        ],
    }


def write_stac(
    folder: Path,
    catalog: pa.Table,
    crs: str,
    doc: dict[str, Any],
    labels_root: Path,
    *,
    relative: bool = True,
) -> int:
    """Write ``STAC_FILES`` of ``catalog`` into ``folder``, each atomically; returns the
    number of Items. ``relative``: assets' hrefs relative to ``folder``; else absolute (a
    catalogue published to object storage, from which no relative path leads to the labels).
    ``doc``: catalog.json's document (license, versions). ``items.parquet`` needs
    stac-geoparquet (the ``stac`` extra, ``pip install 'mars-pairs[stac]'``): without
    it that file is not written (and an old one removed), and ``doc["stac_parquet"]`` says
    why; the JSON files need nothing more."""
    items = list(stac_items(catalog, crs, folder if relative else None, labels_root))
    collection = stac_collection(items, doc, catalog.num_rows - len(items))
    lines = "".join(json.dumps(item, separators=(",", ":")) + "\n" for item in items)
    atomic_write_bytes(folder / "items.ndjson", lines.encode())
    if importlib.util.find_spec("stac_geoparquet") is None:
        (folder / "items.parquet").unlink(missing_ok=True)
        doc["stac_parquet"] = "not written: stac-geoparquet is not installed (mars-pairs[stac])"
    else:
        _write_items_parquet(folder / "items.parquet", items, collection)
    atomic_write_bytes(folder / "collection.json", json.dumps(collection, indent=2).encode())
    return len(items)


def _write_items_parquet(
    path: Path, items: list[dict[str, Any]], collection: dict[str, Any]
) -> None:
    """stac-geoparquet's ``items.parquet`` of ``items``, atomically."""
    import stac_geoparquet.arrow

    with atomic_path(path) as tmp:
        if items:
            reader = stac_geoparquet.arrow.parse_stac_items_to_arrow([_frozen(i) for i in items])
            stac_geoparquet.arrow.to_parquet(
                reader, tmp, collections={COLLECTION_ID: collection}, compression="zstd"
            )
        else:
            pa.parquet.write_table(pa.table({"id": pa.array([], pa.string())}), tmp)


class _Geometry:
    """A GeoJSON geometry handed to stac-geoparquet as it is: ``copy.deepcopy`` returns it and
    its ``__geo_interface__`` holds the rings as arrays. stac-geoparquet deep-copies every
    Item before turning its geometries into WKB through shapely: on the demo catalogue's
    270 Items (~1,100 vertices a footprint) that copy and the per-vertex rebuild were 13.4 s
    of the 20 s STAC writing (load 19); with this, a copy is free and shapely builds each
    ring from its array."""

    def __init__(self, doc: dict[str, Any]) -> None:
        coords: Any = doc["coordinates"]
        if doc["type"] == "Polygon":
            coords = [np.asarray(ring, dtype=np.float64) for ring in coords]
        elif doc["type"] == "MultiPolygon":
            coords = [[np.asarray(ring, dtype=np.float64) for ring in poly] for poly in coords]
        self.__geo_interface__ = {"type": doc["type"], "coordinates": coords}

    def __deepcopy__(self, memo: dict[int, Any]) -> _Geometry:
        return self


def _frozen(item: dict[str, Any]) -> dict[str, Any]:
    """``item`` (not changed) with its geometry and ``proj:geometry`` as ``_Geometry``."""
    props = dict(item["properties"])
    if "proj:geometry" in props:
        props["proj:geometry"] = _Geometry(props["proj:geometry"])
    return {**item, "geometry": _Geometry(item["geometry"]), "properties": props}
