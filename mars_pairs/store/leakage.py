"""The leak check of a built manifest: do samples of different splits share ground?

Independent of the split rule (``store/splits.py``): it tests the extents actually written,
every chip (rotated square around the rover) and footprint polygon of one split against those
of every other split, with shapely's STRtree. Samples in the ``buffer`` split take no part.
Map units of the dataset CRS throughout.

:func:`leak_report` checks a table in memory; :func:`streamed_leak_report` checks a manifest
file a batch at a time with the same result: a sweep along the easting over the samples sorted
on disk by the west edge of their extent (``store.parquet_stream``), holding only the samples
whose extent reaches within the nearest held-out-to-train distance of the sweep line.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import shapely
from numpy.typing import NDArray

from mars_pairs.store import fs
from mars_pairs.store.parquet_stream import merge_runs, sorted_runs
from mars_pairs.store.splits import BUFFER, TRAIN


def chip_polygons(
    x: np.ndarray, y: np.ndarray, size_m: float, rotation_deg: np.ndarray
) -> np.ndarray:
    """Chip squares of side ``size_m`` centred on map points (x, y), turned ``rotation_deg``
    (clockwise, the chip's up direction from grid north), as shapely polygons."""
    t = np.radians(np.asarray(rotation_deg, dtype=np.float64))
    h = size_m / 2.0
    ux, uy = np.sin(t) * h, np.cos(t) * h  # up
    rx, ry = np.cos(t) * h, -np.sin(t) * h  # right
    corners = np.stack(
        [
            np.stack([x + s * rx + u * ux, y + s * ry + u * uy], axis=-1)
            for s, u in ((-1, 1), (1, 1), (1, -1), (-1, -1))
        ],
        axis=1,
    )
    chips = shapely.polygons(corners)
    assert isinstance(chips, np.ndarray)  # (N, 4, 2) corners: N polygons, not one
    return chips


def _pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) with geometry a[i] intersecting b[j] (None entries never match)."""
    tree = shapely.STRtree(b)
    i, j = tree.query(a, predicate="intersects")
    return i, j


def _min_distance(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) == 0 or len(b) == 0:
        return None
    _, dist = shapely.STRtree(b).query_nearest(a, return_distance=True, all_matches=False)
    return float(dist.min())


#: The manifest columns :func:`leak_report` reads.
LEAK_COLUMNS = ("split", "easting", "northing", "chip_rotation_deg", "footprint")


def _outside_buffer(table: pa.Table) -> tuple[NDArray[Any], Any, Any, Any, NDArray[Any]]:
    """The ``LEAK_COLUMNS`` of the rows outside the buffer zone: split names, rover easting
    and northing (map units), chip rotation (degrees, null as 0) and footprint WKB."""
    split = np.asarray(table["split"].to_pylist(), dtype=object)
    keep = split != BUFFER
    x = table["easting"].to_numpy()[keep]
    y = table["northing"].to_numpy()[keep]
    rot = table["chip_rotation_deg"].fill_null(0.0).to_numpy()[keep]
    wkb = np.asarray(table["footprint"].to_pylist(), dtype=object)[keep]
    return split[keep], x, y, rot, wkb


def leak_report(table: pa.Table, size_m: float) -> dict[str, Any]:
    """Intersections between the chips/footprints of samples of different splits, and the
    nearest held-out to train distances (rover to rover, extent to extent), map units."""
    split, x, y, rot, wkb = _outside_buffer(table)
    chips = chip_polygons(x, y, size_m, rot)
    feet = np.array([None if w is None else shapely.from_wkb(w) for w in wkb], dtype=object)
    counts = {}
    for name, a, b, ordered in (
        ("chip_chip", chips, chips, False),
        ("footprint_footprint", feet, feet, False),
        ("chip_footprint", chips, feet, True),
    ):
        i, j = _pairs(a, b) if len(split) else (np.zeros(0, int), np.zeros(0, int))
        differ = (split[i] != split[j]) & (i != j if ordered else i < j)
        counts[name] = int(np.count_nonzero(differ))
    held, train = split != TRAIN, split == TRAIN
    extents = np.array(
        [c if f is None else shapely.union(c, f) for c, f in zip(chips, feet, strict=True)],
        dtype=object,
    )
    rover = shapely.points(x, y)
    near = _min_distance(rover[held], rover[train])
    gap = _min_distance(extents[held], extents[train])
    return {
        "intersections_between_splits": counts,
        "min_rover_distance_held_out_to_train_m": None if near is None else round(near, 3),
        "min_extent_gap_held_out_to_train_m": None if gap is None else round(gap, 3),
    }


#: Manifest rows read at a time, and rows of a sorted run of :func:`streamed_leak_report`.
LEAK_BATCH = 4096
#: The sweep's order: the west edge of a sample's extent, then its row in the manifest.
SWEEP_ORDER = [("west", "ascending"), ("seq", "ascending")]
#: The sweep's rows: the row among the manifest's kept samples, the split's code (in the
#: order the manifest first holds it), the rover, the chip's rotation, the footprint (WKB)
#: and the west and east edges of the extent.
SWEEP_SCHEMA = pa.schema(
    [
        ("seq", pa.int64()),
        ("code", pa.int32()),
        ("x", pa.float64()),
        ("y", pa.float64()),
        ("rot", pa.float64()),
        ("footprint", pa.binary()),
        ("west", pa.float64()),
        ("east", pa.float64()),
    ]
)


def streamed_leak_report(
    manifest: fs.Location,
    size_m: float,
    scratch: Path,
    batch_rows: int = LEAK_BATCH,
) -> dict[str, Any]:
    """:func:`leak_report` of the manifest file ``manifest`` (its ``LEAK_COLUMNS``), the same
    dict, read ``batch_rows`` rows at a time.

    A first pass writes the kept samples (not ``buffer``) as runs of ``batch_rows`` rows
    sorted by the west edge of their extent (chip and footprint) into ``scratch`` (made by
    the first run; the caller removes it), and bounds the nearest held-out-to-train rover
    distance by the distance between neighbours of the file's order (the manifest's
    Hilbert order: close). The sweep then takes the samples west to east, a batch at a time,
    against a window of those before it whose extent's east edge is within that distance
    (the nearest found so far, or the bound) of the batch's west edge: two samples further
    apart along the easting meet neither in a chip nor a footprint and are not the nearest
    pair. Each pair is tested once, in the direction :func:`leak_report` tests it (the
    sample of the lower manifest row first; held-out against train), so counts and
    distances are those of :func:`leak_report`. Memory: a batch and the window, which
    holds the samples whose extents cross a strip that wide (all of them in the worst
    case: every held-out sample far from every train one)."""
    codes: dict[str, int] = {}
    pre = _FirstPass(size_m)
    with fs.open_input(manifest) as handle:
        batches = pq.ParquetFile(handle).iter_batches(batch_rows, columns=list(LEAK_COLUMNS))
        rows = (pre.rows(pa.Table.from_batches([b]), codes) for b in batches)
        runs, whole = sorted_runs(rows, SWEEP_ORDER, batch_rows, scratch)
    train = codes.get(TRAIN)
    both = train is not None and len(codes) > 1  # a held-out and a train sample
    sweep = _Sweep(size_m, train if both else None, pre.bound if both else 0.0)
    sorted_rows: Iterable[pa.Table] = [whole] if whole is not None else []
    if runs:
        sorted_rows = merge_runs(runs, SWEEP_ORDER, scratch)
    for batch in _batches(sorted_rows, batch_rows, sweep):
        sweep.add(batch)
    near = sweep.rover if both else None
    gap = sweep.gap if both else None
    return {
        "intersections_between_splits": dict(sweep.counts),
        "min_rover_distance_held_out_to_train_m": None if near is None else round(near, 3),
        "min_extent_gap_held_out_to_train_m": None if gap is None else round(gap, 3),
    }


def _batches(tables: Iterable[pa.Table], rows: int, sweep: _Sweep) -> Iterator[pa.Table]:
    """The rows of ``tables`` in order, as tables of ``rows`` rows or as many as the sweep's
    window holds, whichever is more (a window goes into a tree once for as many new rows)."""
    held: list[pa.Table] = []
    count = 0
    for table in tables:
        held.append(table)
        count += table.num_rows
        while count >= max(rows, sweep.window_rows, 1):
            whole = pa.concat_tables(held).combine_chunks()
            n = max(rows, sweep.window_rows, 1)
            rest = whole.slice(n)
            held, count = [rest], rest.num_rows
            yield whole.slice(0, n)
    if count:
        yield pa.concat_tables(held).combine_chunks()


class _FirstPass:
    """The sweep's rows of each manifest batch, and the bound on the nearest held-out-to-
    train rover distance: each sample against the last one of the other kind before it."""

    def __init__(self, size_m: float) -> None:
        self.size_m = size_m
        self.seq = 0
        self.bound = math.inf
        self.last: dict[bool, tuple[float, float]] = {}  # held? -> the last rover seen

    def rows(self, table: pa.Table, codes: dict[str, int]) -> pa.Table:
        split, x, y, rot, wkb = _outside_buffer(table)
        for name in split:
            codes.setdefault(str(name), len(codes))
        code = np.array([codes[str(name)] for name in split], dtype=np.int32)
        chips = shapely.bounds(chip_polygons(x, y, self.size_m, rot))
        feet = shapely.bounds(_footprints(wkb))
        seq = np.arange(self.seq, self.seq + len(x), dtype=np.int64)
        self.seq += len(x)
        self._bound(split != TRAIN, x, y)
        return pa.table(
            {
                "seq": seq,
                "code": code,
                "x": x,
                "y": y,
                "rot": rot,
                "footprint": pa.array(list(wkb), pa.binary()),
                "west": np.fmin(chips[:, 0], feet[:, 0]),
                "east": np.fmax(chips[:, 2], feet[:, 2]),
            },
            schema=SWEEP_SCHEMA,
        )

    def _bound(self, held: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        for kind in (True, False):  # each sample of kind ``not kind`` against the last ``kind``
            at = np.where(held == kind, np.arange(len(x)), -1)
            last = np.maximum.accumulate(at) if len(x) else at
            other = (held != kind) & (last >= 0)
            if np.any(other):
                d = np.hypot(x[other] - x[last[other]], y[other] - y[last[other]])
                self.bound = min(self.bound, float(d.min()))
            first = (held != kind) & (last < 0)
            if kind in self.last and np.any(first):
                px, py = self.last[kind]
                d = np.hypot(x[first] - px, y[first] - py)
                self.bound = min(self.bound, float(d.min()))
            if np.any(held == kind):
                i = int(np.flatnonzero(held == kind)[-1])
                self.last[kind] = (float(x[i]), float(y[i]))


def _footprints(wkb: np.ndarray) -> np.ndarray:
    return np.array([None if w is None else shapely.from_wkb(w) for w in wkb], dtype=object)


@dataclass
class _Samples:
    """Samples of the sweep: their manifest rows, split codes, rovers, chips, footprints,
    extents and extents' east edges."""

    seq: np.ndarray
    code: np.ndarray
    rover: np.ndarray
    chips: np.ndarray
    feet: np.ndarray
    extents: np.ndarray
    east: np.ndarray

    @staticmethod
    def of(table: pa.Table, size_m: float) -> _Samples:
        x, y = table["x"].to_numpy(), table["y"].to_numpy()
        chips = chip_polygons(x, y, size_m, table["rot"].to_numpy())
        feet = _footprints(np.asarray(table["footprint"].to_pylist(), dtype=object))
        extents = np.array(
            [c if f is None else shapely.union(c, f) for c, f in zip(chips, feet, strict=True)],
            dtype=object,
        )
        return _Samples(
            table["seq"].to_numpy(),
            table["code"].to_numpy(),
            shapely.points(x, y),
            chips,
            feet,
            extents,
            table["east"].to_numpy(),
        )

    def __len__(self) -> int:
        return len(self.seq)

    def take(self, rows: np.ndarray) -> _Samples:
        return _Samples(*(getattr(self, f)[rows] for f in _FIELDS))

    def __add__(self, other: _Samples) -> _Samples:
        return _Samples(*(np.concatenate([getattr(self, f), getattr(other, f)]) for f in _FIELDS))


_FIELDS = ("seq", "code", "rover", "chips", "feet", "extents", "east")


class _Sweep:
    """The sweep's state: the window of samples before the batch, the intersection counts
    and the nearest distances found (``train``: the code of the train split, None when
    there are no distances to find; ``bound``: an upper bound of the nearest rover
    distance)."""

    def __init__(self, size_m: float, train: int | None, bound: float) -> None:
        self.size_m = size_m
        self.train = train
        self.bound = bound
        self.counts = {"chip_chip": 0, "footprint_footprint": 0, "chip_footprint": 0}
        self.rover = math.inf
        self.gap = math.inf
        self.window: _Samples | None = None

    @property
    def window_rows(self) -> int:
        return 0 if self.window is None else len(self.window)

    def add(self, table: pa.Table) -> None:
        """Test the batch ``table`` (sweep rows, in sweep order, after those added) against
        itself and the window, then make it part of the window."""
        b = _Samples.of(table, self.size_m)
        w = self._reaching(self.window, float(table["west"][0].as_py()))
        both = b if w is None else w + b
        self._count("chip_chip", b, w, both, "chips", "chips", unordered=True)
        self._count("footprint_footprint", b, w, both, "feet", "feet", unordered=True)
        self._count("chip_footprint", b, w, both, "chips", "feet", unordered=False)
        if self.train is not None:
            self.rover = min(self.rover, self._nearest(b, w, both, "rover"))
            self.gap = min(self.gap, self._nearest(b, w, both, "extents"))
        # every later sample's west edge is at least the batch's last: the window the next
        # batch meets, and what sizes it (``_batches``)
        self.window = self._reaching(both, float(table["west"][-1].as_py()))

    def _reaching(self, w: _Samples | None, west: float) -> _Samples | None:
        """The samples of ``w`` that a sample whose west edge is at ``west`` or east of it
        may meet or be the nearest pair with: east edge within the nearest distance found
        (or its bound; 0 without distances to find) west of ``west``."""
        if w is None:
            return None
        reach = min(self.bound, self.rover) if self.train is not None else 0.0
        reach = reach * (1.0 + 1e-9) + 1e-6  # the float rounding of edges and distances
        return w.take(np.flatnonzero(w.east >= west - reach))

    def _count(
        self, name: str, b: _Samples, w: _Samples | None, both: _Samples,
        first: str, second: str, unordered: bool,
    ) -> None:  # fmt: skip
        """Pairs (i, j), i's ``first`` meeting j's ``second``, of different splits, with i or
        j in the batch ``b`` (``both``: the window ``w`` and the batch); ``unordered``: i's
        row before j's, and the pair once."""
        for query, tree in ((b, both), (w, b)):
            if query is None or len(query) == 0:
                continue
            i, j = shapely.STRtree(getattr(tree, second)).query(
                getattr(query, first), predicate="intersects"
            )
            differ = query.code[i] != tree.code[j]
            if unordered:
                differ &= query.seq[i] < tree.seq[j]
            self.counts[name] += int(np.count_nonzero(differ))

    def _nearest(self, b: _Samples, w: _Samples | None, both: _Samples, field: str) -> float:
        """The nearest held-out ``field`` to a train one, one of them in the batch."""
        best = math.inf
        for held, train in ((b, both), (w, b)):
            if held is None:
                continue
            queries = getattr(held, field)[held.code != self.train]
            targets = getattr(train, field)[train.code == self.train]
            if len(queries) and len(targets):
                _, dist = shapely.STRtree(targets).query_nearest(
                    queries, return_distance=True, all_matches=False
                )
                best = min(best, float(dist.min()))
        return best


def rounded(value: float) -> float:
    """A distance for dataset.json: millimetres, rounded up (a bound stays a bound)."""
    return math.ceil(value * 1000.0) / 1000.0
