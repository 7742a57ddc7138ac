"""The dataset build: labels -> samples -> shards + manifest, parallel, atomic and resumable.

Labels are streamed in one total order (``pipeline.builder.label_list``) and cut into chunks of
``shard_size`` (``pipeline.builder.plan``); chunk k becomes
``shards/shard-{k:06d}.tar`` plus ``parts/manifest-{k:06d}.parquet`` and
``parts/failures-{k:06d}.parquet``. The manifest part is renamed into place last and marks the
chunk done, so a killed build rerun with ``resume`` redoes only unfinished chunks, and the
output is the same whatever the worker count. A finished build writes the folder's card
(``pipeline.builder.finish``) and removes ``parts/`` last (``output.keep_parts`` keeps it); its
stamp lives on in dataset.json, so ``--resume`` over it does nothing. The labels are never held: a
planning pass counts them and sums their fingerprint (the stamp), the build pass streams them
again to the engine, chunk by chunk. The engine's workers write the shards and stage the parts
(``pipeline.builder.engine``); the driver receives rows only, and commits the chunks in order
(``pipeline.builder.commit``). ``append``: the labels a finished dataset does not hold yet become
chunks after its own, the same way, then the union is merged (``pipeline.builder.append``).
"""

from __future__ import annotations

import contextlib
import json
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import NoReturn

import pyarrow.parquet as pq
from tqdm import tqdm

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.append import (
    BASE_FILES,
    AppendPlan,
    dataset_extra,
    labels_done,
    local_dir,
    merge_append,
    new_chunks,
    new_labels,
    plan_append,
    remove_append_parts,
    remove_base,
    snapshot_base,
)
from mars_pairs.pipeline.builder.commit import select_chunk, write_chunk
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, Engine, InProcess
from mars_pairs.pipeline.builder.fingerprints import LabelDigest
from mars_pairs.pipeline.builder.finish import (
    BuildSummary,
    Merged,
    dataset_doc,
    failure_reasons,
    finished_summary,
    merge_parts,
    write_card,
    write_dataset_json,
    write_dataset_pairs,
)
from mars_pairs.pipeline.builder.hygiene import (
    clear_outputs,
    remove_parts,
    remove_temporaries,
)
from mars_pairs.pipeline.builder.key_index import KeyIndex, open_index, scratch_index
from mars_pairs.pipeline.builder.layout import dropped_count, stamp_path
from mars_pairs.pipeline.builder.local_pool import LocalPool
from mars_pairs.pipeline.builder.lock import folder_lock
from mars_pairs.pipeline.builder.plan import (
    check_clearable,
    chunks_of,
    done_chunks,
    is_done,
    labels_of,
    plan_build,
)
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.config_section import check_regular
from mars_pairs.store import fs
from mars_pairs.store.atomic import atomic_write_bytes
from mars_pairs.store.wids_index import write_wids_index


def check_input_files(config: BuildConfig) -> None:
    """ConfigError naming the key when an input path is a FIFO, a socket or a device (one
    would block the build for ever when opened; ``config_section.check_regular``)."""
    inputs = config.inputs
    for key in ("places", "dem", "ortho"):
        check_regular(getattr(inputs, key), f"inputs.{key}")
    if inputs.images is not None:
        check_regular(inputs.images, "inputs.images", folder=True)


def run_build(
    config: BuildConfig,
    *,
    workers: int = 1,
    resume: bool = False,
    limit: int | None = None,
    strict: bool = False,
    progress: bool = True,
    engine: Engine | None = None,
    append: bool = False,
) -> BuildSummary:
    """Build the dataset described by ``config`` into ``config.output.dir``.

    ``engine``: None for this machine's process pool of ``workers`` (this process when 1),
    or another :class:`~mars_pairs.pipeline.builder.engine.Engine` (``dask_engine.DaskEngine``).
    ``append``: add the labels the dataset in the folder does not hold yet as new chunks
    (``pipeline.builder.append``; an interrupted append of the same release is continued,
    with or without ``resume``).
    """
    start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: expected an integer >= 1, got {workers!r}")
    if append and limit is not None:
        raise ConfigError("--limit: not with --append (an append builds every new label)")
    check_input_files(config)  # before any process opens them
    with folder_lock(config.output.dir):  # one writer: before the folder is read or written
        if not isinstance(config.output.dir, Path):
            fs.remove_stale_staging()  # of a build killed mid-upload (or its key index)
        if not resume and not append:  # refused before any worker starts (else: once planned)
            check_clearable(config.output.dir)
        with contextlib.ExitStack() as stack:
            # an append's record of the dataset's keys and label paths, on disk: filled by
            # its plan, then by its commits
            seen = stack.enter_context(scratch_index()) if append else None
            if seen is not None:  # planned before any worker starts: a refused one starts none
                plan = plan_append(config, seen)
                if plan.labels_new == 0:
                    return _nothing_to_append(config, plan, start)
            # the workers start now: their imports and raster opening overlap the planning
            pool = LocalPool(config, workers) if engine is None and workers > 1 else None
            if engine is None:
                engine = pool if pool is not None else InProcess()
            with pool if pool is not None else contextlib.nullcontext():
                if seen is not None:
                    return _run_append(config, plan, seen, start, strict, progress, engine)
                return _run(config, start, resume, limit, strict, progress, engine)


def _commit_all(
    config: BuildConfig,
    results: Iterator[ChunkResult],
    bar: tqdm[NoReturn],  # a bar updated by hand (no iterable)
    strict: bool,
    stage_seconds: Counter[str],
    seen: KeyIndex,
) -> int:
    """Commit every chunk of ``results`` in order (``commit.select_chunk``, then
    ``commit.write_chunk``; ``seen``: key -> label of the samples built, on disk, updated), the bar
    following; closes the bar and the results. The number of chunks committed."""
    built = 0
    try:
        for result in results:
            bar.update(len(result.outcomes))
            selection = select_chunk(result, seen, strict)
            write_chunk(config, result, selection)
            seen.update(selection.built)
            stage_seconds.update(selection.stage_seconds)
            built += 1
    finally:
        bar.close()
        close = getattr(results, "close", None)
        if close:
            close()
    return built


def _run(
    config: BuildConfig,
    start: float,
    resume: bool,
    limit: int | None,
    strict: bool,
    progress: bool,
    engine: Engine,
) -> BuildSummary:
    """run_build's work, its arguments checked and its workers starting."""
    out = config.output.dir
    # checks (the inputs, the stamp, the folder's files); the labels' first pass
    plan = plan_build(config, resume=resume, limit=limit)
    if plan.finished:
        return finished_summary(config, plan, start)
    if isinstance(out, Path):
        out.mkdir(parents=True, exist_ok=True)
    remove_temporaries(out)  # of a killed build
    if plan.clears:
        clear_outputs(out)
    stamp = stamp_path(out)
    if isinstance(stamp, Path):
        stamp.parent.mkdir(parents=True, exist_ok=True)
    fs.put_bytes(stamp, json.dumps(plan.fingerprint).encode())
    done = done_chunks(out, plan.chunks)
    digest = LabelDigest()  # the second pass must list what the first did
    chunks = enumerate(chunks_of(digest.tally(labels_of(config, limit)), plan.chunk_size))
    todo = (ChunkTask(k, tuple(labels)) for k, labels in chunks if k not in done)
    stage_seconds: Counter[str] = Counter()
    with open_index(out) as seen:
        seen.add_parts(out, sorted(done))
        results = engine.run(config, todo)
        bar = tqdm(
            total=plan.labels,
            initial=plan.labels - plan.labels_to_build,
            unit="img",
            disable=not progress,
            desc="build",
        )
        built = _commit_all(config, results, bar, strict, stage_seconds, seen)
    remove_temporaries(out)  # of a worker killed mid-shard, whose chunk was built again
    listed = plan.fingerprint
    if (digest.count, digest.hexdigest()) != (listed["count"], listed["labels"]):
        raise ConfigError(
            f"inputs.labels: the matching files changed during the build ({listed['count']} "
            f"labels listed, then {digest.count}); rerun the build without --resume"
        )
    merged = merge_parts(config, plan.chunks)
    summary = _summary(out, merged, built, plan.chunks, start, stage_seconds)
    pairs = write_dataset_pairs(config, merged)
    doc = dataset_doc(
        config, summary, merged, dropped_count(out, plan.chunks), plan.fingerprint, pairs=pairs
    )
    write_wids_index(out, merged.shards)
    write_card(config, doc)
    write_dataset_json(config, doc)  # the record of the files above: after them
    if not config.output.keep_parts:
        remove_parts(out, plan.chunks)  # the last step: a kill before it resumes
    return summary


def _summary(
    out: fs.Location,
    merged: Merged,
    built: int,
    chunks: int,
    start: float,
    stage_seconds: Counter[str],
    appended: str | None = None,
) -> BuildSummary:
    """The summary of a build of ``chunks`` chunks, ``built`` of them in this run, whose
    merged files are ``merged``."""
    return BuildSummary(
        out_dir=out,
        samples=merged.samples,
        failures=merged.failures,
        failures_by_reason=merged.failures_by_reason,
        chunks_built=built,
        chunks_resumed=chunks - built,
        seconds=time.perf_counter() - start,
        stage_seconds=dict(stage_seconds),
        appended=appended,
    )


def _nothing_to_append(config: BuildConfig, plan: AppendPlan, start: float) -> BuildSummary:
    """The summary of an append that finds no new label: nothing is built or written (a base
    snapshot left by a killed append's last step is removed)."""
    out = local_dir(config)
    remove_base(out)
    failures, reasons = failure_reasons(out / "failures.parquet")
    return BuildSummary(
        out_dir=out,
        samples=pq.read_metadata(out / "manifest.parquet").num_rows,
        failures=failures,
        failures_by_reason=dict(reasons),
        chunks_built=0,
        chunks_resumed=0,
        seconds=time.perf_counter() - start,
        stage_seconds={},
        appended=plan.summary_line(),
    )


def _run_append(
    config: BuildConfig,
    plan: AppendPlan,
    seen: KeyIndex,
    start: float,
    strict: bool,
    progress: bool,
    engine: Engine,
) -> BuildSummary:
    """run_build's work for ``--append`` (``pipeline.builder.append``), planned, its workers
    starting: the base kept (``snapshot_base``) and the stamp written unless an interrupted
    append of this release is continued, the new chunks built and committed after the
    dataset's, then the union merged and described, and parts/ removed."""
    out = local_dir(config)
    remove_temporaries(out)  # of a killed build
    if not plan.resumed:
        snapshot_base(out)  # before the stamp: while the stamp is there, the base is whole
        atomic_write_bytes(stamp_path(out), json.dumps(plan.fingerprint).encode())
    chunks = new_chunks(plan)
    digest = LabelDigest()  # the second pass must list what the first did
    fresh = new_labels(config, seen.is_known, LabelDigest())
    listed = chunks_of(digest.tally(fresh), plan.chunk_size)
    todo = (
        ChunkTask(k, tuple(labels))
        for k, labels in zip(chunks, listed, strict=False)
        if not is_done(out, k)
    )
    stage_seconds: Counter[str] = Counter()
    seen.add_parts(out, (k for k in chunks if is_done(out, k)))  # the dataset's: by the plan
    results = engine.run(config, todo)
    bar = tqdm(
        total=plan.labels_new,
        initial=labels_done(plan),
        unit="img",
        disable=not progress,
        desc="append",
    )
    built = _commit_all(config, results, bar, strict, stage_seconds, seen)
    remove_temporaries(out)
    stamp = plan.fingerprint
    if (digest.count, digest.hexdigest()) != (stamp["count"], stamp["labels"]):
        raise ConfigError(
            f"inputs.labels: the matching files changed during the append ({stamp['count']} "
            f"new labels listed, then {digest.count}); rerun the append"
        )
    merged, dropped = merge_append(config, plan)
    added = merged.samples - pq.read_metadata(out / BASE_FILES["manifest.parquet"]).num_rows
    base_failures = pq.read_metadata(out / BASE_FILES["failures.parquet"]).num_rows
    summary = _summary(out, merged, built, plan.chunks, start, stage_seconds, plan.summary_line())
    extra = dataset_extra(config, plan, added, merged.failures - base_failures)
    pairs = write_dataset_pairs(config, merged)
    doc = dataset_doc(config, summary, merged, dropped, extra=extra, pairs=pairs)
    write_wids_index(out, merged.shards)
    write_card(config, doc)
    write_dataset_json(config, doc)  # the record of the files above: after them
    remove_append_parts(out, plan)  # the stamp before the base: see pipeline.builder.append
    return summary
