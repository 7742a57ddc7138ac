"""Reading a dataset's manifest: :class:`Manifest`, filtered lazily (pyarrow pushdown)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.errors import ArgumentError, DatasetError
from mars_pairs.store import fs
from mars_pairs.store.columns import RENAMED, canonical_names, rename_to, stored_name, warn_renamed
from mars_pairs.store.filter import (
    DatasetValues,
    ManifestFilter,
    checked,
    near_in_order,
    predicates,
)
from mars_pairs.store.manifest import CORE_COLUMNS


class Manifest:
    """A dataset's manifest, filtered lazily: predicates are pushed down into pyarrow.

    Place filters test the rover position of each sample (where the image was taken) unless
    ``by="footprint"`` or ``by="chip"``; coordinates are longitude first. ``filter`` returns
    a new Manifest; nothing is read until ``to_table``/``len`` (the dataset's values, which
    filters are checked against, once, when a filter first needs them).

    >>> m = Manifest.open("out/demo/dataset").filter(near=(77.45, 18.44, 500.0), split="train")
    >>> len(m), m.to_pandas()

    ``root``: a local folder or an fsspec URL (``s3://bucket/prefix``: ``store.fs``).
    """

    def __init__(
        self,
        root: Path | str,
        expression: Any = None,
        exact: tuple[Any, ...] = (),
        dataset: Any = None,
        values: DatasetValues | None = None,
    ) -> None:
        import pyarrow.dataset as ds

        self.root = fs.dataset_root(root)
        if dataset is None:  # filtered Manifests share their parent's (footer read once)
            source, filesystem = fs.parquet_source(fs.join(self.root, "manifest.parquet"))
            dataset = ds.dataset(source, format="parquet", filesystem=filesystem)
        self._dataset = dataset
        self._expression = expression
        self._exact = exact  # callables table -> boolean mask, applied after the scan
        self._values = values

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

    def filter(self, spec: ManifestFilter | None = None, /, **arguments: Any) -> Manifest:
        """A new Manifest keeping rows that satisfy every given predicate.

        The arguments are :class:`~mars_pairs.store.filter.ManifestFilter`'s (or one
        ManifestFilter): ``bbox_lonlat`` (W, S, E, N) degrees, ``bbox_map`` (xmin, ymin,
        xmax, ymax) map units, ``near`` (lon, lat, radius_m), ``polygon_lonlat`` /
        ``polygon_map`` (``polygon``: the map one), ``mission``, ``instrument``, ``split``,
        ``sol`` (first, last) and ``by`` (``rover``, ``footprint`` or ``chip``: what a place
        filter tests); ``saw`` (lon, lat) degrees: the samples whose footprint polygon holds
        the point (the manifest's footprint: a hull of the cells in view). A bad value is an
        ArgumentError naming the argument; a mission,
        instrument or split the dataset lacks an ArgumentError listing its values; a sol range
        outside its sols or a place filter missing the dataset's extent a FilterWarning
        giving its sols or its extent (0 rows); a column a predicate needs that the manifest lacks,
        DatasetError naming the column.
        """
        if spec is None:
            if "saw" in arguments:  # the footprints holding a point: they meet a ~6 mm box
                arguments = _saw_as_box(arguments)
            if "near" in arguments:
                arguments = {**arguments, "near": near_in_order(arguments["near"], self.values)}
            spec = ManifestFilter.of(arguments)
        elif arguments or not isinstance(spec, ManifestFilter):
            raise ArgumentError("filter: pass one ManifestFilter or keyword arguments, not both")
        found = predicates(spec, self.crs)
        self.require(list(found.uses))  # after the arguments: a bad argument is the caller's
        checked(spec, self.values)
        expression = self._expression
        for term in found.terms:
            expression = term if expression is None else expression & term
        exact = (*self._exact, *found.exact)
        return Manifest(self.root, expression, exact, self._dataset, self._values)

    @property
    def values(self) -> DatasetValues:
        """What the whole dataset holds (its missions, instruments, splits, sols, extents),
        which filters are checked against; read lazily, shared by filtered Manifests."""
        if self._values is None:
            dataset, root = self._dataset, self.root

            def scan(columns: list[str]) -> pa.Table:
                stored = dataset.schema.names
                self.require(columns)
                names = [stored_name(c, stored) for c in columns]
                try:
                    table = dataset.to_table(columns=names)
                except (pa.ArrowException, OSError) as exc:
                    raise DatasetError(fs.join(root, "manifest.parquet"), None, str(exc)) from None
                return rename_to(table, columns)

            def configured() -> set[str]:
                from mars_pairs.store.dataset_info import read_dataset_info

                try:
                    return read_dataset_info(root, required=False).configured_splits() or set()
                except DatasetError:
                    return set()  # a damaged dataset.json: the names on the rows

            self._values = DatasetValues(scan, self.crs, str(root), configured)
        return self._values

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
            extra = [c for p in self._exact for c in p.columns]
            needed = list(dict.fromkeys([*columns, *extra]))
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

    def to_geopandas(self, geometry: str = "footprint") -> Any:
        """The filtered rows as a geopandas GeoDataFrame: every geometry column the manifest
        holds (``footprint``, ``rover_point``, ``chip_box``: WKB in the dataset CRS) decoded,
        ``geometry`` the active one, the CRS from the GeoParquet metadata. Needs geopandas."""
        import importlib

        try:
            geopandas = importlib.import_module("geopandas")  # optional, and without stubs
        except ImportError:
            raise ArgumentError("to_geopandas needs geopandas (pip install geopandas)") from None
        from mars_pairs.store.geoparquet import GEOMETRY_COLUMNS

        frame = self.to_pandas()
        present = [c for c in GEOMETRY_COLUMNS if c in frame.columns]
        if geometry not in present:
            raise ArgumentError(f"geometry: expected one of {present}, got {geometry!r}")
        crs = self.crs
        for column in present:
            frame[column] = geopandas.GeoSeries.from_wkb(frame[column], crs=crs)
        return geopandas.GeoDataFrame(frame, geometry=geometry, crs=crs)

    def __repr__(self) -> str:
        """Path, rows, rows per split and a columns summary."""
        import pyarrow.compute as pc

        names = self.column_names
        try:
            table = self.to_table(columns=["split"] if "split" in names else ["key"])
        except DatasetError as exc:
            return f"Manifest({str(self.root)!r}: unreadable: {exc})"
        splits = ""
        if "split" in table.column_names:
            counts = pc.value_counts(table["split"]).to_pylist()
            by = sorted((str(c["values"]), int(c["counts"])) for c in counts)
            splits = ", splits: " + ", ".join(f"{k} {v}" for k, v in by)
        shown = ", ".join(names[:8]) + (f", ... ({len(names) - 8} more)" if len(names) > 8 else "")
        filtered = ", filtered" if self._expression is not None or self._exact else ""
        return (
            f"Manifest({str(self.root)!r}: {table.num_rows} rows{filtered}{splits}; "
            f"{len(names)} columns: {shown})"
        )

    def __len__(self) -> int:
        if not self._exact:
            try:
                return int(self._dataset.count_rows(filter=self._expression))
            except (pa.ArrowException, OSError) as exc:
                where = fs.join(self.root, "manifest.parquet")
                raise DatasetError(where, None, str(exc)) from None
        return int(self.to_table(columns=["key"]).num_rows)


def _saw_as_box(arguments: dict[str, Any]) -> dict[str, Any]:
    """``saw=(lon, lat)`` as the place filter it is: a 1e-7 degree (~6 mm) lon/lat box tested
    against the footprints; another place filter or ``by`` beside it is an ArgumentError."""
    from mars_pairs.store.catalog import checked_point

    rest = {k: v for k, v in arguments.items() if k != "saw"}
    others = [k for k in ("bbox_lonlat", "bbox_map", "near", "polygon", "polygon_lonlat",
                          "polygon_map", "by") if rest.get(k) is not None]  # fmt: skip
    if others:
        raise ArgumentError(f"saw: a place of its own; not with {', '.join(others)}")
    lon, lat = checked_point(arguments["saw"], "saw")
    eps = 1e-7
    return {**rest, "bbox_lonlat": (lon - eps, lat - eps, lon + eps, lat + eps), "by": "footprint"}
