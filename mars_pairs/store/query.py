"""Reading a dataset's manifest: :class:`Manifest`, filtered lazily (pyarrow pushdown)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.errors import DatasetError
from mars_pairs.geometry.body import MARS_RADIUS_M, great_circle_m
from mars_pairs.store import fs
from mars_pairs.store.columns import RENAMED, canonical_names, rename_to, stored_name, warn_renamed
from mars_pairs.store.filter_args import geometry, integers, numbers, shapely_module, strings
from mars_pairs.store.manifest import CORE_COLUMNS


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
        saw: tuple[float, float] | None = None,
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
        manifest lacks, DatasetError naming the column. ``saw``: (lon, lat) degrees east/north
        on the Mars sphere, longitude first: the samples whose ``footprint`` polygon (the
        manifest's: the convex hull of the cells in view and the camera) holds the point.
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
                (saw, ("footprint", "bbox")),
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
        if saw is not None:
            from mars_pairs.geometry.frames import lonlat_to_map
            from mars_pairs.store.catalog import checked_point

            lon, lat = checked_point(saw, "saw")
            if self.crs is None:
                raise DatasetError(self.root, "footprint", "saw: the manifest names no CRS")
            mx, my = (float(v[0]) for v in lonlat_to_map([lon], [lat], self.crs))
            terms.append(
                (f("bbox", "xmin") <= mx)
                & (f("bbox", "xmax") >= mx)
                & (f("bbox", "ymin") <= my)
                & (f("bbox", "ymax") >= my)
            )
            exact.append(_SawPredicate(mx, my))
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
                return int(self._dataset.count_rows(filter=self._expression))
            except (pa.ArrowException, OSError) as exc:
                where = fs.join(self.root, "manifest.parquet")
                raise DatasetError(where, None, str(exc)) from None
        return int(self.to_table(columns=["key"]).num_rows)


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


@dataclass(frozen=True)
class _SawPredicate:
    x: float  # map units, dataset CRS
    y: float

    def __call__(self, table: pa.Table) -> pa.Array:
        import shapely

        geoms = shapely.from_wkb(table["footprint"].to_numpy(zero_copy_only=False))
        return pa.array(shapely.intersects_xy(geoms, self.x, self.y) & ~shapely.is_missing(geoms))
