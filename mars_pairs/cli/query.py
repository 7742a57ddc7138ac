"""``mars-pairs query``: filter a manifest (:class:`~mars_pairs.store.filter.ManifestFilter`)
and print or save the rows."""

from __future__ import annotations

import json
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mars_pairs.errors import ArgumentError, MarsPairsError, UsageError
from mars_pairs.geometry.body import MARS_LONLAT_AUTHORITY

# pyarrow, shapely and the manifest load when a query runs, not with every command's parser
if TYPE_CHECKING:
    import numpy as np
    import pyarrow as pa

    from mars_pairs.store.query import Manifest


def _not_plain() -> tuple[str, ...]:
    """Columns of WKB or struct values, left out of CSV and GeoJSON properties."""
    from mars_pairs.store.geoparquet import GEOMETRY_COLUMNS

    return (*GEOMETRY_COLUMNS, "bbox")


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


#: each filter argument's option (ArgumentErrors name the argument first)
OPTIONS = {
    "bbox_lonlat": "--bbox",
    "bbox_map": "--bbox-map",
    "near": "--near",
    "polygon_lonlat": "--polygon",
    "polygon_map": "--polygon-map",
    "mission": "--mission",
    "instrument": "--instrument",
    "split": "--split",
    "sol": "--sol",
    "by": "--by",
}

DESCRIPTION = (
    "Rows of a dataset's manifest matching every filter given: at most one place filter "
    "(--bbox, --bbox-map, --near, --polygon, --polygon-map) and any of --split, --mission, "
    "--instrument, --sol. No filter: every row. Coordinates are longitude first (lon/lat in "
    "degrees east/north on the Mars sphere; map units are the dataset CRS's metres). A place "
    "filter tests the rover position (where the image was taken) unless --by footprint (the "
    "viewshed footprint meets the place) or --by chip (the orbital chip meets it). A value "
    "the dataset does not hold is an error listing its values; a place that misses the "
    "dataset prints a warning with its extent in both units."
)


def register(sub: Any) -> None:
    """Add the ``query`` sub-command to ``sub`` (an argparse sub-parsers action)."""
    from mars_pairs.cli.arguments import finite
    from mars_pairs.store.filter_args import BY

    p = sub.add_parser(
        "query", help="filter a dataset's manifest by place and attributes", description=DESCRIPTION
    )
    p.add_argument(
        "dataset",
        help="dataset folder, or footprint catalogue (a folder or a URL: s3://bucket/prefix)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--bbox",
        nargs=4,
        type=finite,
        metavar=("W", "S", "E", "N"),
        help="longitude/latitude box, degrees east/north (W > E crosses the 180th meridian); "
        "on a catalogue: the images whose visible footprint polygon meets the box",
    )
    where.add_argument(
        "--bbox-map",
        nargs=4,
        type=finite,
        metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
        help="box in the dataset CRS, map units (metres)",
    )
    where.add_argument(
        "--near",
        nargs=3,
        type=finite,
        metavar=("LON", "LAT", "RADIUS_M"),
        help="within a great-circle radius (metres) of a point, longitude first (LAT LON, the "
        "old order, is read swapped with a warning when only that way the point is in the "
        "dataset)",
    )
    where.add_argument("--polygon", metavar="WKT", help="WKT polygon in lon/lat degrees")
    where.add_argument("--polygon-map", metavar="WKT", help="WKT polygon in the dataset CRS")
    where.add_argument(
        "--saw",
        nargs=2,
        type=finite,
        metavar=("LON", "LAT"),
        help="the images whose footprint holds the point, longitude first (a catalogue: its "
        "visible footprint, nearest first, with the range; a dataset: the manifest's footprint)",
    )
    p.add_argument(
        "--per-cell",
        action="store_true",
        help="with --saw on a catalogue: the images whose view holds the DEM cell the point lies "
        "in (the cell's verdict `viewshed --label` writes) instead of the footprint polygon",
    )
    where.add_argument(
        "--overlaps",
        metavar="KEY",
        help="the images that saw the same ground as KEY (a catalogue's pairs.parquet), by IoU",
    )
    p.add_argument(
        "--by",
        choices=BY,
        default=BY[0],
        help="what a place filter tests: rover = the rover position (default), footprint = "
        "the viewshed footprint polygon meets the place, chip = the orbital chip's square "
        "meets it",
    )
    p.add_argument("--mission", action="append", help="e.g. m2020 or msl (repeat for several)")
    p.add_argument(
        "--instrument",
        action="append",
        help="e.g. MCZ_LEFT, NAVCAM_LEFT (m2020), MAST_LEFT (msl) (repeat for several)",
    )
    p.add_argument(
        "--split", action="append", help="train, val, test, buffer... (repeat for several)"
    )
    p.add_argument("--sol", nargs=2, type=int, metavar=("FIRST", "LAST"), help="inclusive")
    p.add_argument("--format", choices=("table", "csv", "parquet", "geojson"), default="table")
    p.add_argument("--out", help="output file (parquet needs one; others default to stdout)")
    p.set_defaults(func=run)


def run(args: Any) -> int:
    """``mars-pairs query``: the rows matching the options, printed or written."""
    from mars_pairs.store import fs
    from mars_pairs.store.catalog import is_catalog

    footprint = args.bbox is not None or args.saw is not None or args.overlaps is not None
    url = fs.is_url(args.dataset)
    catalogue = (not url or footprint) and is_catalog(fs.dataset_root(args.dataset))
    if url and not catalogue:
        import argparse

        from mars_pairs.cli.arguments import local_dataset

        try:
            local_dataset(args.dataset)
        except argparse.ArgumentTypeError as exc:
            raise UsageError(
                f"{exc}; a footprint catalogue on object storage is queried with --bbox, "
                "--saw or --overlaps"
            ) from None
    named = [o for o in ("mission", "instrument", "split", "sol") if getattr(args, o)]
    if catalogue and named:
        raise MarsPairsError(
            f"--{named[0]}: {args.dataset} is a footprint catalogue, queried by --bbox, --saw "
            "or --overlaps only"
        )
    if args.saw is not None or args.overlaps is not None or (catalogue and args.bbox):
        return footprint_query(
            args.dataset, args.saw, args.overlaps, args.format, args.out, args.per_cell, args.bbox
        )
    if catalogue:
        raise MarsPairsError(
            f"{args.dataset}: a footprint catalogue: query it with --bbox, --saw or --overlaps"
        )
    if args.per_cell:
        raise MarsPairsError("--per-cell: only with --saw")
    filters = filter_arguments(
        bbox=args.bbox,
        bbox_map=args.bbox_map,
        near=args.near,
        polygon=args.polygon,
        polygon_map=args.polygon_map,
        mission=args.mission,
        instrument=args.instrument,
        split=args.split,
        sol=args.sol,
        by=args.by,
    )
    return run_query(args.dataset, filters, args.format, args.out)


def filter_arguments(
    *,
    bbox: Sequence[float] | None = None,
    bbox_map: Sequence[float] | None = None,
    near: Sequence[float] | None = None,
    polygon: str | None = None,
    polygon_map: str | None = None,
    mission: str | Sequence[str] | None = None,
    instrument: str | Sequence[str] | None = None,
    split: str | Sequence[str] | None = None,
    sol: Sequence[int] | None = None,
    by: str = "rover",
) -> dict[str, Any]:
    """Manifest.filter keyword arguments (:class:`~mars_pairs.store.filter.ManifestFilter`'s)
    from the query's options (unset ones left out): ``bbox`` (W, S, E, N) degrees,
    ``bbox_map`` (xmin, ymin, xmax, ymax) map units, ``near`` (lon, lat, radius_m),
    ``polygon`` lon/lat WKT, ``polygon_map`` WKT in the dataset CRS; the names a value or a
    list; ``by`` what a place filter tests. Checked when the manifest filters them."""
    given = {
        "bbox_lonlat": bbox,
        "bbox_map": bbox_map,
        "near": near,
        "polygon_lonlat": polygon,
        "polygon_map": polygon_map,
        "mission": mission or None,
        "instrument": instrument or None,
        "split": split or None,
        "sol": sol or None,
    }
    from mars_pairs.store.filter import PLACE_KEYS

    out = {k: (tuple(v) if isinstance(v, list) else v) for k, v in given.items() if v is not None}
    if any(k in out for k in OPTIONS if k in PLACE_KEYS) or by != "rover":
        out["by"] = by
    return out


def filtered(dataset: str | Path, filters: dict[str, Any]) -> Manifest:
    """The dataset's manifest filtered by ``filters``; an ArgumentError names the option
    (``--bbox``, ...), a FilterWarning is printed as ``warning: ...`` on stderr."""
    from mars_pairs.store.filter import FilterWarning
    from mars_pairs.store.query import Manifest

    manifest = Manifest.open(dataset).require()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FilterWarning)
        try:
            result = manifest.filter(**filters)
        except ArgumentError as exc:
            raise ArgumentError(_optioned(str(exc))) from None
    for warning in caught:
        if issubclass(warning.category, FilterWarning):
            print(f"mars-pairs query: warning: {_optioned(str(warning.message))}", file=sys.stderr)
        else:
            warnings.warn_explicit(
                warning.message, warning.category, warning.filename, warning.lineno
            )
    return result


def _optioned(message: str) -> str:
    """``message`` with its leading filter argument name as the command's option."""
    name, sep, rest = message.partition(":")
    return f"{OPTIONS[name]}{sep}{rest}" if name in OPTIONS and sep else message


#: GeoJSON's CRS member for the Mars sphere, planetocentric, east longitude (R = 3396190 m).
GEOJSON_CRS = {"type": "name", "properties": {"name": MARS_LONLAT_AUTHORITY}}


def _geojson(table: pa.Table, crs: str | None) -> str:
    """A FeatureCollection in longitude/latitude degrees on the Mars sphere.

    GeoJSON coordinates are longitude, latitude (RFC 7946 fixes the Earth's WGS 84; for Mars
    the sphere is named in the legacy ``crs`` member, which GDAL and QGIS read). Footprints
    are transformed from the dataset CRS ``crs`` (map units); a row without one is its rover
    point.
    """
    import shapely

    not_plain = _not_plain()
    features = []
    for row in table.to_pylist():
        wkb = row.get("footprint")
        props = {
            k: (v.isoformat() if hasattr(v, "isoformat") else v)
            for k, v in row.items()
            if not k.endswith(("_shard", "_offset", "_size", "_crc32c")) and k not in not_plain
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
    import numpy as np

    from mars_pairs.geometry.frames import map_to_lonlat

    lon, lat = map_to_lonlat(xy[:, 0], xy[:, 1], crs)
    return np.column_stack([lon, lat])


def run_query(
    dataset: str | Path, filters: dict[str, Any], fmt: str = "table", out: str | None = None
) -> int:
    """Print (or write to ``out``) the rows matching ``filters``, as table/csv/parquet/geojson.

    Parquet is GeoParquet 1.1 (``store.geoparquet``: the manifest's geometry columns in the
    dataset CRS, named); GeoJSON is longitude/latitude on the Mars sphere (IAU_2015:49900)."""
    from mars_pairs.store.atomic import write_parquet_atomic
    from mars_pairs.store.geoparquet import table_geo_metadata
    from mars_pairs.store.query import Manifest

    manifest = Manifest.open(dataset).require()
    table = filtered(dataset, filters).to_table()
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
        text = _csv(table.drop_columns([c for c in _not_plain() if c in table.column_names]))
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

    import pyarrow.csv as pacsv

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
    per_cell: bool = False,
    bbox: Sequence[float] | None = None,
) -> int:
    """``query --saw LON LAT`` / ``--overlaps KEY`` / ``--bbox W S E N`` on a catalogue folder
    (catalog.parquet: ``store.catalog.Catalog``; ``--bbox``: ``Catalog.bbox``, the visible
    footprint meets the box) or a dataset (``--saw``: ``Manifest.filter(saw=...)``);
    ``per_cell``: ``Catalog.saw(..., per_cell=True)`` (a catalogue and ``--saw`` only)."""
    from mars_pairs.store import fs
    from mars_pairs.store.atomic import write_parquet_atomic
    from mars_pairs.store.catalog import Catalog, checked_point, is_catalog
    from mars_pairs.store.query import Manifest

    root = fs.dataset_root(folder)
    if saw is not None:
        lon, lat = checked_point(saw, "--saw")
    if is_catalog(root):
        catalog = Catalog.open(root)
        if saw is not None:
            table = catalog.saw(lon, lat, per_cell=per_cell)
        elif per_cell:
            raise MarsPairsError("--per-cell: only with --saw")
        elif bbox is not None:
            try:
                table = catalog.bbox(*bbox)
            except ArgumentError as exc:
                raise ArgumentError(f"--{exc}") from None
        else:
            table = catalog.overlaps(str(overlaps))
    elif per_cell:
        raise MarsPairsError(f"--per-cell: {root} holds no catalog.parquet (a footprint catalogue)")
    elif saw is not None:
        table = Manifest.open(root).filter(saw=(lon, lat)).to_table(columns=list(SHOWN))
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
