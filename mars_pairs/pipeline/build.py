"""The dataset build: labels -> samples -> shards + manifest, parallel, atomic and resumable.

Labels are streamed in one total order (``pipeline.label_list``) and cut into chunks of
``shard_size`` (``pipeline.plan``); chunk k becomes
``shards/shard-{k:06d}.tar`` plus ``parts/manifest-{k:06d}.parquet`` and
``parts/failures-{k:06d}.parquet``. The manifest part is renamed into place last and marks the
chunk done, so a killed build rerun with ``resume`` redoes only unfinished chunks, and the
output is the same whatever the worker count. A finished build writes the folder's card
(``pipeline.finish``) and removes ``parts/`` last (``output.keep_parts`` keeps it); its stamp
lives on in dataset.json, so ``--resume`` over it does nothing. The labels are never held: a
planning pass counts them and sums their fingerprint (the stamp), the build pass streams them
again to the engine, chunk by chunk.
"""

from __future__ import annotations

import json
import time
from collections import Counter, deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import Any

from tqdm import tqdm

from mars_pairs.errors import ConfigError, MarsPairsError
from mars_pairs.pipeline import worker
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.config_section import check_regular
from mars_pairs.pipeline.context import SampleContext
from mars_pairs.pipeline.dense import member_fields
from mars_pairs.pipeline.finish import (
    finished_summary,
    merge_parts,
    write_card,
    write_dataset_json,
)
from mars_pairs.pipeline.local_pool import LocalPool
from mars_pairs.pipeline.outputs import (
    DROPPED_KEY,
    LabelDigest,
    built_keys,
    clear_outputs,
    dropped_count,
    part_paths,
    remove_parts,
    remove_temporaries,
    stamp_path,
)
from mars_pairs.pipeline.plan import (
    check_clearable,
    chunks_of,
    is_done,
    labels_of,
    plan_build,
)
from mars_pairs.pipeline.worker import WorkerStartError  # noqa: F401  (re-exported)
from mars_pairs.store.manifest import (
    FAILURE_SCHEMA,
    manifest_schema,
    rows_to_table,
    write_parquet_atomic,
)
from mars_pairs.store.shards import ShardWriter, atomic_write_bytes
from mars_pairs.store.splits import BUFFER
from mars_pairs.store.wids_index import write_wids_index


@dataclass(frozen=True)
class BuildSummary:
    """Counts and timing of one build."""

    out_dir: Path
    samples: int
    failures: int
    failures_by_reason: dict[str, int]
    chunks_built: int
    chunks_resumed: int
    seconds: float
    stage_seconds: dict[str, float]  # summed over the samples built in this run

    def format(self) -> str:
        """A short human-readable summary."""
        rate = self.samples / self.seconds if self.seconds > 0 else float("nan")
        lines = [
            f"dataset: {self.out_dir}",
            f"samples: {self.samples}   failures: {self.failures}   "
            f"time: {self.seconds:.1f} s ({rate:.1f} samples/s)",
            f"chunks: {self.chunks_built} built, {self.chunks_resumed} resumed",
        ]
        lines += [
            f"  failed at {reason}: {n}" for reason, n in sorted(self.failures_by_reason.items())
        ]
        return "\n".join(lines)


class BuildError(MarsPairsError):
    """A strict build stopped at its first failure."""


def check_input_files(config: BuildConfig) -> None:
    """ConfigError naming the key when an input path is a FIFO, a socket or a device (one
    would block the build for ever when opened; ``config_section.check_regular``)."""
    inputs = config.inputs
    for key in ("places", "dem", "ortho"):
        check_regular(getattr(inputs, key), f"inputs.{key}")
    if inputs.images is not None:
        check_regular(inputs.images, "inputs.images", folder=True)


def _in_process(config: BuildConfig, labels: Iterable[str]) -> Iterator[tuple[str, Any]]:
    """Results in label order, built in this process (one worker)."""
    context = SampleContext.open(config)  # its error is the build's, as it is
    worker.use_context(context)
    try:
        yield from map(worker.work, labels)
    finally:
        worker.use_context(None)
        context.close()


class DuplicateKeyError(MarsPairsError):
    """Two labels give the same sample key (the same product id): the first one is kept."""


def _write_chunk(
    config: BuildConfig,
    k: int,
    results: list[tuple[str, Any]],
    strict: bool,
    stage_seconds: Counter[str],
    seen: dict[str, str],
) -> int:
    """Write chunk k's shard and parts; samples in the split buffer are dropped when the
    config says so (their count goes in the manifest part's metadata)."""
    out = config.output.dir
    shard_rel, manifest_part, failures_part = part_paths(out, k)
    rows, failures = [], []
    samples = []
    for i, (status, r) in enumerate(results):
        if status != "ok":
            continue
        label = r.row["label_path"]
        if r.key in seen:
            error = DuplicateKeyError(f"{label}: key {r.key}: already built from {seen[r.key]}")
            results[i] = ("fail", worker.failure_row(label, "record", error))
            continue
        seen[r.key] = label
        samples.append(r)
    dropped = 0
    if config.splits.buffer_policy == "drop":
        kept = [s for s in samples if s.row["split"] != BUFFER]
        dropped, samples = len(samples) - len(kept), kept
    for sample in samples:
        stage_seconds.update(sample.seconds)
    for status, r in results:
        if status == "fail":
            if strict:
                raise BuildError(f"{r['path']}: {r['stage']}: {r['error_type']}: {r['message']}")
            failures.append(r)
    if samples:
        with ShardWriter(out, shard_rel) as shard:
            for sample in samples:
                locs = shard.add(sample.key, sample.members)
                row = dict(sample.row)
                for name, loc in locs.items():
                    fld = name.split(".")[0]
                    row.update(
                        {
                            f"{fld}_shard": loc.shard,
                            f"{fld}_offset": loc.offset,
                            f"{fld}_size": loc.size,
                            f"{fld}_crc32c": loc.crc32c,
                        }
                    )
                rows.append(row)
    write_parquet_atomic(rows_to_table(failures, FAILURE_SCHEMA), failures_part)
    table = rows_to_table(rows, manifest_schema(member_fields(config.output.members)))
    table = table.replace_schema_metadata({DROPPED_KEY: str(dropped).encode()})
    write_parquet_atomic(table, manifest_part)  # commit marker
    return len(samples)


def _chunk_results(
    config: BuildConfig,
    todo: Iterator[tuple[int, list[str]]],
    handed: deque[tuple[int, int]],
    pool: LocalPool | None,
    engine: Any,
) -> Iterator[tuple[str, Any]]:
    """Every result of the chunks ``todo`` ((k, labels), streamed), in order, from the local
    pool (this process when None) or ``engine``; each chunk's (k, length) goes into
    ``handed`` as the engine takes it, before any of its results. No cluster starts when
    there is nothing to build."""
    first = next(todo, None)
    if first is None:
        return iter(())

    def taken() -> Iterator[list[str]]:
        for k, labels in chain([first], todo):
            handed.append((k, len(labels)))
            yield labels

    if engine is None:
        labels = chain.from_iterable(taken())
        return pool.results(labels) if pool is not None else _in_process(config, labels)
    return engine.results(config, taken())  # one task per chunk, results in label order


def run_build(
    config: BuildConfig,
    *,
    workers: int = 1,
    resume: bool = False,
    limit: int | None = None,
    strict: bool = False,
    progress: bool = True,
    engine: Any = None,
) -> BuildSummary:
    """Build the dataset described by ``config`` into ``config.output.dir``.

    ``engine``: None for this machine's process pool of ``workers``, or an engine with a
    ``results(config, chunks)`` method (``pipeline.dask_engine.DaskEngine``).
    """
    start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: expected an integer >= 1, got {workers!r}")
    check_input_files(config)  # before any process opens them
    if not resume:  # refused before any worker starts (resume: once the stamp is read)
        check_clearable(config.output.dir)
    # the workers start now: their imports and raster opening overlap the planning
    pool = LocalPool(config, workers) if engine is None and workers > 1 else None
    if pool is None:
        return _run(config, start, resume, limit, strict, progress, engine, pool)
    with pool:
        return _run(config, start, resume, limit, strict, progress, engine, pool)


def _run(
    config: BuildConfig,
    start: float,
    resume: bool,
    limit: int | None,
    strict: bool,
    progress: bool,
    engine: Any,
    pool: LocalPool | None,
) -> BuildSummary:
    """run_build's work, its arguments checked and its workers starting."""
    out = config.output.dir
    # checks (the inputs, the stamp, the folder's files); the labels' first pass
    plan = plan_build(config, resume=resume, limit=limit)
    if plan.finished:
        return finished_summary(config, plan, start)
    out.mkdir(parents=True, exist_ok=True)
    remove_temporaries(out)  # of a killed build
    if plan.clears:
        clear_outputs(out)
    stamp = stamp_path(out)
    stamp.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(stamp, json.dumps(plan.fingerprint).encode())
    seen = built_keys(out, (k for k in range(plan.chunks) if is_done(out, k)))
    digest = LabelDigest()  # the second pass must list what the first did
    chunks = enumerate(chunks_of(digest.tally(labels_of(config, limit)), plan.chunk_size))
    handed: deque[tuple[int, int]] = deque()
    todo = ((k, labels) for k, labels in chunks if not is_done(out, k))
    results = _chunk_results(config, todo, handed, pool, engine)
    bar = tqdm(
        total=plan.labels,
        initial=plan.labels - plan.labels_to_build,
        unit="img",
        disable=not progress,
        desc="build",
    )
    stage_seconds: Counter[str] = Counter()
    built = 0
    try:
        for first in results:
            k, length = handed.popleft()
            batch = [first]
            bar.update(1)
            for _ in range(length - 1):
                batch.append(next(results))
                bar.update(1)
            _write_chunk(config, k, batch, strict, stage_seconds, seen)
            built += 1
    finally:
        bar.close()
        close = getattr(results, "close", None)
        if close:
            close()
    listed = plan.fingerprint
    if (digest.count, digest.hexdigest()) != (listed["count"], listed["labels"]):
        raise ConfigError(
            f"inputs.labels: the matching files changed during the build ({listed['count']} "
            f"labels listed, then {digest.count}); rerun the build without --resume"
        )
    manifest, failures = merge_parts(config, plan.chunks)
    summary = BuildSummary(
        out_dir=out,
        samples=manifest.num_rows,
        failures=failures.num_rows,
        failures_by_reason=dict(
            Counter(
                f"{s} ({e})"
                for s, e in zip(
                    failures.column("stage").to_pylist(),
                    failures.column("error_type").to_pylist(),
                    strict=False,
                )
            )
        ),
        chunks_built=built,
        chunks_resumed=plan.chunks - built,
        seconds=time.perf_counter() - start,
        stage_seconds=dict(stage_seconds),
    )
    doc = write_dataset_json(
        config, summary, manifest, dropped_count(out, plan.chunks), plan.fingerprint
    )
    write_wids_index(out, manifest)
    write_card(config, manifest, doc)
    if not config.output.keep_parts:
        remove_parts(out, plan.chunks)  # the last step: a kill before it resumes
    return summary
