"""Committing a built chunk: a pure selection step, then one write step.

:func:`select_chunk` decides, from the chunk's result, the keys earlier chunks built and
``--strict``, what the chunk commits (no I/O): a sample whose key an earlier chunk built
becomes a ``duplicate`` failure row (DuplicateKeyError naming the label that built it first),
samples dropped in the split buffer are counted, the committed samples' stage times summed,
and a strict build stops at the chunk's first failure row. :func:`write_chunk` then makes it
so in the output folder: it renames the parts the worker staged into place (the failure part,
then the manifest part: the chunk's commit marker) or, when duplicates changed the chunk,
writes the chunk's shards again without them and writes the parts itself. On object storage
(``output.dir`` a URL: ``store.fs``) a rename is a server-side copy and a delete (the copy
appears whole), and a shard rewritten is downloaded, written again locally and uploaded
whole.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from mars_pairs.errors import BuildError, MarsPairsError
from mars_pairs.pipeline.builder.engine import ChunkResult, Outcome, duplicate_row, part_tables
from mars_pairs.pipeline.builder.layout import part_paths
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store import fs
from mars_pairs.store.atomic import rename_into_place
from mars_pairs.store.manifest import with_locations
from mars_pairs.store.shards import ShardWriter, read_members

#: The failure row's columns a strict build's error names, in order.
_STOP_COLUMNS = ("path", "stage", "error_type", "message")


@dataclass(frozen=True)
class ChunkSelection:
    """What committing one chunk keeps (:func:`select_chunk`).

    ``outcomes``: the chunk's outcomes in label order, each sample whose key an earlier chunk
    built turned into a ``duplicate`` outcome. ``committed``: the keys of the samples that go
    into the manifest (``ok``), in label order. ``failures``: the failure rows (``fail`` and
    ``duplicate``), in label order. ``dropped``: the keys of the samples dropped in the split
    buffer. ``built``: key -> label of the samples that own their key from this chunk on
    (committed and dropped). ``stage_seconds``: the committed samples' stage times summed
    (stage -> seconds). ``stop``: for a strict build with a failure row, the first one
    (``path: stage: error_type: message``), else None. ``rewrite_shard``: a sample the worker
    wrote into a shard is now a duplicate (the shards must be written again without it).
    ``parts_staged``: the parts the worker staged are the chunk's (else the driver writes
    them).
    """

    outcomes: tuple[Outcome, ...]
    committed: tuple[str, ...]
    failures: tuple[dict[str, Any], ...]
    dropped: tuple[str, ...]
    built: dict[str, str]
    stage_seconds: dict[str, float]
    stop: str | None
    rewrite_shard: bool
    parts_staged: bool


def select_chunk(result: ChunkResult, seen: Mapping[str, str], strict: bool) -> ChunkSelection:
    """What committing ``result`` keeps, given ``seen`` (key -> the label an earlier chunk
    built it from) and ``strict``. Pure: reads and changes nothing else."""
    earlier = [o.kind != "fail" and o.key is not None and o.key in seen for o in result.outcomes]
    outcomes = tuple(
        Outcome("duplicate", o.label, o.key, duplicate_row(o.label, str(o.key), seen[str(o.key)]))
        if dup
        else o
        for o, dup in zip(result.outcomes, earlier, strict=True)
    )
    ok = [o for o in outcomes if o.kind == "ok"]
    failures = tuple(o.row for o in outcomes if o.kind in ("fail", "duplicate"))
    seconds: Counter[str] = Counter()
    for o in ok:
        seconds.update(o.seconds)
    stop = None
    if strict and failures:
        stop = ": ".join(str(failures[0][c]) for c in _STOP_COLUMNS)
    written = sum(o.kind == "ok" for o in result.outcomes)
    return ChunkSelection(
        outcomes=outcomes,
        committed=tuple(str(o.key) for o in ok),
        failures=failures,
        dropped=tuple(str(o.key) for o in outcomes if o.kind == "dropped"),
        built={str(o.key): o.label for o in outcomes if o.kind in ("ok", "dropped")},
        stage_seconds=dict(seconds),
        stop=stop,
        rewrite_shard=bool(result.shards) and len(ok) != written,
        parts_staged=result.staged is not None and not any(earlier),
    )


def write_chunk(config: BuildConfig, result: ChunkResult, selection: ChunkSelection) -> None:
    """Commit chunk ``result.index`` as ``selection`` says: its failure part, then its
    manifest part (the commit marker). MarsPairsError when a shard is not the size its
    worker reported; BuildError (the staged parts removed, nothing committed) when the
    selection stops a strict build."""
    out = config.output.dir
    _, manifest_part, failures_part = part_paths(out, result.index)
    for shard, written in result.shards:
        size = fs.size(fs.join(out, shard))
        if size != written:
            raise MarsPairsError(
                f"{fs.join(out, shard)}: {size} bytes, but its worker "
                f"({result.worker}) wrote {written}; rerun the build with --resume"
            )
    if selection.parts_staged and selection.stop is None:
        assert result.staged is not None
        if isinstance(out, Path):
            rename_into_place(out / result.staged[0], failures_part)
            rename_into_place(out / result.staged[1], manifest_part)  # commit marker
        else:  # copied on the server: the manifest part appears last
            fs.replace(fs.join(out, result.staged[0]), failures_part)
            fs.replace(fs.join(out, result.staged[1]), manifest_part)  # commit marker
        return
    for rel in result.staged or ():
        fs.remove(fs.join(out, rel))
    if selection.stop is not None:
        raise BuildError(selection.stop)
    outcomes = selection.outcomes
    if selection.rewrite_shard:
        if isinstance(out, Path):
            outcomes = _rewrite_shard(out, result, outcomes)
        else:
            outcomes = _rewrite_remote_shard(out, result, outcomes)
    failures, manifest = part_tables(config, outcomes)
    fs.write_parquet(failures, failures_part)
    fs.write_parquet(manifest, manifest_part)  # commit marker


def _rewrite_shard(
    out: Path, result: ChunkResult, outcomes: tuple[Outcome, ...]
) -> tuple[Outcome, ...]:
    """Write the shards of ``result`` again (each atomically, over the worker's) with the
    ``ok`` samples of ``outcomes`` only, read back from the worker's shards (checksums
    verified), and return ``outcomes`` with their new locations; a shard is removed when no
    sample is left in it."""
    kept = list(outcomes)
    for rel, _ in result.shards:
        shard: ShardWriter | None = None
        try:
            for i, o in enumerate(kept):
                if o.kind != "ok" or _shard_of(o) != rel:
                    continue
                members = read_members(out, o.members, key=str(o.key), verify=True)
                if shard is None:
                    shard = ShardWriter(out, rel)
                locs = shard.add(str(o.key), members)
                kept[i] = replace(o, row=with_locations(o.row, locs), members=locs)
        except BaseException:
            if shard is not None:
                shard.close(commit=False)
            raise
        if shard is None:
            (out / rel).unlink()
        else:
            shard.close()
    return tuple(kept)


def _shard_of(outcome: Outcome) -> str:
    """The shard holding the members of the written sample ``outcome`` (all in one)."""
    return next(iter(outcome.members.values())).shard


def _rewrite_remote_shard(
    out: str, result: ChunkResult, outcomes: tuple[Outcome, ...]
) -> tuple[Outcome, ...]:
    """``_rewrite_shard`` of shards on object storage under ``out``: downloaded into a local
    temporary folder, written again there, then uploaded whole (or removed)."""
    with fs.local_staging() as staging:
        for rel, _ in result.shards:
            local = staging / rel
            local.parent.mkdir(parents=True, exist_ok=True)
            local.write_bytes(fs.read_bytes(fs.join(out, rel)))
        kept = _rewrite_shard(staging, result, outcomes)
        for rel, _ in result.shards:
            if (staging / rel).exists():
                fs.upload(staging / rel, fs.join(out, rel))
            else:
                fs.remove(fs.join(out, rel))
    return kept
