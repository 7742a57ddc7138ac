"""Appending a new archive release to a finished dataset (``mars-pairs build --append``).

An append builds the labels its globs match that the dataset does not hold yet, as new chunks
after the dataset's own (chunk k >= the dataset's chunk count: new shards, new manifest and
failure parts), and merges them with the dataset at the end. It never writes an existing
shard; manifest.parquet, failures.parquet, dataset.json, the WIDS index, README.md and
croissant.json are rewritten whole (atomically) as the union.

What the dataset holds: a label whose path (relative to the labels root) is a manifest row's
``label_path`` or a failure row's ``path`` is *known* and skipped (a failed label stays failed:
rebuild from scratch to retry it); the count is printed and recorded. A new label whose
sample key the dataset already holds (the same product under another path, a newer version)
becomes a DuplicateKeyError failure row naming the label that holds the key, as in a single
build, where the first label in label order keeps it; an append keeps the existing sample
whatever the order (it never rewrites a shard), so the two agree when the new release's
labels sort after the old ones' and differ otherwise (then the single build keeps the new
label's sample and fails the old one).

What may change between releases: ``inputs.labels`` (the release's globs; their labels root
must stay the one ``label_path`` is relative to) and ``inputs.places`` (a PLACES table with new
rows: the samples already built are not recomputed). Every other config key, and the DEM and
ortho files (dataset.json's ``input_files``), must be those the dataset was built with: an
append refuses otherwise, naming the key. Splits are a function of each sample's position and
the config, so an appended sample lands in the split a single build gives it; the leak check
of dataset.json runs over the whole merged manifest. The dataset's sample keys and label paths
are read a batch at a time into the driver's on-disk key index (``key_index``), which the
plan and then the commits ask: the append holds none of them.

Crash safety. The append first links (or copies) the dataset's manifest.parquet,
failures.parquet and dataset.json to ``parts/base-*`` (its base), then writes its stamp
(``parts/build.json``: the fingerprint of its config, of the new labels and of the inputs,
with the base's chunk count). While that stamp is there, the base is read from ``parts/base-*``
only, so a killed append rerun with ``--append`` plans the same new labels and chunks, keeps
the chunks it committed and rewrites the merged files from the base: the same dataset as an
uninterrupted append. The stamp goes before the base copies as the append finishes. Not
supported: ``splits.buffer_policy: drop`` (a dropped sample's label is in neither file, so the
next append would not know it was seen) and ``output.keep_parts`` (parts/ is the append's
working state).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.fingerprints import LabelDigest, input_change, input_files
from mars_pairs.pipeline.builder.finish import RUN_ROWS, Merged, relative_config, write_merged
from mars_pairs.pipeline.builder.hygiene import remove_empty_parts
from mars_pairs.pipeline.builder.key_index import KeyIndex, scratch_index
from mars_pairs.pipeline.builder.label_list import iter_matches
from mars_pairs.pipeline.builder.layout import DROPPED_KEY, part_paths, stamp_path
from mars_pairs.pipeline.builder.plan import check_clearable, check_inputs, is_done
from mars_pairs.pipeline.builder.stamp import (
    FINISHED_KEY,
    read_stamp,
    stamp_chunks,
    stamp_difference,
    stamp_digest,
    stamp_of,
)
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.record import labels_root
from mars_pairs.store import fs
from mars_pairs.store.atomic import atomic_path
from mars_pairs.store.dataset_info import DATASET_JSON, DatasetInfo

#: dataset.json's list of the appends made to the dataset (``append_record``).
APPENDS_KEY = "appends"
#: The dataset's files an append reads as its base, and where it keeps their snapshot.
BASE_FILES = {
    "manifest.parquet": "parts/base-manifest.parquet",
    "failures.parquet": "parts/base-failures.parquet",
    "dataset.json": "parts/base-dataset.json",
}
#: The config keys an append may change (dotted): the release's globs and PLACES table.
MAY_CHANGE = ("inputs.labels", "inputs.places", "source")
#: The inputs whose files must be those the dataset was built from.
FIXED_INPUTS = ("dem", "ortho")
#: Rows of the base's files read at a time.
_BATCH = 8192


@dataclass(frozen=True)
class AppendPlan:
    """What ``--append`` would do over the dataset in ``out_dir``: counts of the release's
    labels, of those the dataset holds (skipped) and of the new ones, and the new chunks
    (indices ``[base_chunks, base_chunks + chunks)``)."""

    out_dir: Path
    base_chunks: int  # the dataset's chunks: the append's first chunk index
    labels_seen: int  # labels the release's globs match
    labels_known: int  # of those, in the manifest or the failures already (skipped)
    labels_new: int  # the labels to build (at most one sample each)
    chunk_size: int
    chunks: int  # new chunks
    chunks_done: int  # of those, committed by an interrupted append of the same release
    resumed: bool  # an interrupted append of the same release was found
    started: str  # when the append began (UTC, ISO 8601): its record's ``when``
    seconds: float  # planning wall time, s
    fingerprint: dict[str, Any] = field(repr=False, compare=False)  # the stamp it writes
    full_digest: dict[str, Any] = field(repr=False, compare=False)  # build_stamp after it
    base: dict[str, Any] = field(repr=False, compare=False)  # the base's dataset.json

    def format(self) -> str:
        """The plan as ``mars-pairs build --append --dry-run`` prints it."""
        resumed = " (an interrupted append of this release: kept)" if self.resumed else ""
        first, end = self.base_chunks, self.base_chunks + self.chunks
        return "\n".join(
            [
                f"dry run: nothing written to {self.out_dir}",
                f"append: {self.labels_seen} labels matched, {self.labels_known} already in "
                f"the dataset (skipped), {self.labels_new} new   planned in "
                f"{self.seconds:.2f} s",
                f"chunks: {self.base_chunks} kept, {self.chunks} new (chunks {first} to "
                f"{end - 1}) of up to {self.chunk_size} labels",
                f"new chunks done: {self.chunks_done}{resumed}",
            ]
        )

    def summary_line(self) -> str:
        """One line for the build's summary."""
        return (
            f"append: {self.labels_seen} labels matched, {self.labels_known} already in the "
            f"dataset (skipped), {self.labels_new} new"
        )


def _plain(doc: Any) -> Any:
    """``doc`` as JSON reads it back (tuples as lists)."""
    return json.loads(json.dumps(doc))


def config_difference(old: Any, new: Any, prefix: str = "") -> str | None:
    """The first dotted key (sorted, depth first) whose value differs between two config
    documents, skipping ``MAY_CHANGE``; None when they agree."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new)):
            name = f"{prefix}.{key}" if prefix else key
            if name in MAY_CHANGE:
                continue
            if key not in old or key not in new:
                return name
            why = config_difference(old[key], new[key], name)
            if why is not None:
                return why
        return None
    return None if old == new else prefix


def _info(base: dict[str, Any]) -> DatasetInfo:
    """The typed view of the base's dataset.json document ``base``."""
    return DatasetInfo.from_doc(base, DATASET_JSON, required=False)


def _lookup(doc: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        doc = doc.get(part) if isinstance(doc, dict) else None
    return doc


def local_dir(config: BuildConfig) -> Path:
    """``output.dir``, a local folder; ConfigError naming it when it is on object storage
    (an fsspec URL: an append's base snapshot and merge work on local files)."""
    out = config.output.dir
    if not isinstance(out, Path):
        raise ConfigError(
            f"--append: output.dir {out} is on object storage, where an append is not "
            "supported yet; append to a local copy, or rebuild"
        )
    return out


def check_append_config(config: BuildConfig, base: dict[str, Any]) -> None:
    """ConfigError naming the key when ``config`` may not append to the dataset whose
    dataset.json is ``base``: a config key other than ``MAY_CHANGE`` changed, the labels root
    moved, the DEM or ortho file changed (``input_files``), or the config asks for what an
    append does not support (``splits.buffer_policy: drop``; ``output.keep_parts`` is
    refused by ``plan_append``)."""
    out = local_dir(config)
    why = f"{out}: cannot --append"
    old = _info(base).config
    if not old:
        raise ConfigError(f"{why}: its dataset.json holds no config")
    new = _plain(relative_config(config))
    key = config_difference(old, new)
    if key is not None:
        raise ConfigError(
            f"{key}: changed since the dataset was built ({_lookup(old, key)!r} -> "
            f"{_lookup(new, key)!r}); {why}: an append may change inputs.labels and "
            "inputs.places only (build the new config into a new folder)"
        )
    root = Path(os.path.relpath(labels_root(config.inputs.labels), out)).as_posix()
    if base.get("labels_root") != root:
        raise ConfigError(
            f"inputs.labels: the labels root would move from {base.get('labels_root')!r} to "
            f"{root!r} (relative to the dataset); {why}: label_path is relative to it, so "
            "the release's globs must start from the same folder"
        )
    recorded = base.get("input_files")
    if not isinstance(recorded, dict):
        raise ConfigError(
            f"{why}: its dataset.json records no input_files (built by an older mars-pairs); "
            "rebuild it"
        )
    check_fixed_inputs(
        config, recorded, "the dataset was built", f"{why}: the samples built would not match "
        "the new ones",
    )  # fmt: skip
    if config.splits.buffer_policy == "drop":
        raise ConfigError(
            f"splits.buffer_policy: drop: {why}: a dropped sample's label is in neither "
            "manifest.parquet nor failures.parquet, so an append could not tell it was seen"
        )


def check_fixed_inputs(
    config: BuildConfig, recorded: dict[str, Any], since: str, consequence: str
) -> None:
    """ConfigError naming the input when a ``FIXED_INPUTS`` file of ``config`` is not the one
    ``recorded`` (an ``input_files`` record) fingerprints: ``inputs.NAME: PATH changed since
    SINCE: what changed; CONSEQUENCE``."""
    now = input_files(config)
    for name in FIXED_INPUTS:
        if recorded.get(name) != now[name]:
            raise ConfigError(
                f"inputs.{name}: {getattr(config.inputs, name)} changed since {since}: "
                f"{input_change(recorded.get(name), now[name])}; {consequence}"
            )


def known_labels(
    manifest: Path, failures: Path, root: str
) -> tuple[frozenset[str], dict[str, str]]:
    """The label paths (relative to ``root``, with ``/``) the dataset holds, as a manifest
    row's ``label_path`` or a failure row's ``path`` (absolute ones made relative to
    ``root``), and its sample key -> label_path. Memory: linear in the dataset's rows."""
    table = pq.read_table(manifest, columns=["key", "label_path"])
    labels = table["label_path"].to_pylist()
    keys = dict(zip(table["key"].to_pylist(), labels, strict=True))
    known = set(labels)
    for path in pq.read_table(failures, columns=["path"])["path"].to_pylist():
        if path is None:
            continue
        known.add(Path(os.path.relpath(path, root)).as_posix() if os.path.isabs(path) else path)
    return frozenset(known), keys


def add_base(index: KeyIndex, manifest: Path, failures: Path, root: str) -> None:
    """Record in ``index`` what the dataset holds: its sample keys (key -> ``label_path``)
    and, as known label paths (relative to ``root``, with ``/``), every manifest row's
    ``label_path`` and failure row's ``path`` (absolute ones made relative to ``root``); read
    a batch of rows at a time."""
    index.add_table(manifest)
    for batch in pq.ParquetFile(manifest).iter_batches(_BATCH, columns=["label_path"]):
        index.add_known(str(p) for p in batch.column(0).to_pylist())
    for batch in pq.ParquetFile(failures).iter_batches(_BATCH, columns=["path"]):
        index.add_known(
            Path(os.path.relpath(p, root)).as_posix() if os.path.isabs(p) else p
            for p in batch.column(0).to_pylist()
            if p is not None
        )


def new_labels(
    config: BuildConfig, is_known: Callable[[str], bool], every: LabelDigest
) -> Iterator[str]:
    """The labels ``config.inputs.labels`` match whose relative path (with ``/``) is not
    ``is_known`` (``KeyIndex.is_known`` of the base's index), in build order, streamed;
    ``every`` sums every label matched."""
    root = labels_root(config.inputs.labels)
    for label in every.tally(iter_matches(config.inputs.labels)):
        if not is_known(Path(os.path.relpath(label, root)).as_posix()):
            yield label


def plan_append(config: BuildConfig, index: KeyIndex | None = None) -> AppendPlan:
    """Check that ``config`` may append to the finished dataset in ``config.output.dir``, list
    the release's labels and find the new ones (one streaming pass), and find the new chunks
    an interrupted append of the same release committed; writes nothing in the folder.
    ``index``: an empty key index (``key_index.scratch_index``) the plan fills with the
    dataset's keys and label paths (``add_base``) for the append to go on with; without it,
    one of its own, removed. ConfigError naming the key or the file otherwise (see
    ``check_append_config``; no finished dataset; an interrupted build that is not an
    append, or an interrupted append of another release)."""
    if index is None:
        with scratch_index() as own:
            return plan_append(config, own)
    start = time.perf_counter()
    out = local_dir(config)
    if config.output.keep_parts:  # (its finished build's stamp is still in parts/)
        raise ConfigError(
            f"output.keep_parts: true: {out}: cannot --append: parts/ is an append's working state"
        )
    check_inputs(config)
    previous = read_stamp(stamp_path(out))
    interrupted = previous is not None and isinstance(previous.get("append"), dict)
    if previous is not None and not interrupted:
        raise ConfigError(
            f"{out}: cannot --append: it holds an interrupted build (parts/build.json); "
            "finish it with --resume first"
        )
    if interrupted:
        base_paths = {name: out / rel for name, rel in BASE_FILES.items()}
    else:
        base_paths = {name: out / name for name in BASE_FILES}
    absent = [str(p) for p in base_paths.values() if not p.is_file()]
    base = read_stamp(base_paths["dataset.json"])
    if absent or base is None or not isinstance(base.get(FINISHED_KEY), dict):
        what = absent[0] if absent else str(base_paths["dataset.json"])
        raise ConfigError(
            f"{out}: cannot --append: {what} is missing or not a finished build's; "
            "--append adds to a finished dataset (build it first)"
        )
    check_append_config(config, base)
    check_clearable(out, resume=True)  # a stranger's file is never touched
    base_chunks = stamp_chunks(base)
    if base_chunks is None:
        raise ConfigError(f"{base_paths['dataset.json']}: build_stamp: not a build's stamp")
    add_base(
        index,
        base_paths["manifest.parquet"],
        base_paths["failures.parquet"],
        labels_root(config.inputs.labels),
    )
    every, fresh = LabelDigest(), LabelDigest()
    for label in new_labels(config, index.is_known, every):
        fresh.add(label)
    size = config.output.shard_size
    chunks = -(-fresh.count // size)
    stamp = stamp_of(config, fresh)
    stamp["chunks"] = base_chunks + chunks
    full = stamp_of(config, every)
    full_digest = {**stamp_digest(full), "chunks": base_chunks + chunks}
    started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    done = 0
    if interrupted:
        assert previous is not None
        why = stamp_difference(
            {k: v for k, v in previous.items() if k != "append"},
            {k: v for k, v in stamp.items() if k != "append"},
        )
        if why is None and previous["append"].get("first_chunk") != base_chunks:
            why = "the interrupted append's first chunk differs"
        if why is not None:
            raise ConfigError(
                f"{out}: cannot --append: the folder holds an interrupted --append of another "
                f"release ({why}); rerun that append (its config) with --append to finish it"
            )
        started = str(previous["append"].get("started", started))
        done = sum(is_done(out, k) for k in range(base_chunks, base_chunks + chunks))
    stamp["append"] = {
        "first_chunk": base_chunks,
        "started": started,
        "labels_seen": every.count,
        "labels_known": every.count - fresh.count,
    }
    return AppendPlan(
        out_dir=out,
        base_chunks=base_chunks,
        labels_seen=every.count,
        labels_known=every.count - fresh.count,
        labels_new=fresh.count,
        chunk_size=size,
        chunks=chunks,
        chunks_done=done,
        resumed=interrupted,
        started=started,
        seconds=time.perf_counter() - start,
        fingerprint=stamp,
        full_digest=full_digest,
        base=base,
    )


def snapshot_base(out: Path) -> None:
    """Keep the dataset's manifest.parquet, failures.parquet and dataset.json as the append's
    base (``BASE_FILES``): hard links where the file system has them (the merge replaces the
    files, never writes into them), copies otherwise; each through a temporary name
    (``store.atomic.atomic_path``)."""
    (out / "parts").mkdir(exist_ok=True)
    for name, rel in BASE_FILES.items():
        with atomic_path(out / rel) as tmp:
            tmp.unlink(missing_ok=True)  # a killed append's, of a reused pid
            try:
                os.link(out / name, tmp)
            except OSError:
                shutil.copyfile(out / name, tmp)


def new_chunks(plan: AppendPlan) -> range:
    """The indices of the append's chunks."""
    return range(plan.base_chunks, plan.base_chunks + plan.chunks)


def labels_done(plan: AppendPlan) -> int:
    """The new labels of the append's chunks already committed."""
    size = plan.chunk_size
    return sum(
        min(size, plan.labels_new - (k - plan.base_chunks) * size)
        for k in new_chunks(plan)
        if is_done(plan.out_dir, k)
    )


def merge_append(config: BuildConfig, plan: AppendPlan) -> tuple[Merged, int]:
    """Write manifest.parquet and failures.parquet as the base's rows and the new chunks'
    (``finish.write_merged``: Hilbert order; failures: the base's, then the new chunks' in
    chunk order), a batch of rows at a time; returns their counts and the count of samples
    dropped in the split buffer (the base's and the new chunks')."""
    out = local_dir(config)
    dropped = int(_info(plan.base).splits.get("dropped_in_buffer") or 0)
    for k in new_chunks(plan):
        meta = pq.read_schema(part_paths(out, k)[1]).metadata or {}
        dropped += int(meta.get(DROPPED_KEY, b"0"))

    def tables(base: str, part: int) -> Iterator[pa.Table]:
        for batch in pq.ParquetFile(out / BASE_FILES[base]).iter_batches(RUN_ROWS):
            yield pa.Table.from_batches([batch])
        for k in new_chunks(plan):
            yield fs.read_parquet_file(part_paths(out, k)[part])

    merged = write_merged(config, tables("manifest.parquet", 1), tables("failures.parquet", 2))
    return merged, dropped


def append_record(
    config: BuildConfig, plan: AppendPlan, samples: int, failures: int
) -> dict[str, Any]:
    """The entry of dataset.json's ``appends`` for ``plan``: when it began, the release's
    globs and PLACES table (relative to the dataset folder, as ``config``), the globs before
    it, the counts of labels matched, skipped (already in the dataset) and new, of the
    samples and failure rows it added, and its chunks ``[first, end)``."""
    inputs = relative_config(config)["inputs"]
    before = _info(plan.base).config.get("inputs") or {}
    return {
        "when": plan.started,
        "labels": inputs["labels"],
        "previous_labels": before.get("labels"),
        "places": inputs["places"],
        "labels_seen": plan.labels_seen,
        "labels_known": plan.labels_known,
        "labels_added": plan.labels_new,
        "samples": samples,
        "failures": failures,
        "chunks": [plan.base_chunks, plan.base_chunks + plan.chunks],
    }


def dataset_extra(
    config: BuildConfig, plan: AppendPlan, samples: int, failures: int
) -> dict[str, Any]:
    """What dataset.json holds after the append beside a build's keys: ``appends`` (the
    base's and this one's record) and ``build_stamp`` (the digest of a build of the whole
    label list of ``config``, with the dataset's chunk count)."""
    before = plan.base.get(APPENDS_KEY)
    records = list(before) if isinstance(before, list) else []
    records.append(append_record(config, plan, samples, failures))
    return {APPENDS_KEY: records, FINISHED_KEY: plan.full_digest}


def remove_append_parts(out: Path, plan: AppendPlan) -> None:
    """Remove ``parts/`` of a finished append: the new chunks' manifest parts, their failure
    parts, the stamp, then the base snapshot (``BASE_FILES``), then the folder. A kill before
    the stamp goes reruns the append's end (the rebuilt chunks byte for byte); after it, the
    dataset is whole and a leftover base is removed by the next append (or a rebuild)."""
    for k in new_chunks(plan):
        part_paths(out, k)[1].unlink(missing_ok=True)
    for k in new_chunks(plan):
        part_paths(out, k)[2].unlink(missing_ok=True)
    stamp_path(out).unlink(missing_ok=True)
    remove_base(out)


def remove_base(out: Path) -> None:
    """Remove the append base (``BASE_FILES``) left in ``parts/``, and ``parts/`` if empty."""
    for rel in BASE_FILES.values():
        (out / rel).unlink(missing_ok=True)
    remove_empty_parts(out)
