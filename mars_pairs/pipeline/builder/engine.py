"""The build engines' one contract: chunks of labels in, typed chunk results out, in order.

An engine (:class:`Engine`: the in-process build, ``pipeline.builder.local_pool.LocalPool``,
``pipeline.builder.dask_engine.DaskEngine``) runs :func:`build_chunk` once per chunk, wherever its
workers are. A worker builds the chunk's samples one at a time and writes them straight
into the chunk's shard of its split in the output folder (``shards/shard-{k:06d}-{split}.tar``,
through the temporary name ``.shard-{k:06d}-{split}.tar.tmp-<pid>`` and a rename:
``store.shards.ShardWriter``; a split's samples never share a shard with another split's),
so a sample's bytes never leave the worker that built it; the worker also writes the chunk's
failure part and manifest part under their temporary names (``.NAME.tmp-<pid>``, synced, not
renamed). What travels back to the driver is a :class:`ChunkResult`: one :class:`Outcome`
per label (its manifest row with the member locations, or its failure row; a few KB a
sample at most), the shards' names and sizes, the staged parts' names, and timings. The driver
commits the chunks in order (``pipeline.builder.commit``): it renames the failure part, then the
manifest part (the chunk's commit marker) into place. A killed build leaves temporary names
and shards of uncommitted chunks, which the next build removes or writes again.

Duplicate sample keys (two labels with one product id): the first label in label order
keeps the key, every later one becomes a ``record`` failure row (DuplicateKeyError naming
the first). A worker resolves the duplicates inside its chunk: it writes the first and
reports the later ones as ``duplicate`` outcomes. Duplicates of an earlier chunk's key are
resolved by the driver at commit, which knows every earlier key (``pipeline.builder.commit``):
it turns them into failure rows, writes the chunk's parts itself, and, when such a sample was
written into a shard, rewrites the chunk's shards without it (a rare path, the only one where sample
bytes pass through the driver).
The output is therefore byte-identical to a build that wrote every chunk in the driver, for
any engine and worker count. Samples in the split buffer are dropped by the worker when the
config says so (``splits.buffer_policy: drop``) and reported as ``dropped`` outcomes.

The workers need write access to the output folder, at the same path as the driver (a
shared file system for a cluster), or to the same object storage (``output.dir`` an fsspec
URL: ``store.fs``). On object storage a worker writes the chunk's shard and parts into a
local temporary folder exactly as above, then uploads the shard under its final name and
the parts under their temporary names, each object whole (it appears only when its upload
completes: a worker killed mid-upload leaves nothing under the name); the driver's commit
copies the parts to their final names on the server, the manifest part last.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import pyarrow as pa

from mars_pairs.errors import DuplicateKeyError, WorkerStartError
from mars_pairs.pipeline.builder import worker
from mars_pairs.pipeline.builder.layout import DROPPED_KEY, part_paths, shard_name
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.store import fs
from mars_pairs.store.atomic import write_parquet_staged
from mars_pairs.store.manifest import (
    FAILURE_SCHEMA,
    manifest_schema,
    rows_to_table,
    with_locations,
)
from mars_pairs.store.members import member_fields
from mars_pairs.store.shards import MemberLocation, ShardWriter
from mars_pairs.store.splits import BUFFER


@dataclass(frozen=True)
class ChunkTask:
    """Chunk ``index`` of the build: its labels, in label order. ``job``: what a worker runs
    for the chunk instead of building samples (a module-level function, so it pickles by
    name: the footprint catalogue's ``pipeline.catalog.chunk.catalog_chunk``); None: the
    build's samples."""

    index: int
    labels: tuple[str, ...]
    job: Callable[[BuildConfig, ChunkTask], ChunkResult] | None = None


@dataclass(frozen=True)
class Outcome:
    """What became of one label of a chunk.

    ``kind``: ``ok`` (written to the shard; ``row`` is its manifest row with the member
    locations, ``members`` the member name -> location), ``dropped`` (in the split buffer,
    not written), ``duplicate`` (its key was already built from an earlier label, not
    written; ``row`` is its DuplicateKeyError failure row), ``fail`` (``row`` is its failure
    row). ``key`` is the sample key (None for
    a failure), ``label`` the label path as the manifest names it, ``seconds`` the sample's
    stage times (s).
    """

    kind: Literal["ok", "dropped", "duplicate", "fail"]
    label: str
    key: str | None = None
    row: dict[str, Any] = field(default_factory=dict)
    members: dict[str, MemberLocation] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ChunkResult:
    """A chunk built by a worker: its outcomes in label order, and the shards it wrote.

    ``shards``: (path relative to the output folder, final size in bytes) of each shard it
    wrote (one per split among its samples, sorted by path; none when no sample was
    written). ``seconds``: the
    worker's wall time for the chunk; ``worker``: ``host:pid`` of the process that built it.
    ``staged``: the temporary names (relative to the output folder) under which the worker
    wrote the chunk's failure part and manifest part as they are when no earlier chunk
    built one of its keys (``part_tables``); committing the chunk renames them into place.
    None: the driver writes the parts.
    """

    index: int
    outcomes: tuple[Outcome, ...]
    shards: tuple[tuple[str, int], ...]
    seconds: float
    worker: str
    staged: tuple[str, str] | None = None

    @property
    def rows(self) -> list[dict[str, Any]]:
        """The manifest rows of the samples written, in label order."""
        return [o.row for o in self.outcomes if o.kind == "ok"]


class Engine(Protocol):
    """Runs :func:`build_chunk` for each chunk and yields the results in chunk order.

    ``chunks`` may be a lazy iterator: an engine pulls it as it has room (never lists it)
    and starts nothing when it is empty. WorkerStartError when a worker could not open the
    build's inputs."""

    def run(self, config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        """The results of ``chunks``, in their order."""
        ...


def duplicate_row(label: str, key: str, first: str) -> dict[str, Any]:
    """The failure row of ``label``, whose sample key ``key`` was built from ``first``."""
    error = DuplicateKeyError(f"{label}: key {key}: already built from {first}")
    return worker.failure_row(label, "record", error)


def part_tables(config: BuildConfig, outcomes: Iterable[Outcome]) -> tuple[pa.Table, pa.Table]:
    """A chunk's failure part and manifest part (of the schema of ``config``'s members; the
    count of samples dropped in the split buffer in its metadata) for its ``outcomes``, in
    label order."""
    outcomes = list(outcomes)
    failures = [o.row for o in outcomes if o.kind in ("fail", "duplicate")]
    rows = [o.row for o in outcomes if o.kind == "ok"]
    dropped = sum(o.kind == "dropped" for o in outcomes)
    table = rows_to_table(rows, build_schema(config))
    table = table.replace_schema_metadata({DROPPED_KEY: str(dropped).encode()})
    return rows_to_table(failures, FAILURE_SCHEMA), table


def build_schema(config: BuildConfig) -> pa.Schema:
    """The manifest schema of ``config``'s build: its optional members' location columns, and
    with terrain labels their members and per-class pixel counts."""
    fields = member_fields(config.output.members)
    spec = config.inputs.terrain_labels
    if spec is None:
        return manifest_schema(fields)
    from mars_pairs.pipeline.sample.terrain import label_table
    from mars_pairs.store.members import TERRAIN_FIELDS
    from mars_pairs.terrain_labels import count_columns

    return manifest_schema((*fields, *TERRAIN_FIELDS), count_columns(label_table(spec)))


def build_chunk(config: BuildConfig, task: ChunkTask) -> ChunkResult:
    """Build chunk ``task`` in this process (its context open: ``worker.open_context``) and
    write its shard into ``config.output.dir``; WorkerStartError when the context could not
    be opened. A sample is written as soon as it is built (one sample in memory). On object
    storage the chunk is written to a local temporary folder, then uploaded (``_upload``).
    A task with a ``job`` runs that instead, in the same context."""
    if task.job is not None:
        return task.job(config, task)
    if not isinstance(config.output.dir, Path):
        with fs.local_staging() as staging:
            return _upload(config.output.dir, staging, _build_chunk(config, task, staging))
    return _build_chunk(config, task, config.output.dir)


def _upload(out: str, staging: Path, result: ChunkResult) -> ChunkResult:
    """Upload the files of ``result``, written under ``staging``, to the same names under the
    URL ``out``, each whole: the shard, then the staged failure part and manifest part."""
    for rel in (*(rel for rel, _ in result.shards), *(result.staged or ())):
        fs.upload(staging / rel, fs.join(out, rel))
    return result


def _build_chunk(config: BuildConfig, task: ChunkTask, out: Path) -> ChunkResult:
    """``build_chunk`` with the chunk's files written into the local folder ``out``."""
    start = time.perf_counter()
    drop = config.splits.buffer_policy == "drop"
    outcomes: list[Outcome] = []
    first: dict[str, str] = {}
    shards: dict[str, ShardWriter] = {}  # split -> its shard, opened at its first sample
    try:
        for label in task.labels:
            status, r = worker.work(label)
            if status == "start":
                raise WorkerStartError(r)
            if status == "fail":
                outcomes.append(Outcome("fail", r["path"], row=r))
                continue
            name = r.row["label_path"]
            if r.key in first:
                row = duplicate_row(name, r.key, first[r.key])
                outcomes.append(Outcome("duplicate", name, r.key, row))
                continue
            first[r.key] = name
            if drop and r.row["split"] == BUFFER:
                outcomes.append(Outcome("dropped", name, r.key))
                continue
            split = str(r.row["split"])
            if split not in shards:
                shards[split] = ShardWriter(out, shard_name(task.index, split))
            locs = shards[split].add(r.key, r.members)
            outcomes.append(
                Outcome("ok", name, r.key, with_locations(r.row, locs), locs, r.seconds)
            )
    except BaseException:
        for shard in shards.values():
            shard.close(commit=False)
        raise
    written = []
    try:
        for split in sorted(shards):
            shard = shards.pop(split)
            shard.close()
            written.append((shard.relpath, shard.path.stat().st_size))
    finally:  # a failed close: the rest are not committed (a shard of an uncommitted chunk)
        for shard in shards.values():
            shard.close(commit=False)
    _, manifest_part, failures_part = part_paths(out, task.index)
    failures, manifest = part_tables(config, outcomes)
    staged = (
        write_parquet_staged(failures, failures_part).relative_to(out).as_posix(),
        write_parquet_staged(manifest, manifest_part).relative_to(out).as_posix(),
    )
    return ChunkResult(
        task.index,
        tuple(outcomes),
        tuple(sorted(written)),
        time.perf_counter() - start,
        f"{socket.gethostname()}:{os.getpid()}",
        staged,
    )


class InProcess:
    """The engine of a one-worker build: every chunk built in this process, in order."""

    def run(self, config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        """The results of ``chunks`` built here; the context opens at the first chunk."""
        todo = iter(chunks)
        first = next(todo, None)
        if first is None:
            return
        context = SampleContext.open(config)  # its error is the build's, as it is
        worker.use_context(context)
        try:
            yield build_chunk(config, first)
            for task in todo:
                yield build_chunk(config, task)
        finally:
            worker.use_context(None)
            context.close()
