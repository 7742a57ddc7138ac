"""Planning a build: check the inputs, list and chunk the labels, find the chunks done.

The labels are streamed (``pipeline.builder.label_list``), never held: the plan is one pass that
counts them and sums their fingerprint; chunk k is labels ``[k*S, (k+1)*S)`` of that order
(S = ``output.shard_size``), so the chunk count and sizes follow from the count, and a chunk
is done when its manifest part exists (and the build stamp matches, for ``--resume``: the
config, the label list and the other inputs' files). The driver's memory is flat in the
number of labels (``benchmarks/bench_plan.py``). Planning writes nothing: ``mars-pairs build
--dry-run`` prints the plan and stops (a synthetic mission still to generate is planned from
its preset, ``generate``).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError, TerrainError
from mars_pairs.pipeline.builder.hygiene import foreign_file
from mars_pairs.pipeline.builder.label_list import iter_matches
from mars_pairs.pipeline.builder.layout import part_paths, stamp_path, written_by
from mars_pairs.pipeline.builder.stamp import (
    fingerprint,
    finished_stamp,
    read_stamp,
    stamp_difference,
    stamp_digest,
    stamped_chunks,
)
from mars_pairs.pipeline.config import BuildConfig, SyntheticSpec
from mars_pairs.pipeline.splitting import split_rule
from mars_pairs.raster.terrain import Terrain
from mars_pairs.raster.vsi import open_raster
from mars_pairs.store import fs


def fetch_hint(config: BuildConfig) -> str:
    """What to run when the inputs of a real-data config are not there yet: its archive
    files are fetched by ``mars-pairs fetch all`` with the same config."""
    if config.inputs.synthetic is not None:
        return ""
    name = config.source if config.source is not None else "CONFIG"
    return f" (not fetched yet? run: mars-pairs fetch all --config {name})"


def check_inputs(config: BuildConfig) -> None:
    """Check that a label matches and every input opens; ConfigError names the key."""
    import rasterio

    if next(iter_matches(config.inputs.labels), None) is None:
        raise ConfigError(
            f"inputs.labels: no file matches {list(config.inputs.labels)}{fetch_hint(config)}"
        )
    if not config.inputs.places.is_file():
        raise ConfigError(f"inputs.places: no such file {config.inputs.places}{fetch_hint(config)}")
    for key in ("dem", "ortho"):
        path = getattr(config.inputs, key)
        try:
            with open_raster(path) as src:
                if src.crs is None:
                    raise ConfigError(f"inputs.{key}: {path} has no CRS")
        except rasterio.errors.RasterioIOError as exc:
            raise ConfigError(f"inputs.{key}: cannot open {path}: {exc}") from None
    try:  # the checks every worker's Terrain makes, once, before any work
        Terrain.open(config.inputs.dem, config.inputs.ortho).close()
    except TerrainError as exc:
        key = "ortho" if str(exc).startswith(str(config.inputs.ortho)) else "dem"
        raise ConfigError(f"inputs.{key}: {exc}") from None
    with open_raster(config.inputs.dem) as src:  # a split config error stops it here
        split_rule(config, src.crs.to_wkt(), tuple(src.bounds), src.res)


def check_clearable(out: fs.Location, *, resume: bool = False) -> None:
    """ConfigError unless a build may clear (``resume``: resume in) ``out``: absent, empty, or
    holding only what an earlier mars-pairs build wrote there, as its stamp lists
    (``hygiene.foreign_file``). A folder holding anything else is refused whole: nothing in
    it is removed or overwritten."""
    foreign = foreign_file(out)
    if foreign is not None:
        what = "resume in" if resume else "clear"
        why = (
            "which does not read as the file a mars-pairs build writes there"
            if written_by(stamped_chunks(out), foreign)
            else "which no mars-pairs build stamp there lists"
        )
        raise ConfigError(
            f"output.dir: {out} holds {foreign}, {why}; "
            f"refusing to {what} the folder (nothing was removed): build into a new or empty "
            "folder (--out), or remove what is not the dataset's"
        )


def mission_pending(config: BuildConfig) -> SyntheticSpec | None:
    """The config's synthetic mission when the build would generate it first (its DEM, its
    PLACES table or every label absent); None otherwise."""
    spec, inputs = config.inputs.synthetic, config.inputs
    if spec is None:
        return None
    dem_there = not isinstance(inputs.dem, Path) or inputs.dem.exists()
    if dem_there and inputs.places.exists() and next(iter_matches(inputs.labels), None):
        return None
    return spec


def labels_of(config: BuildConfig, limit: int | None = None) -> Iterator[str]:
    """The build's labels in build order, streamed: the first ``limit`` (None: all)."""
    return islice(iter_matches(config.inputs.labels), limit)


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

    out_dir: Path | str  # a local folder or an fsspec URL (store.fs)
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
    mission: SyntheticSpec | None = None  # the synthetic mission generated first (labels: its)

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
        generated = []
        if self.mission is not None:
            m = self.mission
            generated = [
                f"inputs.synthetic: the {m.mission} mission is absent: the build generates it "
                f"at {m.root} first (size {m.size}: {m.stops} stops x {m.images_per_stop} "
                f"images = {m.stops * m.images_per_stop} labels)"
            ]
        return "\n".join(
            [
                f"dry run: nothing written to {self.out_dir}",
                *generated,
                f"labels: {self.labels}   planned in {self.seconds:.2f} s",
                f"chunks: {self.chunks} of up to {self.chunk_size} labels (output.shard_size)",
                f"chunks done: {self.chunks_done} ({done})",
                f"samples to build: {self.labels_to_build} (at most: one per label of the "
                f"{todo} chunks to build)",
            ]
        )


def plan_build(
    config: BuildConfig,
    *,
    resume: bool = False,
    limit: int | None = None,
    generate: bool = False,
) -> BuildPlan:
    """Check the config, inputs and output folder, list and chunk the labels, and find the
    chunks done; writes nothing. ConfigError as the build would raise it (a bad ``--limit``,
    no label, an input that does not open, a ``--resume`` over a build of another config,
    label list or input file, an output folder holding files no build stamp there lists).

    ``generate``: a synthetic mission still to generate (``mission_pending``) is planned
    from its preset (stops x images labels) instead of refused; the inputs it generates are
    not checked (those outside its root must exist) and its plan has no fingerprint
    (``mars-pairs build --dry-run``)."""
    start = time.perf_counter()
    check_limit(limit)
    out = config.output.dir
    previous = read_stamp(stamp_path(out))
    pending = mission_pending(config) if generate else None
    finished = None
    if pending is not None:
        if resume and previous is not None:
            raise ConfigError(
                f"{out}: cannot resume: the synthetic mission at {pending.root} is absent and "
                "the build generates it anew; rerun without --resume"
            )
        for key in ("places", "dem", "ortho"):  # the inputs the generation does not write
            path = getattr(config.inputs, key)
            outside = isinstance(path, Path) and not path.is_relative_to(pending.root)
            if outside and not path.exists():
                raise ConfigError(
                    f"inputs.{key}: no such file {path} (outside inputs.synthetic.root "
                    f"{pending.root}: not generated)"
                )
        stamp: dict[str, Any] = {}
        n = pending.stops * pending.images_per_stop
        n = n if limit is None else min(n, limit)
    else:
        check_inputs(config)
        stamp = fingerprint(config, labels_of(config, limit))
        n = stamp["count"]
        if n == 0:  # the files went between the check and the listing
            raise ConfigError(
                f"inputs.labels: no file matches {list(config.inputs.labels)}{fetch_hint(config)}"
            )
        if resume and previous is not None and "append" in previous:
            raise ConfigError(
                f"{out}: cannot resume: the folder holds an interrupted --append; rerun it "
                "with --append (and the config of the release it appends)"
            )
        why = stamp_difference(previous, stamp) if resume and previous is not None else None
        if why is not None:
            raise ConfigError(f"{out}: cannot resume: {why}; rerun without --resume")
        finished = finished_stamp(out) if previous is None else None  # parts/ removed
        # (an appended dataset's build_stamp also counts its chunks: the digest decides)
        same = finished is not None and finished.get("sha256") == stamp_digest(stamp)["sha256"]
        if resume and finished is not None and not same:
            raise ConfigError(
                f"{out}: cannot resume: the config, the label list or an input file changed "
                "since the finished build; rerun without --resume"
            )
    is_finished = resume and finished is not None and fs.is_file(fs.join(out, "manifest.parquet"))
    clears = not resume or (previous is None and not is_finished)  # no stamp: no part trusted
    check_clearable(out, resume=not clears)  # a stranger's file is never touched
    size = config.output.shard_size
    chunks = -(-n // size)
    done = labels_done = 0
    if is_finished:
        done, labels_done = chunks, n
    for k in sorted(done_chunks(out, 0 if clears or is_finished else chunks)):
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
        mission=pending,
    )


def is_done(out: fs.Location, k: int) -> bool:
    """Whether chunk k is finished: its manifest part (the chunk's commit marker) exists."""
    return fs.exists(part_paths(out, k)[1])


def done_chunks(out: fs.Location, chunks: int) -> set[int]:
    """The finished chunks among the first ``chunks`` (``is_done``); on object storage from
    one listing of ``parts/``, not a request a chunk."""
    if isinstance(out, Path) or chunks == 0:
        return {k for k in range(chunks) if is_done(out, k)}
    listed = set(fs.list_files(fs.join(out, "parts")))
    return {k for k in range(chunks) if f"manifest-{k:06d}.parquet" in listed}
