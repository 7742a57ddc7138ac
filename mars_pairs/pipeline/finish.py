"""The end of a build: chunk parts merged into manifest.parquet and failures.parquet, and
dataset.json."""

from __future__ import annotations

import json
import platform
from collections import Counter
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.parquet as pq

from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.outputs import part_paths
from mars_pairs.pipeline.splitting import splits_report
from mars_pairs.store.geoparquet import footprints_bbox, geo_metadata
from mars_pairs.store.manifest import (
    FAILURE_SCHEMA,
    MANIFEST_SCHEMA,
    write_parquet_atomic,
)
from mars_pairs.store.shards import atomic_write_bytes

if TYPE_CHECKING:
    from mars_pairs.pipeline.build import BuildSummary


def merge_parts(config: BuildConfig, n_chunks: int) -> tuple[pa.Table, pa.Table]:
    """Concatenate the chunk parts into manifest.parquet (Hilbert order) and failures.parquet."""
    out = config.output.dir
    parts = [pq.read_table(part_paths(out, k)[1]) for k in range(n_chunks)]
    fails = [pq.read_table(part_paths(out, k)[2]) for k in range(n_chunks)]
    manifest = pa.concat_tables(parts) if parts else MANIFEST_SCHEMA.empty_table()
    manifest = manifest.sort_by([("hilbert", "ascending"), ("key", "ascending")])
    failures = pa.concat_tables(fails) if fails else FAILURE_SCHEMA.empty_table()
    crs = dataset_crs(config)
    manifest = manifest.replace_schema_metadata(geo_metadata(crs, footprints_bbox(manifest)))
    write_parquet_atomic(manifest, out / "manifest.parquet", row_group_size=1024)
    write_parquet_atomic(failures, out / "failures.parquet")
    return manifest, failures


def dataset_crs(config: BuildConfig) -> str:
    import rasterio

    with rasterio.open(config.inputs.dem) as src:
        return src.crs.to_wkt()


def write_dataset_json(
    config: BuildConfig, summary: BuildSummary, manifest: pa.Table, dropped: int
) -> None:
    import numba
    import numpy
    import pyarrow
    import rasterio

    from mars_pairs import __version__

    counts: dict[str, Any] = {"samples": summary.samples, "failures": summary.failures}
    if manifest.num_rows:
        counts["by_split"] = dict(Counter(manifest.column("split").to_pylist()))
        counts["by_mission"] = dict(Counter(manifest.column("mission").to_pylist()))
    doc = {
        "config": config.to_dict(),
        "versions": {
            "mars_pairs": __version__,
            "numpy": numpy.__version__,
            "rasterio": rasterio.__version__,
            "pyarrow": pyarrow.__version__,
            "numba": numba.__version__,
            "python": platform.python_version(),
        },
        "crs": dataset_crs(config),
        "chip": {
            "size_m": config.chips.size_m,
            "size_px": config.chips.size_px,
            "orientation": config.chips.orientation,
        },
        "counts": counts,
        "splits": splits_report(config, manifest, dropped),
        "failures_by_reason": summary.failures_by_reason,
        "build_seconds": round(summary.seconds, 3),
    }
    atomic_write_bytes(config.output.dir / "dataset.json", json.dumps(doc, indent=2).encode())
