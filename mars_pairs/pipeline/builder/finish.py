"""The end of a build: chunk parts merged into manifest.parquet and failures.parquet, then
pairs.parquet (``output.pairs``) and the files that explain the folder (the shard index,
README.md, croissant.json), then dataset.json
recording their digests and SHA256SUMS over it (``store.seal``: the folder's integrity chain),
then ``parts/`` goes (``hygiene.remove_parts``).

Every path written in the folder is relative to it: dataset.json's config names its inputs
relative to the dataset folder as they were at build time, the manifest's ``label_path`` is
relative to the labels root (``labels_root``), croissant.json's files relative to the folder;
moving the folder keeps it whole. A dataset on object storage (``output.dir`` an fsspec URL:
``store.fs``) names its local inputs and labels root by their absolute paths (no path leads
from a bucket to them); every file is uploaded whole.

Memory does not grow with the samples: the parts are read one at a time, the manifest sorted
in runs of ``RUN_ROWS`` rows on scratch disk (``layout.SORT_RUNS``) and merged
(``store.parquet_stream``), what dataset.json, the shard indexes and the summary say is
counted while the files are written (:class:`Merged`), and the leak check
(``store.leakage.streamed_leak_report``) reads the manifest written a batch at a time, its
samples sorted on the same scratch disk."""

from __future__ import annotations

import contextlib
import fnmatch
import itertools
import json
import os
import platform
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from mars_pairs.pipeline.builder.fingerprints import input_files
from mars_pairs.pipeline.builder.hygiene import remove_empty_parts, remove_sort_runs
from mars_pairs.pipeline.builder.layout import SORT_RUNS, part_paths
from mars_pairs.pipeline.builder.plan import BuildPlan
from mars_pairs.pipeline.builder.stamp import FINISHED_KEY, stamp_digest
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.record import labels_root
from mars_pairs.pipeline.splitting import splits_section
from mars_pairs.raster.vsi import open_raster
from mars_pairs.store import fs
from mars_pairs.store.card import CardFacts, dataset_card, default_license
from mars_pairs.store.croissant import croissant_metadata, dataset_description, sha256_of
from mars_pairs.store.dataset_info import DatasetInfo, dataset_document
from mars_pairs.store.dem_codec import dataset_dem_encoding
from mars_pairs.store.geoparquet import crs_name, geo_extremes, named_crs, table_geo_metadata
from mars_pairs.store.leakage import streamed_leak_report
from mars_pairs.store.manifest import FAILURE_SCHEMA, MANIFEST_SCHEMA
from mars_pairs.store.pairs import Footprints, write_pairs
from mars_pairs.store.parquet_stream import RowGroupWriter, merge_runs, sorted_runs
from mars_pairs.store.seal import seal

#: the dataset's pairs of overlapping samples (``output.pairs``)
PAIRS = "pairs.parquet"

#: What dataset.json says of its paths: a dataset on disk, one on object storage.
PATHS_NOTE = (
    "config paths are relative to this dataset folder, as they were when it was built "
    "(inputs stay where they were; a moved folder still reads whole: it needs none of them)"
)
PATHS_NOTE_URL = (
    "config paths are absolute (no relative path leads from object storage to the build's "
    "inputs); output.dir is this dataset's own location"
)


@dataclass(frozen=True)
class BuildSummary:
    """Counts and timing of one build."""

    out_dir: Path | str  # a local folder or an fsspec URL (store.fs)
    samples: int
    failures: int
    failures_by_reason: dict[str, int]
    chunks_built: int
    chunks_resumed: int
    seconds: float
    stage_seconds: dict[str, float]  # summed over the samples built in this run
    appended: str | None = None  # ``--append``: what the append did, one line

    def format(self) -> str:
        """A short human-readable summary."""
        rate = self.samples / self.seconds if self.seconds > 0 else float("nan")
        lines = [
            f"dataset: {self.out_dir}",
            f"samples: {self.samples}   failures: {self.failures}   "
            f"time: {self.seconds:.1f} s ({rate:.1f} samples/s)",
            f"chunks: {self.chunks_built} built, {self.chunks_resumed} resumed",
        ]
        if self.appended is not None:
            lines.append(self.appended)
        lines += [
            f"  failed at {reason}: {n}" for reason, n in sorted(self.failures_by_reason.items())
        ]
        return "\n".join(lines)


#: The manifest's order: Hilbert index of the rover position, then sample key (unique).
MANIFEST_ORDER = [("hilbert", "ascending"), ("key", "ascending")]
#: Rows a row group of manifest.parquet, and of failures.parquet. pyarrow's Parquet writer
#: holds every row group's column metadata until the footer, and readers parse the footer
#: whole: at 1,024 rows a group a 1M-row manifest's 976 groups of 69 columns held 62 MiB in
#: the finish (10 MiB at 100k), against ~6 MiB at 10,000 rows a group; a location filter
#: still skips row groups by their statistics (benchmarks/bench_manifest.py: 4 of the 100
#: row groups of a 1M-row manifest read for a 0.01-degree box).
MANIFEST_ROW_GROUP = 10_000
FAILURES_ROW_GROUP = 4096
#: Manifest rows sorted in memory at a time: a manifest of more rows is sorted on disk (sorted
#: runs of this many rows, merged: ``store.parquet_stream``), so the finish holds no more.
RUN_ROWS = 4096


@dataclass(frozen=True)
class Merged:
    """What the finish needs of the merged files, counted while they are written.

    ``by_split`` and ``by_mission``: samples a split and a mission, in the order the
    manifest first holds them; ``shards``: split -> shard -> samples; ``failures_by_reason``:
    failure rows a ``"stage (error_type)"``, in the order of failures.parquet."""

    manifest: fs.Location  # manifest.parquet, written
    samples: int
    failures: int
    by_split: dict[str, int]
    by_mission: dict[str, int]
    shards: dict[str, dict[str, int]]
    failures_by_reason: dict[str, int]


def merge_parts(config: BuildConfig, n_chunks: int) -> Merged:
    """Merge the chunk parts into manifest.parquet (Hilbert order) and failures.parquet, a
    part at a time."""
    out = config.output.dir
    parts = (fs.read_parquet_file(part_paths(out, k)[1]) for k in range(n_chunks))
    fails = (fs.read_parquet_file(part_paths(out, k)[2]) for k in range(n_chunks))
    return write_merged(config, parts, fails)


def write_merged(
    config: BuildConfig, parts: Iterable[pa.Table], fails: Iterable[pa.Table]
) -> Merged:
    """Write manifest.parquet (the rows of ``parts``, in Hilbert order, then by key, with the
    GeoParquet metadata, row groups of ``MANIFEST_ROW_GROUP``) and failures.parquet (the
    rows of ``fails``, in order), reading one table of each at a time; the tables' schemas
    may differ in their metadata only. Memory: ``RUN_ROWS`` manifest rows, whatever the
    count (more are sorted in runs on scratch disk: ``SORT_RUNS`` in a local output folder,
    ``fs.local_staging`` for object storage); the bytes
    are those of the whole table sorted in memory and written at once."""
    out = config.output.dir
    crs = dataset_crs(config)
    extremes: list[pa.Table] = []  # at most one: the extremes of the rows so far
    schemas: list[pa.Schema] = []

    def noted(tables: Iterable[pa.Table]) -> Iterator[pa.Table]:
        for table in tables:
            table = table.replace_schema_metadata(None)
            if not schemas:
                schemas.append(table.schema)
            both = [*extremes, geo_extremes(table)]
            extremes[:] = [geo_extremes(pa.concat_tables(both))]
            yield table

    counts = _ManifestCounts()
    target = fs.join(out, "manifest.parquet")
    with _sort_scratch(out) as scratch:
        runs, whole = sorted_runs(noted(parts), MANIFEST_ORDER, RUN_ROWS, scratch)
        schema = schemas[0] if schemas else MANIFEST_SCHEMA
        seen = extremes[0] if extremes else MANIFEST_SCHEMA.empty_table()
        schema = schema.with_metadata(table_geo_metadata(seen, crs))
        if whole is not None:
            rows: Iterable[pa.Table] = [whole]
        else:
            rows = merge_runs(runs, MANIFEST_ORDER, scratch)
        with (
            fs.written_file(target) as local,
            RowGroupWriter(local, schema, MANIFEST_ROW_GROUP) as writer,
        ):
            for table in rows:
                writer.write(table)
                counts.add(table)
    failures, reasons = _write_failures(fs.join(out, "failures.parquet"), fails)
    return Merged(
        manifest=target,
        samples=counts.samples,
        failures=failures,
        by_split=dict(counts.by_split),
        by_mission=dict(counts.by_mission),
        shards={split: dict(n) for split, n in counts.shards.items()},
        failures_by_reason=dict(reasons),
    )


@contextlib.contextmanager
def _sort_scratch(out: fs.Location) -> Iterator[Path]:
    """The folder of the manifest's sorted runs: ``SORT_RUNS`` of a local output folder (one a
    killed build left removed first; made by the first run written, removed at the end), a
    local staging folder for object storage (``fs.local_staging``)."""
    if not isinstance(out, Path):
        with fs.local_staging() as staging:
            yield staging
        return
    remove_sort_runs(out)
    try:
        yield out / SORT_RUNS
    finally:
        remove_sort_runs(out)


class _ManifestCounts:
    """The counts of :class:`Merged` over the manifest rows added, in their order."""

    def __init__(self) -> None:
        self.samples = 0
        self.by_split: Counter[str] = Counter()
        self.by_mission: Counter[str] = Counter()
        self.shards: dict[str, Counter[str]] = {}

    def add(self, table: pa.Table) -> None:
        self.samples += table.num_rows
        for name, counter in (("split", self.by_split), ("mission", self.by_mission)):
            for entry in pc.value_counts(table[name]).to_pylist():  # first seen first
                counter[entry["values"]] += entry["counts"]
        pairs = table.group_by(["split", "meta_shard"], use_threads=False)
        for row in pairs.aggregate([([], "count_all")]).to_pylist():
            shards = self.shards.setdefault(row["split"], Counter())
            shards[row["meta_shard"]] += row["count_all"]


def failure_reasons(path: fs.Location) -> tuple[int, Counter[str]]:
    """The rows of the failures file ``path`` and their count a ``"stage (error_type)"``, in
    order, read a batch at a time."""
    reasons: Counter[str] = Counter()
    rows = 0
    with fs.open_input(path) as handle:
        batches = pq.ParquetFile(handle).iter_batches(65536, columns=["stage", "error_type"])
        for batch in batches:
            rows += batch.num_rows
            _count_reasons(reasons, pa.Table.from_batches([batch]))
    return rows, reasons


def _count_reasons(reasons: Counter[str], failures: pa.Table) -> None:
    stages, errors = failures["stage"].to_pylist(), failures["error_type"].to_pylist()
    reasons.update(f"{s} ({e})" for s, e in zip(stages, errors, strict=True))


def _write_failures(path: fs.Location, fails: Iterable[pa.Table]) -> tuple[int, Counter[str]]:
    """Write the rows of ``fails`` in order as the failures file ``path`` (row groups of
    ``FAILURES_ROW_GROUP``; ``FAILURE_SCHEMA`` when there is no table); the row count and
    the rows a ``"stage (error_type)"``, in order."""
    tables = (t.replace_schema_metadata(None) for t in fails)
    first = next(tables, None)
    schema = FAILURE_SCHEMA if first is None else first.schema
    reasons: Counter[str] = Counter()
    with (
        fs.written_file(path) as local,
        RowGroupWriter(local, schema, FAILURES_ROW_GROUP) as writer,
    ):
        for table in itertools.chain([first] if first is not None else [], tables):
            writer.write(table)
            _count_reasons(reasons, table)
        return writer.rows, reasons


#: the manifest columns the pairs read (``store.pairs.Footprints.from_table``)
PAIRS_COLUMNS = (
    "key", "footprint", "longitude", "latitude", "elevation_m", "azimuth_deg",
    "mission", "site", "drive", "pose", "split",
)  # fmt: skip


def write_dataset_pairs(config: BuildConfig, merged: Merged) -> int | None:
    """With ``output.pairs``, write ``pairs.parquet`` (``store.pairs`` over the footprints of
    the manifest written, ``merged.manifest``: every pair of samples whose footprints
    overlap, with their splits and ``cross_split``) and return the count of pairs; without
    it, remove a ``pairs.parquet`` an earlier build left and return None. Before the card and
    dataset.json, which seal it. Memory: the samples' footprints (an opt-in file)."""
    out = config.output.dir
    path = fs.join(out, PAIRS)
    if not config.output.pairs:
        if fs.exists(path):
            fs.remove(path)
        return None
    manifest = fs.read_parquet(merged.manifest, columns=list(PAIRS_COLUMNS))
    footprints = Footprints.from_table(manifest, crs=dataset_crs(config))
    if isinstance(out, Path):
        return write_pairs(out / PAIRS, footprints)
    with fs.local_staging() as tmp:
        count = write_pairs(tmp / PAIRS, footprints)
        fs.upload(tmp / PAIRS, path)
    return count


def dataset_crs(config: BuildConfig) -> str:
    with open_raster(config.inputs.dem) as src:
        return str(src.crs.to_wkt())


def named_wkt(crs: str) -> str:
    """``crs`` as WKT with the names ``geoparquet.named_crs`` gives it (the same CRS)."""
    from pyproj import CRS

    return str(CRS.from_json_dict(named_crs(crs)).to_wkt("WKT1_GDAL"))


def relative_config(config: BuildConfig) -> dict[str, Any]:
    """``config.to_dict()`` with every local path relative to the dataset folder (POSIX
    separators); remote rasters (GDAL ``/vsi...`` paths) as given; ``output.dir`` is ``.``.
    A dataset on object storage keeps the absolute local paths."""
    out = config.output.dir

    def rel(value: Any) -> Any:
        if value is None or (isinstance(value, str) and value.startswith("/vsi")):
            return value
        if not isinstance(out, Path):
            return Path(value).as_posix()
        return Path(os.path.relpath(str(value), out)).as_posix()

    doc = config.to_dict()
    inputs = doc["inputs"]
    inputs["labels"] = [rel(p) for p in inputs["labels"]]
    for key in ("places", "dem", "ortho", "images"):
        inputs[key] = rel(inputs.get(key))
    if isinstance(inputs.get("synthetic"), dict):
        inputs["synthetic"]["root"] = rel(inputs["synthetic"].get("root"))
    doc["output"]["dir"] = "."
    doc["source"] = rel(doc.get("source"))
    return doc


def license_of(config: BuildConfig) -> str:
    """``output.license``, or the default for the inputs (``card.default_license``)."""
    return config.output.license or default_license(config.inputs.synthetic is not None)


def library_versions() -> dict[str, str]:
    """The versions of what a build's bytes depend on: mars-pairs, Python, the libraries that
    read and write the data (numpy, rasterio with its GDAL and PROJ, pyproj's PROJ, pyarrow,
    numba, Pillow, imagecodecs) and torch, which reads it (from the installed metadata: torch
    is not imported); ``-`` for one not installed."""
    from importlib.metadata import PackageNotFoundError, version

    import numba
    import numpy
    import pyarrow
    import pyproj
    import rasterio

    from mars_pairs.version import __version__

    def installed(name: str) -> str:
        try:
            return version(name)
        except PackageNotFoundError:
            return "-"

    return {
        "mars_pairs": __version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "rasterio": rasterio.__version__,
        "gdal": str(rasterio.__gdal_version__),
        "proj": str(pyproj.proj_version_str),
        "pyproj": pyproj.__version__,
        "pyarrow": pyarrow.__version__,
        "numba": numba.__version__,
        "pillow": installed("pillow"),
        "imagecodecs": installed("imagecodecs"),
        "torch": installed("torch"),
    }


def dataset_doc(
    config: BuildConfig,
    summary: BuildSummary,
    merged: Merged,
    dropped: int,
    fingerprint: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
    pairs: int | None = None,
) -> dict[str, Any]:
    """The dataset.json document (with the finished build's ``build_stamp`` when
    ``fingerprint``, the build's stamp, is given; ``extra``'s keys over the document's: an
    append's ``appends`` and ``build_stamp``), written last by :func:`write_dataset_json`.
    ``input_files`` holds the fingerprints of the PLACES table, DEM and ortho without their paths
    (``fingerprints.input_files``), which ``--append`` checks. ``merged``: the merged files'
    counts; the leak check reads the manifest written a batch at a time
    (``store.leakage.streamed_leak_report``, its sweep's runs in the sort scratch of
    :func:`write_merged`). ``pairs``: the count of
    pairs.parquet's rows (``counts.pairs``; None: no pairs.parquet)."""
    counts: dict[str, Any] = {"samples": summary.samples, "failures": summary.failures}
    if pairs is not None:
        counts["pairs"] = pairs
    if merged.samples:
        counts["by_split"] = dict(merged.by_split)
        counts["by_mission"] = dict(merged.by_mission)
    with _sort_scratch(config.output.dir) as scratch:
        leak = streamed_leak_report(merged.manifest, config.chips.size_m, scratch)
    crs = named_wkt(dataset_crs(config))
    out = config.output.dir
    root = labels_root(config.inputs.labels)
    doc: dict[str, Any] = {
        "config": relative_config(config),
        "paths": PATHS_NOTE if isinstance(out, Path) else PATHS_NOTE_URL,
        # the folder the manifest's label_path is relative to (relative to this folder)
        "labels_root": Path(
            os.path.relpath(root, out) if isinstance(out, Path) else root
        ).as_posix(),
        "license": license_of(config),
        "versions": library_versions(),
        "crs": crs,
        "crs_name": crs_name(crs),
        "chip": {
            "size_m": config.chips.size_m,
            "size_px": config.chips.size_px,
            "orientation": config.chips.orientation,
        },
        "dem_encoding": dataset_dem_encoding(),
        "counts": counts,
        "splits": splits_section(config, merged.by_split, leak, dropped),
        "failures_by_reason": summary.failures_by_reason,
        "build_seconds": round(summary.seconds, 3),
    }
    doc["input_files"] = input_files(config)
    if fingerprint is not None:
        doc[FINISHED_KEY] = stamp_digest(fingerprint)
    doc.update(extra or {})
    return dataset_document(doc, fs.join(out, "dataset.json"))  # format_version first, checked


def write_dataset_json(config: BuildConfig, doc: dict[str, Any]) -> None:
    """Write dataset.json ``doc`` with the record of the folder's files, then SHA256SUMS over
    it (``store.seal``): the last files of a build, after every file they record."""
    seal(config.output.dir, doc)


def write_card(config: BuildConfig, doc: dict[str, Any]) -> None:
    """README.md (the dataset card) and croissant.json, from dataset.json's ``doc`` and the
    manifest written (``manifest.parquet`` must be in place: croissant.json holds its hash)."""
    from mars_pairs.version import __version__

    out = config.output.dir
    synthetic = config.inputs.synthetic is not None
    schema = fs.parquet_schema(fs.join(out, "manifest.parquet"))
    shards = sorted(
        name
        for name in fs.list_files(fs.join(out, "shards"))
        if "/" not in name and fnmatch.fnmatchcase(name, "shard-*.tar")
    )
    info = DatasetInfo.from_doc(doc, fs.join(out, "dataset.json"))
    facts = CardFacts(
        version=__version__,
        config=info.config,
        counts=info.counts,
        splits=info.splits,
        crs_name=str(info.crs_name),
        license=str(info.license),
        synthetic=synthetic,
        schema=schema,
        shards=shards,
        failures_by_reason=info.failures_by_reason,
    )
    fs.put_bytes(fs.join(out, "README.md"), dataset_card(facts).encode())
    meta = croissant_metadata(
        name="mars-pairs-dataset",
        description=dataset_description(info.counts, synthetic),
        version=__version__,
        license=str(info.license),
        synthetic=synthetic,
        schema=schema,
        manifest_sha256=sha256_of(fs.join(out, "manifest.parquet")),
        missions=list(info.counts.get("by_mission") or {}),
    )
    fs.put_bytes(fs.join(out, "croissant.json"), json.dumps(meta, indent=2).encode())


def finished_summary(config: BuildConfig, plan: BuildPlan, start: float) -> BuildSummary:
    """The summary of a ``--resume`` over a finished build of the same config: nothing is
    built or written (an empty ``parts/`` left by a kill is removed)."""

    out = config.output.dir
    remove_empty_parts(out)
    samples = fs.parquet_metadata(fs.join(out, "manifest.parquet")).num_rows
    failures, reasons = failure_reasons(fs.join(out, "failures.parquet"))
    return BuildSummary(
        out_dir=out,
        samples=samples,
        failures=failures,
        failures_by_reason=dict(reasons),
        chunks_built=0,
        chunks_resumed=plan.chunks,
        seconds=time.perf_counter() - start,
        stage_seconds={},
    )
