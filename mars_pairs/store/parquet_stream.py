"""Tables written to Parquet and sorted a batch at a time: memory bounded by a batch, not by
the rows.

:class:`RowGroupWriter` writes tables handed to it one after another as one Parquet file cut
into row groups of exactly ``row_group_size`` rows (the last one shorter), the bytes
``pyarrow.parquet.write_table`` writes for their concatenation with the same options.
:func:`sorted_runs` cuts a stream of tables into sorted runs of at most ``run_rows`` rows,
each a scratch Arrow IPC file, and :func:`merge_runs` merges those runs back into one stream in
order, holding a batch of each run: an external merge sort. The sort keys must order the rows
totally (no two rows equal on every key: the manifest's ``key`` is unique), so the merged order
is the one ``Table.sort_by`` gives the whole table; keys must hold no null.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.ipc
import pyarrow.parquet as pq

#: ``Table.sort_by``'s keys: (column, "ascending").
SortKeys = list[tuple[str, str]]
#: At most this many runs are merged at once; more are merged in passes.
FAN_IN = 16
#: Rows a record batch of a run file: a run is read a batch at a time while merged, so the
#: merge holds ``FAN_IN`` of them (of the manifest's ~70 columns: ~6 MiB of Arrow buffers).
RUN_ROW_GROUP = 128
#: Rows the merge puts out at a time (in order: the merge's ``take`` of every column).
OUT_ROWS = 1024


class RowGroupWriter:
    """A Parquet file at ``path`` written from tables of ``schema`` (their metadata ignored:
    ``schema``'s is the file's), in row groups of ``row_group_size`` rows; zstd and
    statistics unless ``compression`` says otherwise. Holds less than a row group of rows
    between writes (``statistics``: the columns' statistics written). A file without a row
    written holds one empty row group, as
    ``pq.write_table`` of an empty table writes it."""

    def __init__(
        self,
        path: Path,
        schema: pa.Schema,
        row_group_size: int,
        compression: str = "zstd",
        statistics: bool = True,
    ) -> None:
        self.schema = schema
        self.rows = 0
        self._size = row_group_size
        self._pending: list[pa.Table] = []
        self._held = 0
        self._writer = pq.ParquetWriter(
            path, schema, compression=compression, write_statistics=statistics
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
    ``folder`` (Arrow IPC files, :class:`_RunWriter`; the folder made by the first) and None."""
    paths: list[Path] = []
    pending: list[pa.Table] = []
    held = 0

    def spill() -> None:
        run = pa.concat_tables(pending).sort_by(keys)
        folder.mkdir(parents=True, exist_ok=True)  # made on the first run: none when all fit
        path = folder / f"run-{len(paths):06d}.arrow"
        with _RunWriter(path, run.schema) as out:
            out.write(run)
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


def merge_runs(runs: list[Path], keys: SortKeys, folder: Path) -> Iterator[pa.Table]:
    """The rows of the sorted ``runs`` (written by :func:`sorted_runs`) in order, a table at
    a time, holding a batch of each run (``FAN_IN`` at most); more than ``FAN_IN`` runs
    are first merged in groups into runs in ``folder``. Every key ascending."""
    runs = list(runs)
    rounds = 0
    while len(runs) > FAN_IN:
        merged = []
        for start in range(0, len(runs), FAN_IN):
            group = runs[start : start + FAN_IN]
            path = folder / f"merged-{rounds:03d}-{start // FAN_IN:06d}.arrow"
            with pa.OSFile(str(group[0])) as first:
                schema = pa.ipc.open_file(first).schema
            with _RunWriter(path, schema) as out:
                for table in _merge(group, keys):
                    out.write(table)
            for done in group:
                done.unlink()
            merged.append(path)
        runs, rounds = merged, rounds + 1
    yield from _merge(runs, keys)


def _merge(runs: list[Path], keys: SortKeys) -> Iterator[pa.Table]:
    """The k-way merge: every row not after the smallest last row of the runs still being
    read is in order, so those rows of every run's batch go out together, sorted."""
    if any(order != "ascending" for _, order in keys):
        raise ValueError(f"merge_runs: keys {keys}: ascending keys only")
    names = [name for name, _ in keys]
    with contextlib.ExitStack() as stack:
        files = [stack.enter_context(pa.OSFile(str(path))) for path in runs]
        yield from _merge_files([pa.ipc.open_file(f) for f in files], keys, names)


def _merge_files(
    files: list[pa.ipc.RecordBatchFileReader], keys: SortKeys, names: list[str]
) -> Iterator[pa.Table]:
    batches = [0] * len(files)  # the next batch of each run
    held: list[pa.Table | None] = [None] * len(files)
    # the rows to go out, a block an iteration, and each block's order (indices into the
    # blocks concatenated): every row of a block is after every row of the blocks before it,
    # so the blocks are sorted each by its keys alone and taken together (one take of every
    # column for OUT_ROWS rows, not one an iteration)
    blocks: list[pa.Table] = []
    orders: list[pa.Array] = []
    rows = 0
    while True:
        for i, table in enumerate(held):
            while (table is None or table.num_rows == 0) and batches[i] < files[
                i
            ].num_record_batches:
                table = pa.Table.from_batches([files[i].get_batch(batches[i])])
                batches[i] += 1
            held[i] = table
        reading = [batches[i] < f.num_record_batches for i, f in enumerate(files)]
        if not any(t is not None and t.num_rows for t in held):
            break
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
            if frontier is None or _row(table, names, table.num_rows - 1) <= frontier:
                n = table.num_rows
            elif _row(table, names, 0) > frontier:
                continue
            else:
                n = _not_after(table, names, frontier)
            out.append(table.slice(0, n))
            held[i] = table.slice(n)
        block = pa.concat_tables(out)
        order = pc.sort_indices(block.select(names), sort_keys=keys)
        blocks.append(block)
        orders.append(pc.add(order, pa.scalar(rows, order.type)))
        rows += block.num_rows
        if rows >= OUT_ROWS:
            yield _taken(blocks, orders)
            blocks, orders, rows = [], [], 0
    if blocks:
        yield _taken(blocks, orders)


def _taken(blocks: list[pa.Table], orders: list[pa.Array]) -> pa.Table:
    """The rows of ``blocks`` concatenated, in the order of ``orders`` concatenated."""
    return pa.concat_tables(blocks).combine_chunks().take(pa.concat_arrays(orders))


class _RunWriter:
    """A run file: Arrow IPC (lz4), record batches of ``RUN_ROW_GROUP`` rows, read back a
    batch at a time. A Parquet run's footer, parsed, holds ~40 bytes a column a row group
    (~650 KiB a run of 4096 manifest rows); an IPC file's, a few bytes a batch."""

    def __init__(self, path: Path, schema: pa.Schema) -> None:
        self._sink = pa.OSFile(str(path), "wb")
        options = pa.ipc.IpcWriteOptions(compression=None)
        self._writer = pa.ipc.new_file(self._sink, schema, options=options)

    def write(self, table: pa.Table) -> None:
        self._writer.write_table(table, max_chunksize=RUN_ROW_GROUP)

    def __enter__(self) -> _RunWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self._writer.close()
        self._sink.close()


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
