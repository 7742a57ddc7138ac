"""The dataset build: labels -> samples -> shards + manifest, parallel, atomic and resumable.

Labels are streamed in one total order (``pipeline.build.label_list``) and cut into chunks of
``shard_size`` (``pipeline.build.plan``); chunk k becomes
``shards/shard-{k:06d}.tar`` plus ``parts/manifest-{k:06d}.parquet`` and
``parts/failures-{k:06d}.parquet``. The manifest part is renamed into place last and marks the
chunk done, so a killed build rerun with ``resume`` redoes only unfinished chunks, and the
output is the same whatever the worker count. A finished build writes the folder's card
(``pipeline.build.finish``) and removes ``parts/`` last (``output.keep_parts`` keeps it); its stamp
lives on in dataset.json, so ``--resume`` over it does nothing. The labels are never held: a
planning pass counts them and sums their fingerprint (the stamp), the build pass streams them
again to the engine, chunk by chunk. The engine's workers write the shards and stage the parts
(``pipeline.build.engine``); the driver receives rows only, and commits the chunks in order
(``pipeline.build.commit``).
"""

from __future__ import annotations

import contextlib
import json
import time
from collections import Counter
from pathlib import Path

from tqdm import tqdm

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.build.commit import select_chunk, write_chunk
from mars_pairs.pipeline.build.engine import ChunkTask, Engine, InProcess
from mars_pairs.pipeline.build.finish import (
    BuildSummary,
    finished_summary,
    merge_parts,
    write_card,
    write_dataset_json,
)
from mars_pairs.pipeline.build.local_pool import LocalPool
from mars_pairs.pipeline.build.outputs import (
    LabelDigest,
    built_keys,
    clear_outputs,
    dropped_count,
    remove_parts,
    remove_temporaries,
    stamp_path,
)
from mars_pairs.pipeline.build.plan import (
    check_clearable,
    chunks_of,
    done_chunks,
    labels_of,
    plan_build,
)
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.config_section import check_regular
from mars_pairs.store import fs
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
) -> BuildSummary:
    """Build the dataset described by ``config`` into ``config.output.dir``.

    ``engine``: None for this machine's process pool of ``workers`` (this process when 1),
    or another :class:`~mars_pairs.pipeline.build.engine.Engine` (``dask_engine.DaskEngine``).
    """
    start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: expected an integer >= 1, got {workers!r}")
    check_input_files(config)  # before any process opens them
    if not resume:  # refused before any worker starts (resume: once the stamp is read)
        check_clearable(config.output.dir)
    # the workers start now: their imports and raster opening overlap the planning
    pool = LocalPool(config, workers) if engine is None and workers > 1 else None
    if engine is None:
        engine = pool if pool is not None else InProcess()
    with pool if pool is not None else contextlib.nullcontext():
        return _run(config, start, resume, limit, strict, progress, engine)


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
    seen = built_keys(out, sorted(done))
    digest = LabelDigest()  # the second pass must list what the first did
    chunks = enumerate(chunks_of(digest.tally(labels_of(config, limit)), plan.chunk_size))
    todo = (ChunkTask(k, tuple(labels)) for k, labels in chunks if k not in done)
    results = engine.run(config, todo)
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
    remove_temporaries(out)  # of a worker killed mid-shard, whose chunk was built again
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
