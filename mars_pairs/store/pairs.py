"""Pairs of images that saw the same ground: every pair whose footprints overlap, found
through a spatial index (``shapely.STRtree``: O(N log N + pairs), never all N^2 pairs), in
blocks of query rows taken in the table's order (a catalogue's and a manifest's rows are in
Hilbert order: spatial blocks), paired on a few threads and streamed out in order, so memory
holds a few blocks' pairs at a time. Each box candidate's intersection area comes from the
compiled kernel ``kernels.overlap`` when the pair is small and in general position (and
the footprints are ``KERNEL_MIN_FOOTPRINTS`` or more), from GEOS otherwise
(``intersection_map_areas``): the pairs and areas (to 1e-9 relative) of
``shapely.area(shapely.intersection(a, b)) > 0`` over every pair.

Frames and units: footprints in one map CRS (map units); areas are turned into true square
metres by each footprint's own scale (its true area over its map area: a catalogue's
visible area, a manifest's map area over the CRS's areal scale at the rover), distances
between camera centres are true metres on the Mars sphere (great circle at the mean height,
then the height difference), headings are the centre rays' azimuths (degrees from true
north).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pyproj
import shapely

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.kernels.overlap import intersection_areas
from mars_pairs.store.atomic import atomic_path
from mars_pairs.store.catalog_schema import DATASET_PAIR_SCHEMA, PAIR_SCHEMA

#: query rows per batch: bounds the memory of the pairs in flight
BATCH_ROWS = 4096
#: an intersection area under this fraction of the smaller footprint's is GEOS's to give
#: (the kernel's error there may exceed 1e-9 relative)
SLIVER = 1e-4
#: pairs whose vertex counts multiply to more go to GEOS (the kernel is O(n m), GEOS near
#: O(n + m): measured in ``kernels.overlap``)
KERNEL_VERTICES = 4096
#: fewer footprints than this: every area from GEOS, the kernel not loaded (loading its
#: compiled code is ~0.3 s of CPU, the ~66 us it saves a small pair against GEOS pays that
#: back after ~4,500 pairs; the demo's 270 footprints: 837 candidates, 0.19 s from GEOS
#: against 0.49 s with the kernel's load)
KERNEL_MIN_FOOTPRINTS = 1000
#: threads pairing blocks at once (shapely's vectorised operations release the GIL)
THREADS = 2


@dataclass(frozen=True)
class Footprints:
    """The images to pair, one entry per image (arrays of one length N).

    ``geometry``: shapely (multi)polygons in the map CRS (None: no footprint, never paired);
    ``area_m2``: each footprint's true area (square metres; NaN: take the map area);
    ``lon``/``lat``: camera centres, degrees on the Mars sphere; ``z``: their heights (m);
    ``azimuth``: centre-ray azimuth (degrees from true north); ``position``: one id per
    rover position (images with equal ids share a position); ``split``: each image's split
    (None: not a dataset)."""

    keys: np.ndarray
    geometry: np.ndarray
    area_m2: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    z: np.ndarray
    azimuth: np.ndarray
    position: np.ndarray
    split: np.ndarray | None = None

    @classmethod
    def from_table(
        cls, table: pa.Table, geometry: str = "footprint", crs: str | None = None
    ) -> Footprints:
        """The footprints of a catalogue table (``catalog.parquet``'s columns) or of a dataset
        manifest (``footprint``, ``longitude``/``latitude``/``elevation_m`` of the rover,
        ``split``), whose true areas are the map areas over the areal scale of ``crs`` (the
        dataset's, WKT or PROJJSON; required for a manifest) at the rover's position."""
        names = table.column_names

        def col(name: str) -> np.ndarray:
            values: np.ndarray = table[name].to_numpy(zero_copy_only=False)
            return values

        geoms = np.asarray(shapely.from_wkb(col(geometry)), dtype=object)
        catalog = "camera_lon" in names
        if catalog:
            area = col("visible_area_m2").astype(np.float64)
        elif crs is None:
            raise ArgumentError("Footprints.from_table: a manifest needs its CRS (crs=...)")
        else:
            factors = pyproj.Proj(crs).get_factors(
                col("longitude").astype(np.float64), col("latitude").astype(np.float64)
            )
            with np.errstate(invalid="ignore", divide="ignore"):
                area = shapely.area(geoms) / np.asarray(factors.areal_scale, dtype=np.float64)
        position = np.asarray(
            [
                f"{m}|{s}|{d}|{p}"
                for m, s, d, p in zip(
                    col("mission"), col("site"), col("drive"), col("pose"), strict=True
                )
            ],
            dtype=object,
        )
        return cls(
            keys=col("key").astype(object),
            geometry=geoms,
            area_m2=area,
            lon=col("camera_lon" if catalog else "longitude").astype(np.float64),
            lat=col("camera_lat" if catalog else "latitude").astype(np.float64),
            z=col("camera_z" if catalog else "elevation_m").astype(np.float64),
            azimuth=col("azimuth_deg").astype(np.float64),
            position=position,
            split=None if "split" not in names else col("split").astype(object),
        )


def great_circle_m(
    lon_a: np.ndarray, lat_a: np.ndarray, lon_b: np.ndarray, lat_b: np.ndarray, radius: Any
) -> np.ndarray:
    """Great-circle distance (metres on a sphere of ``radius`` m) between lon/lat degrees."""
    la, lb = np.radians(lat_a), np.radians(lat_b)
    dlon, dlat = np.radians(lon_b - lon_a), lb - la
    h = np.sin(dlat / 2) ** 2 + np.cos(la) * np.cos(lb) * np.sin(dlon / 2) ** 2
    out: np.ndarray = np.asarray(2.0 * radius * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0))))
    return out


def intersection_map_areas(
    geoms: np.ndarray, a: np.ndarray, b: np.ndarray, map_area: np.ndarray, kernel: bool = True
) -> np.ndarray:
    """The area (map units squared) of ``geoms[a[k]]`` and ``geoms[b[k]]``'s intersection
    for every k, as ``shapely.area(shapely.intersection(...))`` gives it (to 1e-9 relative):
    ``kernels.overlap`` answers the pairs in general position, GEOS the rest (touching or
    overlapping edges, slivers under ``SLIVER`` of the smaller footprint, pairs over
    ``KERNEL_VERTICES``, footprints that are not (multi)polygons). ``map_area``: every
    footprint's map area. ``kernel`` False: every area from GEOS."""
    area = np.zeros(len(a))
    redo = np.ones(len(a), dtype=bool)
    if len(a) and kernel:
        rows, local = np.unique(np.concatenate([a, b]), return_inverse=True)
        la, lb = local[: len(a)], local[len(a) :]
        ragged = _ragged(geoms[rows])
        if ragged is not None:
            xy, rings, geom_rings = ragged
            vertices = rings[geom_rings[1:]] - rings[geom_rings[:-1]]
            small = vertices[la] * vertices[lb] <= KERNEL_VERTICES
            if small.any():  # else the kernel is not even loaded
                got, ok = intersection_areas(xy, rings, geom_rings, la[small], lb[small])
                area[small] = got
                smaller = np.minimum(map_area[a], map_area[b])
                redo[small] = ~ok | ((got != 0) & ~(got >= SLIVER * smaller[small]))
    if redo.any():
        area[redo] = shapely.area(shapely.intersection(geoms[a[redo]], geoms[b[redo]]))
    return area


def _ragged(geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(vertices (M, 2), ring offsets, each footprint's first ring) of (multi)polygons,
    rings oriented for ``kernels.overlap``; None for any other geometry type."""
    oriented = shapely.orient_polygons(geoms)
    try:
        kind, xy, offsets = shapely.to_ragged_array(oriented)
    except ValueError:
        return None
    if kind == shapely.GeometryType.POLYGON:
        rings, geom_rings = offsets
    elif kind == shapely.GeometryType.MULTIPOLYGON:
        rings, poly_rings, geom_polys = offsets
        geom_rings = poly_rings[geom_polys]
    else:
        return None
    return (
        np.ascontiguousarray(xy, dtype=np.float64),
        rings.astype(np.int64),
        geom_rings.astype(np.int64),
    )


def iter_pairs(
    fp: Footprints, batch_rows: int = BATCH_ROWS, threads: int = THREADS
) -> Iterator[pa.RecordBatch]:
    """Every pair of images whose footprints overlap (intersection area > 0), once each, as
    record batches of ``PAIR_SCHEMA`` (``DATASET_PAIR_SCHEMA`` when ``fp.split`` is given):
    ``key_a`` < ``key_b``. Rows come in the order of the query image (the table's row
    order), then of its partner: the same rows for the same footprints whatever
    ``batch_rows`` and ``threads`` (blocks of ``batch_rows`` query images are paired on
    ``threads`` threads, at most ``threads + 1`` blocks in flight, yielded in order)."""
    geoms = fp.geometry
    valid = ~shapely.is_missing(geoms)
    index = np.flatnonzero(valid)
    map_area = np.where(valid, shapely.area(geoms), np.nan)
    positive = np.isfinite(fp.area_m2) & (map_area > 0)
    rank = np.empty(len(fp.keys), dtype=np.int64)
    rank[np.argsort(fp.keys, kind="stable")] = np.arange(len(fp.keys))
    pairing = _Pairing(
        fp=fp,
        tree=shapely.STRtree(geoms[index]),
        index=index,
        map_area=map_area,
        scale=np.where(positive, fp.area_m2 / np.where(positive, map_area, 1.0), 1.0),
        rank=rank,
        position=np.unique(fp.position, return_inverse=True)[1],
        keys=pa.array(fp.keys, type=pa.string()),
        split=None if fp.split is None else pa.array(fp.split, type=pa.string()),
    )
    blocks = (index[s : s + batch_rows] for s in range(0, len(index), batch_rows))
    if threads <= 1:
        for query in blocks:
            batch = pairing.block(query)
            if batch is not None:
                yield batch
        return
    with ThreadPoolExecutor(threads) as pool:
        pending: deque[Future[pa.RecordBatch | None]] = deque()
        for query in blocks:
            pending.append(pool.submit(pairing.block, query))
            if len(pending) > threads:
                batch = pending.popleft().result()
                if batch is not None:
                    yield batch
        for future in pending:
            batch = future.result()
            if batch is not None:
                yield batch


@dataclass(frozen=True)
class _Pairing:
    """What every block of query images reads (never writes): the footprints, the STRtree
    over the valid ones (``index``: their rows), each footprint's map area and true-area
    scale, the keys' sort rank, the position ids, the keys and splits as Arrow arrays."""

    fp: Footprints
    tree: shapely.STRtree
    index: np.ndarray
    map_area: np.ndarray
    scale: np.ndarray
    rank: np.ndarray
    position: np.ndarray
    keys: pa.Array
    split: pa.Array | None

    def block(self, query: np.ndarray) -> pa.RecordBatch | None:
        """The pairs whose lower row is one of ``query`` (rows, ascending), in (a, b) row
        order; None when there are none. The tree gives the box candidates, whose
        intersection areas come from ``intersection_map_areas``."""
        qi, ti = self.tree.query(self.fp.geometry[query])
        a, b = query[qi], self.index[ti]
        keep = b > a
        a, b = a[keep], b[keep]
        order = np.lexsort((b, a))
        a, b = a[order], b[order]
        kernel = len(self.fp.keys) >= KERNEL_MIN_FOOTPRINTS
        inter = intersection_map_areas(self.fp.geometry, a, b, self.map_area, kernel)
        keep = inter > 0
        a, b, inter = a[keep], b[keep], inter[keep]
        if not len(a):
            return None
        union = self.map_area[a] + self.map_area[b] - inter
        return self._batch(a, b, inter, union)

    def _batch(
        self, a: np.ndarray, b: np.ndarray, inter: np.ndarray, union: np.ndarray
    ) -> pa.RecordBatch:
        fp, scale = self.fp, self.scale
        swap = self.rank[a] > self.rank[b]
        first, second = np.where(swap, b, a), np.where(swap, a, b)
        mean_z = (fp.z[a] + fp.z[b]) / 2.0
        ground = great_circle_m(fp.lon[a], fp.lat[a], fp.lon[b], fp.lat[b], MARS_RADIUS_M + mean_z)
        distance = np.hypot(ground, fp.z[a] - fp.z[b])
        heading = np.abs((fp.azimuth[a] - fp.azimuth[b] + 180.0) % 360.0 - 180.0)
        columns: dict[str, Sequence[object] | np.ndarray | pa.Array] = {
            "key_a": self.keys.take(pa.array(first)),
            "key_b": self.keys.take(pa.array(second)),
            "intersection_m2": inter * (scale[a] + scale[b]) / 2.0,
            "iou": inter / union,
            "distance_m": distance,
            "heading_diff_deg": heading,
            "same_position": self.position[a] == self.position[b],
        }
        schema = PAIR_SCHEMA
        if self.split is not None and fp.split is not None:
            columns |= {
                "split_a": self.split.take(pa.array(first)),
                "split_b": self.split.take(pa.array(second)),
                "cross_split": fp.split[first] != fp.split[second],
            }
            schema = DATASET_PAIR_SCHEMA
        return pa.RecordBatch.from_pydict(
            {k: pa.array(v, type=schema.field(k).type) for k, v in columns.items()},
            schema=schema,
        )


def pairs_table(fp: Footprints, batch_rows: int = BATCH_ROWS, threads: int = THREADS) -> pa.Table:
    """``iter_pairs`` gathered in one table (a catalogue's; a stream for very large ones)."""
    schema = PAIR_SCHEMA if fp.split is None else DATASET_PAIR_SCHEMA
    return pa.Table.from_batches(list(iter_pairs(fp, batch_rows, threads)), schema=schema)


def write_pairs(
    path: Path, fp: Footprints, batch_rows: int = BATCH_ROWS, threads: int = THREADS
) -> int:
    """Write ``iter_pairs(fp)`` to the Parquet file ``path`` (atomically, batch by batch);
    the number of pairs."""
    schema = PAIR_SCHEMA if fp.split is None else DATASET_PAIR_SCHEMA
    count = 0
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, pq.ParquetWriter(tmp, schema, compression="zstd") as writer:
        for batch in iter_pairs(fp, batch_rows, threads):
            writer.write_batch(batch)
            count += batch.num_rows
        if count == 0:
            writer.write_table(schema.empty_table())
    return count
