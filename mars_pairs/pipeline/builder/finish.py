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
from a bucket to them); every file is uploaded whole."""

from __future__ import annotations

import fnmatch
import json
import os
import platform
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.pipeline.builder.fingerprints import input_files
from mars_pairs.pipeline.builder.hygiene import remove_empty_parts
from mars_pairs.pipeline.builder.layout import part_paths
from mars_pairs.pipeline.builder.plan import BuildPlan
from mars_pairs.pipeline.builder.stamp import FINISHED_KEY, stamp_digest
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.record import labels_root
from mars_pairs.pipeline.splitting import splits_report
from mars_pairs.raster.vsi import open_raster
from mars_pairs.store import fs
from mars_pairs.store.card import CardFacts, dataset_card, default_license
from mars_pairs.store.croissant import croissant_metadata, dataset_description, sha256_of
from mars_pairs.store.dataset_info import DatasetInfo, dataset_document
from mars_pairs.store.dem_codec import dataset_dem_encoding
from mars_pairs.store.geoparquet import crs_name, named_crs, table_geo_metadata
from mars_pairs.store.manifest import FAILURE_SCHEMA, MANIFEST_SCHEMA
from mars_pairs.store.pairs import Footprints, write_pairs
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


def merge_parts(config: BuildConfig, n_chunks: int) -> tuple[pa.Table, pa.Table]:
    """Concatenate the chunk parts into manifest.parquet (Hilbert order) and failures.parquet."""
    out = config.output.dir
    parts = [fs.read_parquet(part_paths(out, k)[1]) for k in range(n_chunks)]
    fails = [fs.read_parquet(part_paths(out, k)[2]) for k in range(n_chunks)]
    return write_merged(config, parts, fails)


def write_merged(
    config: BuildConfig, parts: list[pa.Table], fails: list[pa.Table]
) -> tuple[pa.Table, pa.Table]:
    """Write manifest.parquet (the rows of ``parts``, in Hilbert order, then by key, with the
    GeoParquet metadata) and failures.parquet (the rows of ``fails``, in order); returns
    both tables. The parts' schemas may differ in their metadata only."""
    out = config.output.dir
    parts = [t.replace_schema_metadata(None) for t in parts]
    fails = [t.replace_schema_metadata(None) for t in fails]
    manifest = pa.concat_tables(parts) if parts else MANIFEST_SCHEMA.empty_table()
    manifest = manifest.sort_by([("hilbert", "ascending"), ("key", "ascending")])
    failures = pa.concat_tables(fails) if fails else FAILURE_SCHEMA.empty_table()
    crs = dataset_crs(config)
    manifest = manifest.replace_schema_metadata(table_geo_metadata(manifest, crs))
    fs.write_parquet(manifest, fs.join(out, "manifest.parquet"), row_group_size=1024)
    fs.write_parquet(failures, fs.join(out, "failures.parquet"))
    return manifest, failures


def write_dataset_pairs(config: BuildConfig, manifest: pa.Table) -> int | None:
    """With ``output.pairs``, write ``pairs.parquet`` (``store.pairs`` over the manifest's
    footprints: every pair of samples whose footprints overlap, with their splits and
    ``cross_split``) and return the count of pairs; without it, remove a ``pairs.parquet``
    an earlier build left and return None. Before the card and dataset.json, which seal it."""
    out = config.output.dir
    path = fs.join(out, PAIRS)
    if not config.output.pairs:
        if fs.exists(path):
            fs.remove(path)
        return None
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
    manifest: pa.Table,
    dropped: int,
    fingerprint: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
    pairs: int | None = None,
) -> dict[str, Any]:
    """The dataset.json document (with the finished build's ``build_stamp`` when
    ``fingerprint``, the build's stamp, is given; ``extra``'s keys over the document's: an
    append's ``appends`` and ``build_stamp``), written last by :func:`write_dataset_json`.
    ``input_files`` holds the fingerprints of the PLACES table, DEM and ortho without their paths
    (``fingerprints.input_files``), which ``--append`` checks. ``pairs``: the count of
    pairs.parquet's rows (``counts.pairs``; None: no pairs.parquet)."""
    counts: dict[str, Any] = {"samples": summary.samples, "failures": summary.failures}
    if pairs is not None:
        counts["pairs"] = pairs
    if manifest.num_rows:
        counts["by_split"] = dict(Counter(manifest.column("split").to_pylist()))
        counts["by_mission"] = dict(Counter(manifest.column("mission").to_pylist()))
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
        "splits": splits_report(config, manifest, dropped),
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


def write_card(config: BuildConfig, manifest: pa.Table, doc: dict[str, Any]) -> None:
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
    failures = fs.read_parquet(fs.join(out, "failures.parquet"), columns=["stage", "error_type"])
    reasons = Counter(
        f"{s} ({e})"
        for s, e in zip(
            failures["stage"].to_pylist(), failures["error_type"].to_pylist(), strict=True
        )
    )
    return BuildSummary(
        out_dir=out,
        samples=samples,
        failures=failures.num_rows,
        failures_by_reason=dict(reasons),
        chunks_built=0,
        chunks_resumed=plan.chunks,
        seconds=time.perf_counter() - start,
        stage_seconds={},
    )
