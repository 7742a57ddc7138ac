"""The dataset manifest: one Parquet row per sample, GeoParquet 1.1 footprints, atomic writes."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mars_pairs.geometry.frames import MARS_RADIUS_M
from mars_pairs.store import fs
from mars_pairs.store.columns import (
    RENAMED,
    canonical_names,
    rename_to,
    stored_name,
    warn_renamed,
)
from mars_pairs.store.filter_args import geometry, integers, numbers, shapely_module, strings
from mars_pairs.store.geoparquet import BBOX_TYPE
from mars_pairs.store.members import DENSE_FIELDS, MEMBERS

_FIELDS: list[tuple[str, pa.DataType]] = [
    ("key", pa.string()),
    ("mission", pa.string()),
    ("instrument", pa.string()),
    ("product_id", pa.string()),
    ("label_path", pa.string()),
    ("sol", pa.int32()),
    ("site", pa.int32()),
    ("drive", pa.int32()),
    ("pose", pa.int32()),
    ("time", pa.timestamp("ms", tz="UTC")),
    ("latitude", pa.float64()),  # planetocentric degrees
    ("longitude", pa.float64()),  # degrees east
    ("easting", pa.float64()),  # dataset CRS, map units
    ("northing", pa.float64()),
    ("elevation_m", pa.float64()),  # metres above the areoid (was "elevation", see columns.py)
    ("azimuth_deg", pa.float64()),  # image centre ray, SITE_FRAME, clockwise from true north
    ("elevation_deg", pa.float64()),  # image centre ray, SITE_FRAME, up from the horizon
    ("label_azimuth_deg", pa.float64()),  # the label's derived pointing (null: none)
    ("label_elevation_deg", pa.float64()),
    ("hfov_deg", pa.float64()),
    ("vfov_deg", pa.float64()),
    ("width", pa.int32()),
    ("height", pa.int32()),
    ("localization", pa.string()),  # places | label
    ("places_pose", pa.int32()),  # the PLACES row's pose (-1: every pose; null: none)
    ("places_match", pa.string()),  # geometry.places MATCH_*: site-drive-pose, earlier-pose, ...
    ("dem_offset_m", pa.float64()),  # DEM at the rover origin - PLACES elevation (rover moved)
    ("viewshed_area_m2", pa.float64()),
    ("visible_cells", pa.int64()),
    ("max_visible_range_m", pa.float64()),
    ("ray_hit_fraction", pa.float64()),
    ("footprint", pa.binary()),  # WKB polygon, dataset CRS
    ("bbox", BBOX_TYPE),  # the footprint's bounds: GeoParquet 1.1 bbox covering column
    ("rover_point", pa.binary()),  # WKB point (easting, northing), dataset CRS
    ("chip_box", pa.binary()),  # WKB polygon of the chip's corners (rotated: heading-up)
    ("chip_xmin", pa.float64()),
    ("chip_ymin", pa.float64()),
    ("chip_xmax", pa.float64()),
    ("chip_ymax", pa.float64()),
    ("chip_rotation_deg", pa.float64()),  # 0 north-up; heading-up: the camera azimuth
    ("ortho_coverage", pa.float64()),  # fraction 0..1 of the ortho chip's pixels with data
    ("dem_coverage", pa.float64()),  # fraction 0..1 of the DEM chip's pixels with data
    ("split", pa.string()),
    ("hilbert", pa.int64()),
    ("ground_member", pa.string()),  # e.g. "ground.jpg"
]
for _m in MEMBERS:
    _FIELDS += [
        (f"{_m}_shard", pa.string()),
        (f"{_m}_offset", pa.int64()),
        (f"{_m}_size", pa.int64()),
        (f"{_m}_crc32c", pa.int64()),  # CRC-32C of the member's bytes (store.integrity.checksum)
    ]

MANIFEST_SCHEMA = pa.schema(_FIELDS)


def manifest_schema(fields: Sequence[str] = ()) -> pa.Schema:
    """The manifest schema of a build writing the optional member ``fields`` as well
    (``MANIFEST_SCHEMA`` itself when none)."""
    unknown = [f for f in fields if f not in DENSE_FIELDS]
    if unknown:
        raise ValueError(f"unknown optional member field(s) {unknown}")
    extra = [
        (f"{m}_{suffix}", kind)
        for m in fields
        for suffix, kind in (
            ("shard", pa.string()), ("offset", pa.int64()), ("size", pa.int64()),
            ("crc32c", pa.int64()),
        )
    ]  # fmt: skip
    return pa.schema(_FIELDS + extra) if extra else MANIFEST_SCHEMA


#: Columns added after the first datasets: absent from older manifests, so not required.
COVERAGE_COLUMNS = ("ortho_coverage", "dem_coverage")
POINTING_PLACES_COLUMNS = (
    "label_azimuth_deg",
    "label_elevation_deg",
    "places_pose",
    "places_match",
)
GEOMETRY_VALUE_COLUMNS = ("rover_point", "chip_box")
OPTIONAL_COLUMNS = COVERAGE_COLUMNS + POINTING_PLACES_COLUMNS + GEOMETRY_VALUE_COLUMNS

#: The columns every reader may rely on (checksums and later columns are absent from older
#: datasets).
CORE_COLUMNS = tuple(
    f.name
    for f in MANIFEST_SCHEMA
    if not f.name.endswith("_crc32c") and f.name not in OPTIONAL_COLUMNS
)

#: The plain per-sample attributes that readers pass on (dataset meta, GeoPackage attributes).
SUMMARY_COLUMNS = (
    "key", "mission", "instrument", "product_id", "sol", "site", "drive", "split", "latitude",
    "longitude", "easting", "northing", "elevation_m", "azimuth_deg", "elevation_deg", "hfov_deg",
    "vfov_deg", "localization", "viewshed_area_m2", "visible_cells", "max_visible_range_m",
)  # fmt: skip

FAILURE_SCHEMA = pa.schema(
    [
        ("product_id", pa.string()),
        ("path", pa.string()),
        ("stage", pa.string()),
        ("error_type", pa.string()),
        ("message", pa.string()),
    ]
)


def write_parquet_atomic(table: pa.Table, path: Path, row_group_size: int = 4096) -> None:
    """Write a Parquet file through a temporary name and a rename."""
    os.replace(write_parquet_staged(table, path, row_group_size), path)


def write_parquet_staged(table: pa.Table, path: Path, row_group_size: int = 4096) -> Path:
    """Write the Parquet file of ``path`` under its temporary name (``.NAME.tmp-PID`` beside
    it, synced) and return that name: renaming it to ``path`` is the caller's."""
    path.parent.mkdir(parents=True, exist_ok=True)
    from mars_pairs.store.shards import naming

    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with naming(path):
        try:
            pq.write_table(
                table, tmp, row_group_size=row_group_size, compression="zstd", write_statistics=True
            )
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
    return tmp


def rows_to_table(rows: list[dict[str, Any]], schema: pa.Schema) -> pa.Table:
    """A table of ``schema`` from row dicts (missing keys become nulls)."""
    return pa.Table.from_pylist(
        [{f.name: row.get(f.name) for f in schema} for row in rows], schema=schema
    )


# -- reading and filtering ----------------------------------------------------------------------


class Manifest:
    """A dataset's manifest, filtered lazily: predicates are pushed down into pyarrow.

    Location filters test the rover position of each sample (where the image was taken).
    ``filter`` returns a new Manifest; nothing is read until ``to_table``/``len``.

    >>> m = Manifest.open("out/demo/dataset").filter(near=(18.44, 77.45, 500.0), split="train")
    >>> len(m), m.to_pandas()

    ``root``: a local folder or an fsspec URL (``s3://bucket/prefix``: ``store.fs``).
    """

    def __init__(
        self,
        root: Path | str,
        expression: Any = None,
        exact: tuple[Any, ...] = (),
        dataset: Any = None,
    ) -> None:
        import pyarrow.dataset as ds

        self.root = fs.dataset_root(root)
        if dataset is None:  # filtered Manifests share their parent's (footer read once)
            source, filesystem = fs.parquet_source(fs.join(self.root, "manifest.parquet"))
            dataset = ds.dataset(source, format="parquet", filesystem=filesystem)
        self._dataset = dataset
        self._expression = expression
        self._exact = exact  # callables table -> boolean mask, applied after the scan

    @classmethod
    def open(cls, root: str | Path) -> Manifest:
        """The manifest of a built dataset folder."""
        import pyarrow.dataset as ds

        from mars_pairs.errors import DatasetError

        root = fs.dataset_root(root)
        path = fs.join(root, "manifest.parquet")
        if not fs.is_file(path):
            raise DatasetError(root, None, "no manifest.parquet (not a mars-pairs dataset)")
        try:
            source, filesystem = fs.parquet_source(path)
            dataset = ds.dataset(source, format="parquet", filesystem=filesystem)
            dataset.schema.field("key")
        except (pa.ArrowException, OSError) as exc:
            raise DatasetError(path, None, f"unreadable Parquet: {exc}") from None
        except KeyError:
            raise DatasetError(path, "key", "no such column (not a mars-pairs manifest)") from None
        return cls(root, dataset=dataset)

    def require(self, columns: Sequence[str] = CORE_COLUMNS) -> Manifest:
        """This manifest, or DatasetError naming it and the first of ``columns`` it lacks."""
        from mars_pairs.errors import DatasetError

        names = set(self.column_names)  # a dataset built before a rename has the new names
        missing = [c for c in columns if RENAMED.get(c, c) not in names]
        if missing:
            path = fs.join(self.root, "manifest.parquet")
            raise DatasetError(path, missing[0], f"no such column ({len(missing)} missing)")
        return self

    @property
    def schema(self) -> pa.Schema:
        """The manifest's Arrow schema (its columns)."""
        return self._dataset.schema

    @property
    def crs(self) -> str | None:
        """The dataset CRS (PROJJSON text) from the GeoParquet metadata."""
        meta = self._dataset.schema.metadata or {}
        geo = json.loads(meta.get(b"geo", b"{}") or b"{}")
        crs = geo.get("columns", {}).get("footprint", {}).get("crs")
        return json.dumps(crs) if crs is not None else None

    def filter(
        self,
        *,
        bbox_lonlat: tuple[float, float, float, float] | None = None,
        bbox_map: tuple[float, float, float, float] | None = None,
        near: tuple[float, float, float] | None = None,
        polygon: Any = None,
        mission: str | list[str] | None = None,
        instrument: str | list[str] | None = None,
        sol: tuple[int, int] | None = None,
        split: str | list[str] | None = None,
    ) -> Manifest:
        """A new Manifest keeping rows that satisfy every given predicate.

        ``bbox_lonlat``: (west, south, east, north) degrees east/north, west > east crossing
        the 180th meridian (longitudes match modulo 360, so -180..180 and 0..360 data alike);
        ``bbox_map``: (xmin, ymin, xmax, ymax) in the dataset CRS; ``near``: (lat, lon,
        radius_m), great circle on the Mars sphere; ``polygon``: shapely geometry or WKT in
        the dataset CRS; ``sol``: inclusive (first, last); ``mission``/``instrument``/``split``:
        a value or a list of values. Numbers may be Python, numpy or pandas scalars (and the
        tuples numpy arrays or pandas Series); a wrong type, size, a NaN or an empty list
        raises ArgumentError naming the argument; a column a predicate needs that the
        manifest lacks, DatasetError naming the column.
        """
        import pyarrow.dataset as ds

        f = ds.field
        terms = []
        exact = list(self._exact)
        uses = [
            column
            for value, columns in (
                (bbox_lonlat, ("latitude", "longitude")),
                (bbox_map, ("easting", "northing")),
                (near, ("latitude", "longitude")),
                (polygon, ("easting", "northing")),
                (mission, ("mission",)),
                (instrument, ("instrument",)),
                (sol, ("sol",)),
                (split, ("split",)),
            )
            if value is not None
            for column in columns
        ]
        if bbox_lonlat is not None:
            w, s, e, n = numbers(bbox_lonlat, 4, "bbox_lonlat")
            terms.append((f("latitude") >= s) & (f("latitude") <= n))
            lon_term = _longitude_range(f("longitude"), w, e)
            if lon_term is not None:
                terms.append(lon_term)
        if bbox_map is not None:
            x0, y0, x1, y1 = numbers(bbox_map, 4, "bbox_map")
            terms.append(
                (f("easting") >= x0)
                & (f("easting") <= x1)
                & (f("northing") >= y0)
                & (f("northing") <= y1)
            )
        if near is not None:
            lat, lon, radius = numbers(near, 3, "near")
            dlat = math.degrees(radius / MARS_RADIUS_M)
            coslat = max(math.cos(math.radians(min(abs(lat) + dlat, 90.0))), 1e-9)
            dlon = dlat / coslat
            terms.append((f("latitude") >= lat - dlat) & (f("latitude") <= lat + dlat))
            if dlon < 180.0:
                lon_term = _longitude_range(f("longitude"), lon - dlon, lon + dlon)
                if lon_term is not None:
                    terms.append(lon_term)
            exact.append(_NearPredicate(lat, lon, radius))
        if polygon is not None:
            geom = geometry(polygon)
            x0, y0, x1, y1 = geom.bounds
            terms.append(
                (f("easting") >= x0)
                & (f("easting") <= x1)
                & (f("northing") >= y0)
                & (f("northing") <= y1)
            )
            exact.append(_PolygonPredicate(shapely_module().to_wkb(geom)))
        for name, value in (("mission", mission), ("instrument", instrument), ("split", split)):
            if value is not None:
                terms.append(f(name).isin(strings(value, name)))
        if sol is not None:
            first, last = integers(sol, 2, "sol")
            terms.append((f("sol") >= first) & (f("sol") <= last))
        self.require(uses)  # after the arguments: a bad argument is the caller's error
        expression = self._expression
        for term in terms:
            expression = term if expression is None else expression & term
        return Manifest(self.root, expression, tuple(exact), self._dataset)

    @property
    def column_names(self) -> list[str]:
        """The columns a reader sees (a dataset built before a rename shows the new names)."""
        return canonical_names(self._dataset.schema.names)

    def to_table(self, columns: list[str] | None = None) -> pa.Table:
        """The filtered rows (all columns, or ``columns``). An old column name (see
        :mod:`mars_pairs.store.columns`) reads its new column, with a DeprecationWarning; a
        column the manifest lacks is a DatasetError naming it."""
        stored = self._dataset.schema.names
        needed = None
        if columns is not None:
            columns = list(columns)
            for name in columns:
                if name in RENAMED:
                    warn_renamed(name)
            extra = {"latitude", "longitude", "easting", "northing"} if self._exact else set()
            needed = list(dict.fromkeys([*columns, *sorted(extra)]))
            needed = list(dict.fromkeys(stored_name(c, stored) for c in needed))
            self.require(needed)
        try:
            table = self._dataset.to_table(columns=needed, filter=self._expression)
        except (pa.ArrowException, OSError) as exc:  # a damaged file or a missing column
            from mars_pairs.errors import DatasetError

            raise DatasetError(fs.join(self.root, "manifest.parquet"), None, str(exc)) from None
        for predicate in self._exact:
            table = table.filter(predicate(table))
        if columns is None:
            return rename_to(table, canonical_names(table.column_names))
        return rename_to(table.select([stored_name(c, stored) for c in columns]), columns)

    def to_pandas(self) -> Any:
        """The filtered rows as a pandas DataFrame."""
        return self.to_table().to_pandas()

    def __len__(self) -> int:
        if not self._exact:
            try:
                return self._dataset.count_rows(filter=self._expression)
            except (pa.ArrowException, OSError) as exc:
                from mars_pairs.errors import DatasetError

                where = fs.join(self.root, "manifest.parquet")
                raise DatasetError(where, None, str(exc)) from None
        return self.to_table(columns=["key"]).num_rows


def _longitude_range(field: Any, west: float, east: float) -> Any:
    """Longitudes from ``west`` eastward to ``east`` (degrees east), modulo 360: ``west >
    east`` crosses the 180th meridian (or 0 for 0..360 data). An expression of plain ranges
    (row-group statistics still prune), matching values stored as -180..180 or 0..360;
    None when the range covers every longitude."""
    span = east - west if east >= west else east - west + 360.0
    if span >= 360.0:
        return None
    west -= 360.0 * math.floor((west + 180.0) / 360.0)  # into [-180, 180); exact if there
    # the range's copies that can meet stored values in [-180, 360)
    shifts = [0.0] + [-360.0] * (west + span >= 180.0) + [360.0] * (west < 0.0)
    expression = None
    for k in shifts:
        term = (field >= west + k) & (field <= west + span + k)
        expression = term if expression is None else expression | term
    return expression


def great_circle_m(lat1: Any, lon1: Any, lat2: Any, lon2: Any) -> Any:
    """Great-circle distance (metres) on the Mars sphere between planetocentric degrees."""
    import numpy as np

    p1, p2 = np.radians(lat1), np.radians(lat2)
    dp, dl = p2 - p1, np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dp / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return 2 * MARS_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0, 1)))


@dataclass(frozen=True)
class _NearPredicate:
    lat: float
    lon: float
    radius_m: float

    def __call__(self, table: pa.Table) -> pa.Array:
        d = great_circle_m(
            self.lat, self.lon, table["latitude"].to_numpy(), table["longitude"].to_numpy()
        )
        return pa.array(d <= self.radius_m)


@dataclass(frozen=True)
class _PolygonPredicate:
    wkb: bytes

    def __call__(self, table: pa.Table) -> pa.Array:
        import shapely

        geom = shapely.from_wkb(self.wkb)
        inside = shapely.intersects_xy(
            geom, table["easting"].to_numpy(), table["northing"].to_numpy()
        )
        return pa.array(inside)
