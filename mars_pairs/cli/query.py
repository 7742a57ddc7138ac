"""``mars-pairs query``: filter a manifest by place and print or save the rows."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import shapely

from mars_pairs.errors import DatasetError, MarsPairsError
from mars_pairs.geometry.body import MARS_LONLAT_AUTHORITY
from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.geoparquet import GEOMETRY_COLUMNS, table_geo_metadata
from mars_pairs.store.query import Manifest

#: Columns of WKB or struct values, left out of CSV and GeoJSON properties.
NOT_PLAIN = (*GEOMETRY_COLUMNS, "bbox")

SHOWN = (
    "key",
    "mission",
    "instrument",
    "sol",
    "site",
    "drive",
    "split",
    "latitude",
    "longitude",
    "azimuth_deg",
    "elevation_deg",
)


def filter_arguments(
    *,
    bbox: Sequence[float] | None = None,
    bbox_map: Sequence[float] | None = None,
    near: Sequence[float] | None = None,
    polygon: str | None = None,
    mission: str | Sequence[str] | None = None,
    instrument: str | Sequence[str] | None = None,
    split: str | Sequence[str] | None = None,
    sol: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Manifest.filter keyword arguments from the query's options (unset ones left out).

    ``bbox`` is (west, south, east, north) degrees, ``bbox_map`` (xmin, ymin, xmax, ymax) in
    the dataset CRS, ``near`` (lat, lon, radius_m), ``polygon`` WKT in the dataset CRS;
    ``mission``, ``instrument``, ``split``: a value or a list of values (any of them). Any
    subset may be given, none for every row.
    """
    out: dict[str, Any] = {}
    if bbox is not None:
        w, s, e, n = _finite("--bbox", bbox, 4)
        for name, lat in (("S", s), ("N", n)):
            if not -90.0 <= lat <= 90.0:
                raise MarsPairsError(f"--bbox: {name}: latitude {lat:g} is outside [-90, 90]")
        if s > n:
            raise MarsPairsError(f"--bbox: S ({s:g}) is north of N ({n:g})")
        out["bbox_lonlat"] = (w, s, e, n)
    if bbox_map is not None:
        x0, y0, x1, y1 = _finite("--bbox-map", bbox_map, 4)
        if x0 > x1 or y0 > y1:
            raise MarsPairsError("--bbox-map: expected XMIN <= XMAX and YMIN <= YMAX")
        out["bbox_map"] = (x0, y0, x1, y1)
    if near is not None:
        lat, lon, radius = _finite("--near", near, 3)
        if not -90.0 <= lat <= 90.0:
            raise MarsPairsError(f"--near: LAT: latitude {lat:g} is outside [-90, 90]")
        if not radius > 0.0:
            raise MarsPairsError(f"--near: RADIUS_M: expected a positive radius, got {radius:g}")
        out["near"] = (lat, lon, radius)
    if polygon is not None:
        out["polygon"] = _polygon(polygon)
    for name, value in (("mission", mission), ("instrument", instrument), ("split", split)):
        if value:
            out[name] = [value] if isinstance(value, str) else list(value)
    if sol:
        first, last = (int(v) for v in sol)
        if first > last:
            raise MarsPairsError(f"--sol: FIRST ({first}) is after LAST ({last})")
        out["sol"] = (first, last)
    return out


def check_query_splits(dataset: str | Path, split: Any) -> None:
    """ArgumentError when a requested split (a name or a list) is none the dataset knows:
    those its dataset.json configures (``filter_args.configured_splits``) or its rows hold.
    The known names are listed; a known split with no rows is not an error (0 rows)."""
    if not split:
        return
    import pyarrow.compute as pc

    from mars_pairs.store.dataset_info import read_dataset_doc
    from mars_pairs.store.filter_args import check_split_names, configured_splits

    root = Path(dataset)
    rows = Manifest.open(root).require(["split"]).to_table(["split"])["split"]
    known = {str(v) for v in pc.unique(rows).to_pylist() if v is not None}
    try:
        doc = read_dataset_doc(root)
    except DatasetError:
        doc = {}  # a damaged dataset.json: the names on the rows
    check_split_names(split, known | (configured_splits(doc) or set()), str(root))


def _finite(option: str, values: Sequence[float], n: int) -> tuple[float, ...]:
    """``n`` finite numbers, or MarsPairsError naming the option."""
    numbers = tuple(float(v) for v in values)
    if len(numbers) != n or not all(np.isfinite(numbers)):
        raise MarsPairsError(f"{option}: expected {n} finite numbers, got {list(values)}")
    return numbers


def _polygon(wkt: str) -> Any:
    """A non-empty polygon with finite coordinates from WKT (dataset CRS)."""
    try:
        geom = shapely.from_wkt(wkt)
    except shapely.errors.GEOSException as exc:
        raise MarsPairsError(f"--polygon: not valid WKT: {exc}") from None
    if geom is None or geom.is_empty:
        raise MarsPairsError(f"--polygon: an empty geometry ({wkt!r}) selects nothing")
    if geom.geom_type not in ("Polygon", "MultiPolygon"):
        raise MarsPairsError(f"--polygon: expected a Polygon or MultiPolygon, got {geom.geom_type}")
    if not np.isfinite(shapely.get_coordinates(geom)).all():
        raise MarsPairsError("--polygon: coordinates must be finite numbers")
    return geom


#: GeoJSON's CRS member for the Mars sphere, planetocentric, east longitude (R = 3396190 m).
GEOJSON_CRS = {"type": "name", "properties": {"name": MARS_LONLAT_AUTHORITY}}


def _geojson(table: pa.Table, crs: str | None) -> str:
    """A FeatureCollection in longitude/latitude degrees on the Mars sphere.

    GeoJSON coordinates are longitude, latitude (RFC 7946 fixes the Earth's WGS 84; for Mars
    the sphere is named in the legacy ``crs`` member, which GDAL and QGIS read). Footprints
    are transformed from the dataset CRS ``crs`` (map units); a row without one is its rover
    point.
    """
    features = []
    for row in table.to_pylist():
        wkb = row.get("footprint")
        props = {
            k: (v.isoformat() if hasattr(v, "isoformat") else v)
            for k, v in row.items()
            if not k.endswith(("_shard", "_offset", "_size", "_crc32c")) and k not in NOT_PLAIN
        }
        if wkb and crs is not None:
            geom = shapely.transform(shapely.from_wkb(wkb), lambda xy: _lonlat(xy, crs))
        else:
            geom = shapely.Point(row["longitude"], row["latitude"])
        features.append(
            {"type": "Feature", "geometry": shapely.geometry.mapping(geom), "properties": props}
        )
    return json.dumps({"type": "FeatureCollection", "crs": GEOJSON_CRS, "features": features})


def _lonlat(xy: np.ndarray, crs: str) -> np.ndarray:
    """(N, 2) map x, y in ``crs`` -> (N, 2) longitude, latitude degrees (Mars sphere)."""
    lon, lat = map_to_lonlat(xy[:, 0], xy[:, 1], crs)
    return np.column_stack([lon, lat])


def run_query(
    dataset: str | Path, filters: dict[str, Any], fmt: str = "table", out: str | None = None
) -> int:
    """Print (or write to ``out``) the rows matching ``filters``, as table/csv/parquet/geojson.

    Parquet is GeoParquet 1.1 (``store.geoparquet``: the manifest's geometry columns in the
    dataset CRS, named); GeoJSON is longitude/latitude on the Mars sphere (IAU_2015:49900)."""
    manifest = Manifest.open(dataset).require()
    table = manifest.filter(**filters).to_table()
    if fmt == "parquet":
        if not out:
            raise MarsPairsError("--format parquet needs --out FILE")
        crs = manifest.crs
        if crs is not None:
            table = table.replace_schema_metadata(table_geo_metadata(table, crs))
        write_parquet_atomic(table, Path(out))
        print(f"{out}: {table.num_rows} rows")
        return 0
    if fmt == "csv":
        text = _csv(table.drop_columns([c for c in NOT_PLAIN if c in table.column_names]))
    elif fmt == "geojson":
        text = _geojson(table, manifest.crs)
    else:
        text = _table(table)
    if out:
        with open(out, "w") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0


def _csv(table: pa.Table) -> str:
    import io

    buf = io.BytesIO()
    pacsv.write_csv(table, buf)
    return buf.getvalue().decode()


def _table(table: pa.Table) -> str:
    rows = table.select(list(SHOWN)).to_pylist()
    fmt = {k: ("{:.6f}" if k in ("latitude", "longitude") else "{}") for k in SHOWN}
    cells = [
        [
            fmt[k].format(r[k])
            if isinstance(r[k], float) and k in ("latitude", "longitude")
            else (f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]))
            for k in SHOWN
        ]
        for r in rows
    ]
    widths = [max([len(k)] + [len(c[i]) for c in cells]) for i, k in enumerate(SHOWN)]
    lines = ["  ".join(k.ljust(w) for k, w in zip(SHOWN, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(cell, widths, strict=True)) for cell in cells]
    lines.append(f"({len(rows)} rows)")
    return "\n".join(lines)


def footprint_query(
    folder: str | Path,
    saw: Sequence[float] | None,
    overlaps: str | None,
    fmt: str = "table",
    out: str | None = None,
) -> int:
    """``query --saw LON LAT`` / ``--overlaps KEY`` on a catalogue folder (catalog.parquet:
    ``store.catalog.Catalog``) or a dataset (``--saw``: ``Manifest.filter(saw=...)``)."""
    from mars_pairs.store.catalog import Catalog, checked_point

    root = Path(folder)
    if saw is not None:
        lon, lat = checked_point(saw, "--saw")
    if (root / "catalog.parquet").is_file():
        catalog = Catalog.open(root)
        table = catalog.saw(lon, lat) if saw is not None else catalog.overlaps(str(overlaps))
    elif saw is not None:
        table = Manifest.open(root).require().filter(saw=(lon, lat)).to_table(columns=list(SHOWN))
    else:
        raise MarsPairsError(f"--overlaps: {root} holds no catalog.parquet (a footprint catalogue)")
    if fmt == "parquet":
        if not out:
            raise MarsPairsError("--format parquet needs --out FILE")
        write_parquet_atomic(table, Path(out))
        print(f"{out}: {table.num_rows} rows")
        return 0
    text = _csv(table) if fmt == "csv" else _any_table(table)
    if out:
        Path(out).write_text(text)
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0


def _any_table(table: pa.Table) -> str:
    """Every column of ``table`` as aligned text (floats to 2 places, lon/lat to 6)."""
    names = table.column_names
    cells = [
        [
            f"{v:.6f}" if isinstance(v, float) and ("lon" in k or "lat" in k)
            else f"{v:.2f}" if isinstance(v, float) else str(v)
            for k, v in row.items()
        ]
        for row in table.to_pylist()
    ]  # fmt: skip
    widths = [max([len(k)] + [len(c[i]) for c in cells]) for i, k in enumerate(names)]
    lines = ["  ".join(k.ljust(w) for k, w in zip(names, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in cells]
    lines.append(f"({table.num_rows} rows)")
    return "\n".join(lines)
