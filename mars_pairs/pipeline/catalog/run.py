"""The footprint catalogue of a config's labels (``run_catalog``): every image's visible
footprint, without chips, into a catalogue folder.

The folder holds ``catalog.parquet`` (``store.catalog_schema``; rows in Hilbert order of the
camera centre, then key), ``failures.parquet`` (the build's failure rows), ``pairs.parquet``
(``store.pairs``), ``catalog.json`` (config, versions, counts, the inputs' fingerprints, the
stamp's digest) and ``README.md``. The labels are streamed in the build's order and cut into
chunks of ``output.shard_size`` as the build cuts them; the chunks run on the build's engines
(in process, ``LocalPool``, ``DaskEngine``: a ``ChunkTask`` whose job is
``chunk.catalog_chunk``), and the driver commits each chunk's parts in chunk order
(``parts/failures-K.parquet``, then ``parts/catalog-K.parquet``, the chunk's commit marker,
each written atomically). A killed catalogue rerun with ``resume`` keeps the committed
chunks when its stamp (``parts/stamp.json``: the build's fingerprint of config, labels and
inputs) matches, and writes the same bytes as an uninterrupted run: nothing written depends
on timing, worker count or engine. ``append``: the labels a finished catalogue does not
hold yet become chunks after its own, then the union is merged (``pipeline.catalog.append``).

On object storage (``out`` an fsspec URL, ``s3://bucket/prefix``: ``store.fs``) the catalogue is
made in a local staging folder (``fs.local_staging``; an append first downloads the
catalogue there) and published when finished (``publish``): the old catalog.json removed, every
other file uploaded whole, catalog.json (the catalogue's commit marker, which
``Catalog.open`` needs) last. A killed run leaves the old catalogue's files without its
catalog.json, or the new ones without theirs, never a mix a reader takes for a catalogue; it
reruns from scratch (``resume`` is refused: its chunks were in the lost staging folder). Its
catalog.json names the local inputs by absolute paths, as a build on object storage does.
"""

from __future__ import annotations

import json
import platform
import re
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from mars_pairs.errors import ConfigError, DuplicateKeyError
from mars_pairs.pipeline.builder import worker
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, Engine, InProcess
from mars_pairs.pipeline.builder.fingerprints import input_files
from mars_pairs.pipeline.builder.finish import dataset_crs, license_of, named_wkt, relative_config
from mars_pairs.pipeline.builder.local_pool import LocalPool
from mars_pairs.pipeline.builder.plan import check_inputs, chunks_of, labels_of
from mars_pairs.pipeline.builder.run import check_input_files
from mars_pairs.pipeline.builder.stamp import (
    fingerprint,
    read_stamp,
    stamp_difference,
    stamp_digest,
)
from mars_pairs.pipeline.catalog.append import (
    APPEND_KIND,
    APPENDS_KEY,
    BASE_FILES,
    plan_catalog_append,
    snapshot_base,
)
from mars_pairs.pipeline.catalog.chunk import catalog_chunk
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.footprint import SIMPLIFY_CELLS
from mars_pairs.pipeline.sample.record import labels_root
from mars_pairs.store import fs
from mars_pairs.store.atomic import atomic_write_bytes, temporary_target, write_parquet_atomic
from mars_pairs.store.catalog_schema import CATALOG_SCHEMA, catalog_geo_metadata
from mars_pairs.store.geoparquet import crs_name
from mars_pairs.store.manifest import FAILURE_SCHEMA
from mars_pairs.store.pairs import Footprints, write_pairs
from mars_pairs.store.seal import FILES_KEY, files_record
from mars_pairs.store.stac import STAC_FILES, write_stac

#: the files of a finished catalogue folder
CATALOG_FILES = (
    "catalog.parquet",
    "failures.parquet",
    "pairs.parquet",
    "catalog.json",
    "README.md",
    *STAC_FILES,
)
#: the files catalog.json's ``files`` record covers (SHA-256 and size)
CATALOG_SEALED = tuple(n for n in CATALOG_FILES if n != "catalog.json")
STAMP = "parts/stamp.json"
_PART = re.compile(
    r"parts/(catalog|failures)-[0-9]{6,}\.parquet|parts/base-catalog\.(parquet|json)|parts/base-failures\.parquet"
)


@dataclass(frozen=True)
class CatalogSummary:
    """What a catalogue run wrote: counts, chunks built and kept, seconds, failure reasons;
    ``out_dir`` the folder, or the URL on object storage."""

    out_dir: Path | str
    images: int
    failures: int
    pairs: int
    chunks_built: int
    chunks_resumed: int
    seconds: float
    failures_by_reason: dict[str, int] = field(default_factory=dict)


def part_paths(out: Path, k: int) -> tuple[Path, Path]:
    """Chunk k's catalogue part (its commit marker) and failure part."""
    return out / f"parts/catalog-{k:06d}.parquet", out / f"parts/failures-{k:06d}.parquet"


def _ours(rel: str) -> bool:
    target = temporary_target(rel.rpartition("/")[2])
    if target is not None:
        rel = f"{rel.rpartition('/')[0]}/{target}".lstrip("/")
    return rel in CATALOG_FILES or rel == STAMP or _PART.fullmatch(rel) is not None


def check_folder(out: Path) -> list[Path]:
    """The catalogue files in ``out``; ConfigError (nothing removed) when it holds any other."""
    if not out.exists():
        return []
    if not out.is_dir():
        raise ConfigError(f"--out: {out} is not a folder")
    files = [p for p in sorted(out.rglob("*")) if p.is_file()]
    for path in files:
        rel = path.relative_to(out).as_posix()
        if not _ours(rel):
            raise ConfigError(
                f"--out: {out} holds {rel}, which a catalogue does not write; refusing to "
                "clear the folder (nothing was removed): use a new or empty folder"
            )
    return files


def run_catalog(
    config: BuildConfig,
    out: Path | str | None = None,
    *,
    workers: int = 1,
    resume: bool = False,
    engine: Engine | None = None,
    progress: bool = True,
    pairs: bool = True,
    append: bool = False,
) -> CatalogSummary:
    """The footprint catalogue of ``config``'s labels in ``out`` (default ``output.dir``): a
    local folder, or an fsspec URL (``s3://bucket/prefix``: made locally, then published).

    ``engine``: None for this machine's pool of ``workers`` processes (this process when 1)
    or another build engine (``DaskEngine``). ``resume``: keep the chunks an interrupted run
    with the same stamp committed. ``pairs``: also write pairs.parquet. ``append``: add the
    labels the finished catalogue in the folder does not hold yet (``pipeline.catalog.append``;
    an interrupted append of the same release is continued).
    """
    start = time.perf_counter()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: expected an integer >= 1, got {workers!r}")
    run = _Run(workers, engine, progress, pairs, start)
    target = out if out is not None else config.output.dir
    root = fs.dataset_root(target)
    if isinstance(root, str):
        return _run_to_url(config, root, run, resume, append)
    folder = root.resolve()
    config = replace(config, output=replace(config.output, dir=folder))
    return _run_in(config, folder, run, resume, append)


@dataclass(frozen=True)
class _Run:
    """How a catalogue runs: its engine (None: a pool of ``workers``, this process when 1),
    the progress bar, whether pairs.parquet is written, when it started (perf_counter s)."""

    workers: int
    engine: Engine | None
    progress: bool
    pairs: bool
    start: float


def _run_to_url(
    config: BuildConfig, url: str, run: _Run, resume: bool, append: bool
) -> CatalogSummary:
    """run_catalog into the URL ``url``: made in a local staging folder (an append's base
    downloaded there first), then published (``publish``)."""
    if resume:
        raise ConfigError(
            f"--resume: {url}: a catalogue on object storage is made in a local temporary "
            "folder and uploaded when finished, so a killed run left nothing to resume; "
            "rerun without --resume"
        )
    held = fs.list_files(url)
    foreign = [rel for rel in held if rel not in CATALOG_FILES]
    if foreign:
        raise ConfigError(
            f"--out: {url} holds {foreign[0]}, which a catalogue does not write; refusing to "
            "replace the prefix (nothing was removed): use a new or empty prefix"
        )
    if append and "catalog.json" not in held:
        raise ConfigError(
            f"{url}: cannot --append: no catalog.json there (no finished catalogue); "
            "--append adds to a finished catalogue (make it first)"
        )
    config = replace(config, output=replace(config.output, dir=url))
    fs.remove_stale_staging()
    with fs.local_staging() as staging:
        local = staging / "catalog"
        local.mkdir()
        if append:
            for rel in held:
                (local / rel).write_bytes(fs.read_bytes(fs.join(url, rel)))
        summary = _run_in(config, local, run, False, append)
        if not (append and summary.chunks_built == 0):  # an append of nothing writes nothing
            publish(local, url, held)
    return replace(summary, out_dir=url, seconds=time.perf_counter() - run.start)


def publish(local: Path, url: str, held: list[str]) -> None:
    """Upload the finished catalogue folder ``local`` to ``url``, which holds the files
    ``held`` (an older catalogue's): its catalog.json removed first, every other file
    uploaded whole, the old files the new catalogue does not have removed, catalog.json
    last (while it is absent, no reader takes the prefix for a catalogue)."""
    names = [name for name in CATALOG_FILES if (local / name).is_file()]
    if "catalog.json" in held:
        fs.remove(fs.join(url, "catalog.json"))
    for name in names:
        if name != "catalog.json":
            fs.upload(local / name, fs.join(url, name))
    for rel in held:
        if rel not in names:
            fs.remove(fs.join(url, rel))
    fs.upload(local / "catalog.json", fs.join(url, "catalog.json"))


def _run_in(
    config: BuildConfig, folder: Path, run: _Run, resume: bool, append: bool
) -> CatalogSummary:
    """run_catalog writing into the local ``folder`` (``config.output.dir``, or the staging
    folder of the URL ``config.output.dir``, which catalog.json and the STAC hrefs name)."""
    check_input_files(config)
    check_inputs(config)
    files = check_folder(folder)
    if append:
        if resume:
            raise ConfigError("--resume: not with --append (a killed append reruns with --append)")
        return _run_append(config, folder, run)
    stamp = {"kind": "catalog", **fingerprint(config, labels_of(config))}
    if resume:
        previous = read_stamp(folder / STAMP)
        finished = _finished(folder, stamp)
        if finished is not None:
            return replace(finished, seconds=time.perf_counter() - run.start)
        why = None if previous is None else stamp_difference(previous, stamp)
        if previous is not None and previous.get("kind") == APPEND_KIND:
            why = "it holds an interrupted --append (rerun that append with --append)"
        if why is not None:
            raise ConfigError(f"--resume: {folder}: {why}; rerun without --resume")
        if previous is None:
            resume = False
    if not resume:
        for path in files:
            path.unlink()
    (folder / "parts").mkdir(parents=True, exist_ok=True)
    if not resume or not (folder / STAMP).exists():
        atomic_write_bytes(folder / STAMP, json.dumps(stamp).encode())
    chunk_size = config.output.shard_size
    n_chunks = -(-int(stamp["count"]) // chunk_size)
    done = {k for k in range(n_chunks) if part_paths(folder, k)[0].exists()}
    todo = (
        ChunkTask(k, tuple(labels), job=catalog_chunk)
        for k, labels in enumerate(chunks_of(labels_of(config), chunk_size))
        if k not in done
    )
    seen = _keys_of(folder, sorted(done))
    total = int(stamp["count"])
    built = _run_chunks(config, folder, todo, seen, run, total, done)
    catalog, failures = _merged(folder, range(n_chunks))
    return _finish(config, folder, catalog, failures, stamp, n_chunks, built, len(done), run)


def _run_chunks(
    config: BuildConfig,
    folder: Path,
    todo: Iterable[ChunkTask],
    seen: dict[str, str],
    run: _Run,
    total: int,
    done: set[int],
) -> int:
    """Run the chunks ``todo`` on ``run``'s engine, committing each; returns how many were
    built. ``done``: the chunks already committed (their labels counted on the bar of
    ``total``)."""
    engine, workers = run.engine, run.workers
    pool = LocalPool(config, workers) if engine is None and workers > 1 else None
    chosen: Engine = engine if engine is not None else (pool or _InProcessCatalog())
    bar = tqdm(total=total, unit="img", disable=not run.progress, desc="catalog")
    bar.update(sum(pq.read_metadata(part_paths(folder, k)[1]).num_rows for k in done))
    bar.update(sum(pq.read_metadata(part_paths(folder, k)[0]).num_rows for k in done))
    built = 0
    try:
        for result in chosen.run(config, todo):
            _commit(folder, result, seen)
            bar.update(len(result.outcomes))
            built += 1
    finally:
        bar.close()
        if pool is not None:
            pool.close()
    return built


def _run_append(config: BuildConfig, folder: Path, run: _Run) -> CatalogSummary:
    """run_catalog's work for ``append`` (``pipeline.catalog.append``): planned, the base
    snapshot and the stamp written, the new chunks built and committed after the
    catalogue's, the union merged and described; parts/ removed (the stamp first)."""
    plan = plan_catalog_append(config, folder, STAMP)
    full = {"kind": "catalog", **fingerprint(config, labels_of(config))}
    if not plan.labels:  # nothing written (a killed append's leftover base snapshot removed)
        for rel in BASE_FILES.values():
            (folder / rel).unlink(missing_ok=True)
        if (folder / "parts").is_dir() and not any((folder / "parts").iterdir()):
            (folder / "parts").rmdir()
        summary = _finished_doc(folder, plan.base)
        return replace(summary, chunks_resumed=0, seconds=time.perf_counter() - run.start)
    if not plan.resumed:
        snapshot_base(folder)
        atomic_write_bytes(folder / STAMP, json.dumps(plan.stamp).encode())
    first, end = plan.base_chunks, plan.base_chunks + plan.chunks
    size = config.output.shard_size
    done = {k for k in range(first, end) if part_paths(folder, k)[0].exists()}
    todo = (
        ChunkTask(first + i, tuple(labels), job=catalog_chunk)
        for i, labels in enumerate(chunks_of(iter(plan.labels), size))
        if first + i not in done
    )
    seen = dict(plan.keys)
    seen.update(_keys_of(folder, sorted(done)))
    built = _run_chunks(config, folder, todo, seen, run, len(plan.labels), done)
    new_rows, new_failures = _merged(folder, range(first, end))
    base_rows = pq.read_table(plan.base_path("catalog.parquet")).replace_schema_metadata(None)
    base_failures = pq.read_table(plan.base_path("failures.parquet"))
    catalog = pa.concat_tables([base_rows, new_rows.replace_schema_metadata(None)])
    failures = pa.concat_tables(
        [base_failures.replace_schema_metadata(None), new_failures.replace_schema_metadata(None)]
    )
    appends = list(plan.base.get(APPENDS_KEY) or [])
    appends.append(plan.record(config, new_rows.num_rows, new_failures.num_rows))
    return _finish(
        config, folder, catalog, failures, full, end, built, len(done), run,
        chunks=range(first, end), extra={APPENDS_KEY: appends},
    )  # fmt: skip


class _InProcessCatalog(InProcess):
    """The one-process engine (the build's ``InProcess``)."""


def _keys_of(out: Path, done: list[int]) -> dict[str, str]:
    seen: dict[str, str] = {}
    for k in done:
        table = pq.read_table(part_paths(out, k)[0], columns=["key", "label_path"])
        seen.update(zip(table["key"].to_pylist(), table["label_path"].to_pylist(), strict=True))
    return seen


def _commit(out: Path, result: ChunkResult, seen: dict[str, str]) -> None:
    """Write chunk ``result``'s failure part, then its catalogue part (the commit marker); a
    key already catalogued (from an earlier label) becomes a ``record`` failure row."""
    rows: list[dict[str, Any]] = []
    failures: list[dict[str, Any]] = []
    for outcome in result.outcomes:
        if outcome.kind != "ok":
            failures.append(outcome.row)
            continue
        key = outcome.row["key"]
        if key in seen:
            error = DuplicateKeyError(
                f"{outcome.label}: key {key}: already catalogued from {seen[key]}"
            )
            failures.append(worker.failure_row(outcome.label, "record", error))
            continue
        seen[key] = outcome.row["label_path"]
        rows.append(outcome.row)
    catalog_part, failure_part = part_paths(out, result.index)
    write_parquet_atomic(pa.Table.from_pylist(failures, schema=FAILURE_SCHEMA), failure_part)
    write_parquet_atomic(pa.Table.from_pylist(rows, schema=CATALOG_SCHEMA), catalog_part)


def _finished(out: Path, stamp: dict[str, Any]) -> CatalogSummary | None:
    """The summary of the finished catalogue in ``out`` when its stamp is ``stamp``."""
    try:
        doc = json.loads((out / "catalog.json").read_text())
    except (OSError, ValueError):
        return None
    if doc.get("stamp") != stamp_digest(stamp) or (out / STAMP).exists():
        return None
    return _finished_doc(out, doc)


def _finished_doc(out: Path, doc: dict[str, Any]) -> CatalogSummary:
    """The summary of the finished catalogue in ``out`` whose catalog.json is ``doc``."""
    counts = doc.get("counts", {})
    return CatalogSummary(
        out, counts.get("images", 0), counts.get("failures", 0), counts.get("pairs", 0),
        0, doc.get("chunks", 0), 0.0, doc.get("failures_by_reason", {}),
    )  # fmt: skip


def _merged(out: Path, chunks: range) -> tuple[pa.Table, pa.Table]:
    """The catalogue rows and the failure rows of the committed ``chunks``, in chunk order."""
    parts = [pq.read_table(part_paths(out, k)[0]) for k in chunks]
    catalog = pa.concat_tables(parts) if parts else CATALOG_SCHEMA.empty_table()
    failures = pa.concat_tables(
        [pq.read_table(part_paths(out, k)[1]) for k in chunks]
    ) if len(chunks) else FAILURE_SCHEMA.empty_table()  # fmt: skip
    return catalog, failures


def _finish(
    config: BuildConfig,
    out: Path,
    catalog: pa.Table,
    failures: pa.Table,
    stamp: dict[str, Any],
    n_chunks: int,
    built: int,
    resumed: int,
    run: _Run,
    chunks: range | None = None,
    extra: dict[str, Any] | None = None,
) -> CatalogSummary:
    """Write the catalogue's files from its rows (``catalog``: sorted here) and failure rows,
    describe it (``extra``: more keys of catalog.json), remove the parts of ``chunks`` (default
    all ``n_chunks``), the stamp, then the append's base (last), then parts/."""
    catalog = catalog.replace_schema_metadata(None)
    catalog = catalog.sort_by([("hilbert", "ascending"), ("key", "ascending")])
    crs = dataset_crs(config)
    catalog = catalog.replace_schema_metadata(catalog_geo_metadata(crs, _bbox(catalog)))
    write_parquet_atomic(catalog, out / "catalog.parquet", row_group_size=1024)
    write_parquet_atomic(failures, out / "failures.parquet")
    n_pairs = 0
    if run.pairs:
        n_pairs = write_pairs(out / "pairs.parquet", Footprints.from_table(catalog))
    else:  # an appended catalogue's old pairs would not hold the new images
        (out / "pairs.parquet").unlink(missing_ok=True)
    reasons = Counter(
        f"{s} ({e})"
        for s, e in zip(
            failures["stage"].to_pylist(), failures["error_type"].to_pylist(), strict=True
        )
    )
    doc = catalog_doc(config, catalog, failures.num_rows, n_pairs, dict(reasons), stamp, crs)
    doc["chunks"] = n_chunks
    doc.update(extra or {})
    from mars_pairs.store.catalog_card import catalog_card

    atomic_write_bytes(out / "README.md", catalog_card(doc).encode())
    root = Path(labels_root(config.inputs.labels))
    write_stac(out, catalog, crs, doc, root, relative=isinstance(config.output.dir, Path))
    doc[FILES_KEY] = files_record(out, CATALOG_SEALED)
    atomic_write_bytes(out / "catalog.json", json.dumps(doc, indent=2).encode())
    for k in range(n_chunks) if chunks is None else chunks:
        for path in part_paths(out, k):
            path.unlink(missing_ok=True)
    (out / STAMP).unlink(missing_ok=True)
    for rel in BASE_FILES.values():  # after the stamp: see pipeline.catalog.append
        (out / rel).unlink(missing_ok=True)
    (out / "parts").rmdir()
    return CatalogSummary(
        out, catalog.num_rows, failures.num_rows, n_pairs, built, resumed,
        time.perf_counter() - run.start, dict(reasons),
    )  # fmt: skip


def _bbox(table: pa.Table) -> list[float] | None:
    import pyarrow.compute as pc

    if table.num_rows == 0 or table["bbox"].null_count == table.num_rows:
        return None
    col = table["bbox"]
    return [
        pc.min(pc.struct_field(col, "xmin")).as_py(),
        pc.min(pc.struct_field(col, "ymin")).as_py(),
        pc.max(pc.struct_field(col, "xmax")).as_py(),
        pc.max(pc.struct_field(col, "ymax")).as_py(),
    ]


def catalog_doc(
    config: BuildConfig,
    catalog: pa.Table,
    failures: int,
    pairs: int,
    reasons: dict[str, int],
    stamp: dict[str, Any],
    crs: str,
) -> dict[str, Any]:
    """catalog.json: the config (paths relative to the folder), versions, counts, the CRS,
    the footprint's simplification, the inputs' fingerprints and the stamp's digest (no
    timings: a resumed catalogue writes the same bytes)."""
    import numpy
    import pyarrow
    import rasterio
    import shapely

    from mars_pairs.version import __version__

    with rasterio.open(config.inputs.dem) as src:
        cell = float(max(abs(src.res[0]), abs(src.res[1])))
        dem_transform = [float(v) for v in list(src.transform)[:6]]
    wkt = named_wkt(crs)
    return {
        "kind": "mars-pairs footprint catalogue",
        "config": relative_config(config),
        "license": license_of(config),
        "versions": {
            "mars_pairs": __version__,
            "numpy": numpy.__version__,
            "rasterio": rasterio.__version__,
            "pyarrow": pyarrow.__version__,
            "shapely": shapely.__version__,
            "python": platform.python_version(),
        },
        "crs": wkt,
        "crs_name": crs_name(crs),
        "footprint": {
            "source": "the DEM cells in line of sight cut by the edge of the exact view test "
            "(traced on a sub-cell lattice, crossings found by root finding)",
            "dem_cell": cell,
            "dem_transform": dem_transform,
            "simplify_tolerance": SIMPLIFY_CELLS * cell,
            "unit": "map units of the CRS",
            "radius_m": config.geometry.radius,
            "view_mask": config.geometry.view_mask,
        },
        "counts": {
            "images": catalog.num_rows,
            "failures": failures,
            "pairs": pairs,
            "by_mission": dict(Counter(catalog["mission"].to_pylist())),
            "by_instrument": dict(Counter(catalog["instrument"].to_pylist())),
        },
        "failures_by_reason": reasons,
        "input_files": input_files(config),
        "stamp": stamp_digest(stamp),
    }
