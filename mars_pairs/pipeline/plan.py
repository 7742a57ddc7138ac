"""Planning a build: check the inputs, list and chunk the labels, find the chunks done.

The labels are streamed (``pipeline.label_list``), never held: the plan is one pass that
counts them and sums their fingerprint; chunk k is labels ``[k*S, (k+1)*S)`` of that order
(S = ``output.shard_size``), so the chunk count and sizes follow from the count, and a chunk
is done when its manifest part exists (and the build stamp matches, for ``--resume``). The
driver's memory is flat in the number of labels (``benchmarks/bench_plan.py``). Planning
writes nothing: ``mars-pairs build --dry-run`` prints the plan and stops.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.outputs import (
    fingerprint,
    finished_stamp,
    part_paths,
    read_stamp,
    stamp_digest,
    stamp_path,
)
from mars_pairs.pipeline.splitting import split_rule


def check_inputs(config: BuildConfig) -> None:
    """Check that a label matches and every input opens; ConfigError names the key."""
    import rasterio

    if next(config.inputs.iter_label_paths(), None) is None:
        raise ConfigError(f"inputs.labels: no file matches {list(config.inputs.labels)}")
    if not config.inputs.places.is_file():
        raise ConfigError(f"inputs.places: no such file {config.inputs.places}")
    for key in ("dem", "ortho"):
        path = getattr(config.inputs, key)
        try:
            with rasterio.open(path) as src:
                if src.crs is None:
                    raise ConfigError(f"inputs.{key}: {path} has no CRS")
        except rasterio.errors.RasterioIOError as exc:
            raise ConfigError(f"inputs.{key}: cannot open {path}: {exc}") from None
    with rasterio.open(config.inputs.dem) as src:  # a split config error stops it here
        split_rule(config, src.crs.to_wkt(), tuple(src.bounds), src.res)


def labels_of(config: BuildConfig, limit: int | None = None) -> Iterator[str]:
    """The build's labels in build order, streamed: the first ``limit`` (None: all)."""
    return islice(config.inputs.iter_label_paths(), limit)


def chunks_of(labels: Iterable[str], size: int) -> Iterator[list[str]]:
    """Chunk k: labels ``[k*size, (k+1)*size)`` of ``labels``, one list at a time."""
    it = iter(labels)
    while chunk := list(islice(it, size)):
        yield chunk


def check_limit(limit: int | None) -> None:
    """ConfigError unless ``limit`` is None or an integer >= 1 (``--limit``)."""
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise ConfigError(f"--limit: expected an integer >= 1, got {limit!r}")


@dataclass(frozen=True)
class BuildPlan:
    """What a build of a config would do: counts of labels and chunks, and what is done."""

    out_dir: Path
    labels: int  # after --limit
    chunk_size: int  # labels per chunk (output.shard_size); the last chunk may hold fewer
    chunks: int
    chunks_done: int  # finished chunks the build keeps (--resume with a matching stamp)
    labels_to_build: int  # labels of the chunks still to build: at most one sample each
    resume: bool  # --resume was asked for
    clears: bool  # the build clears the output folder first (no --resume, or no stamp)
    seconds: float  # planning wall time, s
    fingerprint: dict[str, Any] = field(repr=False, compare=False)  # the stamp it writes
    finished: bool = False  # --resume over a finished build of the same config: nothing to do

    def format(self) -> str:
        """The plan as ``mars-pairs build --dry-run`` prints it."""
        if not self.resume:
            done = "no --resume: the build clears the folder and starts afresh"
        elif self.finished:
            done = "--resume: the build in the folder is finished, nothing to do"
        elif self.clears:
            done = "--resume: no earlier build in the folder, the build starts afresh"
        else:
            done = "kept by --resume"
        todo = self.chunks - self.chunks_done
        return "\n".join(
            [
                f"dry run: nothing written to {self.out_dir}",
                f"labels: {self.labels}   planned in {self.seconds:.2f} s",
                f"chunks: {self.chunks} of up to {self.chunk_size} labels (output.shard_size)",
                f"chunks done: {self.chunks_done} ({done})",
                f"samples to build: {self.labels_to_build} (at most: one per label of the "
                f"{todo} chunks to build)",
            ]
        )


def plan_build(config: BuildConfig, *, resume: bool = False, limit: int | None = None) -> BuildPlan:
    """Check the config and inputs, list and chunk the labels, and find the chunks done;
    writes nothing. ConfigError as the build would raise it (a bad ``--limit``, no label,
    an input that does not open, a ``--resume`` over a build of another config or label
    list)."""
    start = time.perf_counter()
    check_limit(limit)
    check_inputs(config)
    stamp = fingerprint(config, labels_of(config, limit))
    n = stamp["count"]
    if n == 0:  # the files went between the check and the listing
        raise ConfigError(f"inputs.labels: no file matches {list(config.inputs.labels)}")
    out = config.output.dir
    previous = read_stamp(stamp_path(out))
    finished = finished_stamp(out) if previous is None else None  # parts/ removed
    if resume and (
        (previous is not None and previous != stamp)
        or (finished is not None and finished != stamp_digest(stamp))
    ):
        raise ConfigError(
            f"{out}: cannot resume: the config or the label list changed since the "
            "interrupted build; rerun without --resume"
        )
    is_finished = resume and finished is not None and (out / "manifest.parquet").is_file()
    clears = not resume or (previous is None and not is_finished)  # no stamp: no part trusted
    size = config.output.shard_size
    chunks = -(-n // size)
    done = labels_done = 0
    if is_finished:
        done, labels_done = chunks, n
    for k in range(0 if clears or is_finished else chunks):
        if is_done(out, k):
            done += 1
            labels_done += min(size, n - k * size)
    return BuildPlan(
        out_dir=out,
        labels=n,
        chunk_size=size,
        chunks=chunks,
        chunks_done=done,
        labels_to_build=n - labels_done,
        resume=resume,
        clears=clears,
        seconds=time.perf_counter() - start,
        fingerprint=stamp,
        finished=is_finished,
    )


def is_done(out: Path, k: int) -> bool:
    """Whether chunk k is finished: its manifest part (the chunk's commit marker) exists."""
    return part_paths(out, k)[1].exists()
