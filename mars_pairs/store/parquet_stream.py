"""Parquet written and sorted a batch at a time: memory bounded by a batch, not by the rows.

:class:`RowGroupWriter` writes tables handed to it one after another as one Parquet file cut
into row groups of exactly ``row_group_size`` rows (the last one shorter), the bytes
``pyarrow.parquet.write_table`` writes for their concatenation with the same options.
:func:`sorted_runs` cuts a stream of tables into sorted runs of at most ``run_rows`` rows,
each a scratch Parquet file, and :func:`merge_runs` merges those runs back into one stream in
order, holding a batch of each run: an external merge sort. The sort keys must order the rows
totally (no two rows equal on every key: the manifest's ``key`` is unique), so the merged order
is the one ``Table.sort_by`` gives the whole table; keys must hold no null.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

#: ``Table.sort_by``'s keys: (column, "ascending").
SortKeys = list[tuple[str, str]]
#: At most this many runs are merged at once; more are merged in passes.
FAN_IN = 64
#: The fewest rows read from a run at a time while merging.
MIN_BATCH = 64


class RowGroupWriter:
    """A Parquet file at ``path`` written from tables of ``schema`` (their metadata ignored:
    ``schema``'s is the file's), in row groups of ``row_group_size`` rows; zstd and
    statistics unless ``compression`` says otherwise. Holds less than a row group of rows
    between writes. A file without a row written holds one empty row group, as
    ``pq.write_table`` of an empty table writes it."""

    def __init__(
        self, path: Path, schema: pa.Schema, row_group_size: int, compression: str = "zstd"
    ) -> None:
        self.schema = schema
        self.rows = 0
        self._size = row_group_size
        self._pending: list[pa.Table] = []
        self._held = 0
        self._writer = pq.ParquetWriter(
            path, schema, compression=compression, write_statistics=True
        )

    def write(self, table: pa.Table) -> None:
        """Add ``table``'s rows after those written."""
        if table.num_rows == 0:
            return
        self._pending.append(table.replace_schema_metadata(self.schema.metadata))
        self._held += table.num_rows
        if self._held >= self._size:
            held = pa.concat_tables(self._pending)
            whole = (self._held // self._size) * self._size
            self._writer.write_table(held.slice(0, whole), row_group_size=self._size)
            rest = held.slice(whole)
            self._pending, self._held = ([rest] if rest.num_rows else []), rest.num_rows
        self.rows += table.num_rows

    def close(self) -> None:
        """Write the rows held and the footer."""
        if self._held or self.rows == 0:
            held = pa.concat_tables(self._pending) if self._pending else self.schema.empty_table()
            self._writer.write_table(held, row_group_size=self._size)
        self._pending, self._held = [], 0
        self._writer.close()

    def __enter__(self) -> RowGroupWriter:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if kind is None:
            self.close()
        else:
            self._writer.close()


def sorted_runs(
    tables: Iterable[pa.Table], keys: SortKeys, run_rows: int, folder: Path
) -> tuple[list[Path], pa.Table | None]:
    """Cut ``tables`` (one schema, metadata ignored) into runs of at least ``run_rows`` rows
    (the last may be shorter), each sorted by ``keys``. When every row fits in one run, the
    sorted table itself (None without a row) and no file; otherwise the runs as files in
    ``folder`` (lz4) and None."""
    paths: list[Path] = []
    pending: list[pa.Table] = []
    held = 0

    def spill() -> None:
        run = pa.concat_tables(pending).sort_by(keys)
        path = folder / f"run-{len(paths):06d}.parquet"
        pq.write_table(run, path, compression="lz4")
        paths.append(path)

    for table in tables:
        if table.num_rows == 0:  # nothing to hold (a table holds its schema: ~1 KiB a column)
            continue
        pending.append(table.replace_schema_metadata(None))
        held += table.num_rows
        if held >= run_rows:
            spill()
            pending, held = [], 0
    if not paths:
        return [], pa.concat_tables(pending).sort_by(keys) if pending else None
    if held:
        spill()
    return paths, None


def merge_runs(
    runs: list[Path], keys: SortKeys, held_rows: int, folder: Path
) -> Iterator[pa.Table]:
    """The rows of the sorted ``runs`` in order, a table at a time, holding about
    ``held_rows`` rows (a batch of each run, at least ``MIN_BATCH`` rows); more than
    ``FAN_IN`` runs are first merged in groups into runs in ``folder``. Every key
    ascending."""
    runs = list(runs)
    batch_rows = max(MIN_BATCH, held_rows // max(1, min(len(runs), FAN_IN)))
    rounds = 0
    while len(runs) > FAN_IN:
        merged = []
        for start in range(0, len(runs), FAN_IN):
            group = runs[start : start + FAN_IN]
            path = folder / f"merged-{rounds:03d}-{start // FAN_IN:06d}.parquet"
            schema = pq.read_schema(group[0])
            with RowGroupWriter(path, schema, 65536, compression="lz4") as out:
                for table in _merge(group, keys, batch_rows):
                    out.write(table)
            for done in group:
                done.unlink()
            merged.append(path)
        runs, rounds = merged, rounds + 1
    yield from _merge(runs, keys, batch_rows)


def _merge(runs: list[Path], keys: SortKeys, batch_rows: int) -> Iterator[pa.Table]:
    """The k-way merge: every row not after the smallest last row of the runs still being
    read is in order, so those rows of every run's batch go out together, sorted."""
    if any(order != "ascending" for _, order in keys):
        raise ValueError(f"merge_runs: keys {keys}: ascending keys only")
    names = [name for name, _ in keys]
    files = [pq.ParquetFile(path) for path in runs]
    batches = [f.iter_batches(batch_rows) for f in files]
    held: list[pa.Table | None] = [None] * len(runs)
    reading = [True] * len(runs)
    while True:
        for i, table in enumerate(held):
            while reading[i] and (table is None or table.num_rows == 0):
                batch = next(batches[i], None)
                if batch is None:
                    reading[i] = False
                else:
                    table = pa.Table.from_batches([batch])
            held[i] = table
        live = [t for t in held if t is not None and t.num_rows]
        if not live:
            return
        lasts = [
            _row(t, names, t.num_rows - 1)
            for t, more in zip(held, reading, strict=True)
            if more and t is not None
        ]
        frontier = min(lasts) if lasts else None
        out = []
        for i, table in enumerate(held):
            if table is None or table.num_rows == 0:
                continue
            n = table.num_rows if frontier is None else _not_after(table, names, frontier)
            out.append(table.slice(0, n))
            held[i] = table.slice(n)
        yield pa.concat_tables(out).sort_by(keys)


def _row(table: pa.Table, names: list[str], i: int) -> tuple[Any, ...]:
    return tuple(table[name][i].as_py() for name in names)


def _not_after(table: pa.Table, names: list[str], frontier: tuple[Any, ...]) -> int:
    """How many leading rows of the sorted ``table`` are not after ``frontier`` (keys in
    ``names`` order, compared as ``Table.sort_by`` compares them)."""
    mask: Any = None
    for name, value in reversed(list(zip(names, frontier, strict=True))):
        column = table[name]
        step = pc.less_equal(column, value) if mask is None else pc.less(column, value)
        if mask is not None:
            step = pc.or_(step, pc.and_(pc.equal(column, value), mask))
        mask = step
    return int(pc.sum(mask).as_py() or 0)
