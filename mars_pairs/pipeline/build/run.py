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
(``pipeline.build.engine``); the driver receives rows only, and commits the chunks in order.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path

from tqdm import tqdm

from mars_pairs.errors import BuildError, ConfigError, MarsPairsError
from mars_pairs.pipeline.build.engine import (
    ChunkResult,
    ChunkTask,
    Engine,
    InProcess,
    part_tables,
    resolve_duplicates,
)
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
    part_paths,
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


def _in_process(config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
    """The results of ``chunks`` built in this process (one worker), in order."""
    return InProcess().run(config, chunks)


def _commit_chunk(
    config: BuildConfig,
    result: ChunkResult,
    strict: bool,
    stage_seconds: Counter[str],
    seen: dict[str, str],
) -> int:
    """Commit chunk ``result.index``, whose shard its worker wrote: its failure part, then its
    manifest part (the commit marker), renamed from where the worker staged them. A sample
    whose key an earlier chunk built (``seen``: key -> label, updated here) becomes a
    DuplicateKeyError failure row and leaves the shard, and the driver writes the parts
    (``engine.resolve_duplicates``). The number of samples committed."""
    out = config.output.dir
    _, manifest_part, failures_part = part_paths(out, result.index)
    if result.shard is not None:
        size = fs.size(fs.join(out, result.shard))
        if size != result.shard_bytes:
            raise MarsPairsError(
                f"{fs.join(out, result.shard)}: {size} bytes, but its worker "
                f"({result.worker}) wrote {result.shard_bytes}; rerun the build with --resume"
            )
    if result.staged is None or any(o.kind != "fail" and o.key in seen for o in result.outcomes):
        result = resolve_duplicates(out, result, seen)
    failed = next((o.row for o in result.outcomes if o.kind in ("fail", "duplicate")), None)
    if strict and failed is not None:
        for rel in result.staged or ():
            fs.remove(fs.join(out, rel))
        what = ": ".join(str(failed[c]) for c in ("path", "stage", "error_type", "message"))
        raise BuildError(what)
    if result.staged is None:
        failures, manifest = part_tables(config, result.outcomes)
        fs.write_parquet(failures, failures_part)
        fs.write_parquet(manifest, manifest_part)  # commit marker
    else:  # on object storage: copied on the server, the manifest part appears last
        fs.replace(fs.join(out, result.staged[0]), failures_part)
        fs.replace(fs.join(out, result.staged[1]), manifest_part)  # commit marker
    written = 0
    for o in result.outcomes:
        if o.kind in ("ok", "dropped"):
            seen[o.key] = o.label
        if o.kind == "ok":
            stage_seconds.update(o.seconds)
            written += 1
    return written


def _chunk_results(
    config: BuildConfig,
    todo: Iterator[tuple[int, list[str]]],
    pool: LocalPool | None,
    engine: Engine | None,
) -> Iterator[ChunkResult]:
    """The results of the chunks ``todo`` ((k, labels), streamed), in order, from the local
    pool, this process (pool and engine None) or ``engine``."""
    tasks = (ChunkTask(k, tuple(labels)) for k, labels in todo)
    if engine is not None:
        return engine.run(config, tasks)
    return pool.run(config, tasks) if pool is not None else _in_process(config, tasks)


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
    engine: Engine | None,
    pool: LocalPool | None,
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
    todo = ((k, labels) for k, labels in chunks if k not in done)
    results = _chunk_results(config, todo, pool, engine)
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
            _commit_chunk(config, result, strict, stage_seconds, seen)
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
