"""Benchmark: a small bounding-box query on a 1,000,000-row manifest, pushed down vs full scan.

    python benchmarks/bench_manifest.py                  # 1,000,000 rows, row groups of 10,000
    python benchmarks/bench_manifest.py --rows 200000 --repeats 3

Writes a synthetic manifest (every ``MANIFEST_SCHEMA`` column; seeded random rover positions
over Jezero crater, sorted by ``mars_pairs.store.splits.hilbert_index``) with
``mars_pairs.store.atomic.write_parquet_atomic`` to a temp dir, then prints a markdown table of
median wall times (ms; warm-up first) for one small box (--box-deg on a side):

- ``Manifest.open(dir).filter(bbox_lonlat=...)``: ``len()``, ``to_table(columns=[key,
  shard/offset/size])`` and ``to_table()`` (all columns); open included;
- full scans + a numpy mask: ``pq.read_table`` of all columns (then ``take`` of the matching
  rows), and of only the longitude/latitude columns (the cheapest possible scan).

Targets: the pushed-down query <= 100 ms and >= 10x faster than the full scan. The ratio
column is the all-columns full scan's time over the row's time.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mars_pairs.geometry.body import MARS_RADIUS_M  # noqa: E402
from mars_pairs.store.atomic import write_parquet_atomic  # noqa: E402
from mars_pairs.store.manifest import MANIFEST_SCHEMA  # noqa: E402
from mars_pairs.store.members import MEMBERS  # noqa: E402
from mars_pairs.store.query import Manifest  # noqa: E402
from mars_pairs.store.splits import hilbert_index  # noqa: E402

# Jezero crater (planetocentric degrees): (west, south, east, north)
JEZERO = (77.25, 18.30, 77.60, 18.60)


def synthetic_manifest(n: int, seed: int = 0) -> pa.Table:
    """``n`` rows of MANIFEST_SCHEMA: random positions over Jezero, Hilbert-sorted."""
    rng = np.random.default_rng(seed)
    w, s, e, north = JEZERO
    lon = rng.uniform(w, e, n)
    lat = rng.uniform(s, north, n)
    # equirectangular map coordinates (metres), standard parallel 0
    x = np.radians(lon) * MARS_RADIUS_M
    y = np.radians(lat) * MARS_RADIUS_M
    bounds = (float(x.min()), float(y.min()), float(x.max()), float(y.max()))
    order = np.argsort(hilbert_index(x, y, bounds), kind="stable")
    lon, lat, x, y = lon[order], lat[order], x[order], y[order]
    hilbert = hilbert_index(x, y, bounds)

    ids = np.arange(n)
    sol = rng.integers(1, 1200, n).astype(np.int32)
    pid = pa.array([f"ZLF_{i:09d}_ECM_N0000000ZCAM00000_034085J01" for i in ids])
    shard_of = ids // 1000
    shards = pa.array([f"shards/shard-{k:06d}.tar" for k in range(int(shard_of.max()) + 1)])
    shard_col = pa.DictionaryArray.from_arrays(pa.array(shard_of, pa.int32()), shards)
    shard_col = shard_col.cast(pa.string())
    split = np.array(["train", "val", "test"])[rng.choice(3, n, p=[0.7, 0.15, 0.15])]
    half = 128.0
    cols: dict[str, pa.Array | np.ndarray] = {
        "key": pa.array([f"m2020_{i:09d}" for i in ids]),
        "mission": pa.array(["m2020"] * n),
        "instrument": pa.array(np.where(ids % 2 == 0, "MCZ_LEFT", "MCZ_RIGHT")),
        "product_id": pid,
        "label_path": pa.array([f"labels/{i:09d}.xml" for i in ids]),
        "sol": sol,
        "site": (sol // 10).astype(np.int32),
        "drive": rng.integers(0, 3000, n).astype(np.int32),
        "pose": rng.integers(0, 20, n).astype(np.int32),
        "time": pa.array((1.6e12 + sol.astype(np.int64) * 88775244).astype(np.int64)).cast(
            pa.timestamp("ms", tz="UTC")
        ),
        "latitude": lat,
        "longitude": lon,
        "easting": x,
        "northing": y,
        "elevation_m": rng.normal(-2550.0, 30.0, n),
        "azimuth_deg": rng.uniform(0, 360, n),
        "elevation_deg": rng.uniform(-30, 10, n),
        "hfov_deg": np.full(n, 19.2),
        "vfov_deg": np.full(n, 14.0),
        "width": np.full(n, 1648, np.int32),
        "height": np.full(n, 1200, np.int32),
        "localization": pa.array(["places"] * n),
        "viewshed_area_m2": rng.uniform(1e2, 1e5, n),
        "visible_cells": rng.integers(10, 100000, n),
        "max_visible_range_m": rng.uniform(5, 1000, n),
        "ray_hit_fraction": rng.uniform(0, 1, n),
        "footprint": pa.nulls(n, pa.binary()),
        "chip_xmin": x - half,
        "chip_ymin": y - half,
        "chip_xmax": x + half,
        "chip_ymax": y + half,
        "chip_rotation_deg": np.zeros(n),
        "split": pa.array(split),
        "hilbert": hilbert.astype(np.int64),
        "ground_member": pa.array(["ground.jpg"] * n),
    }
    offset = ids % 1000 * 2_000_000
    for k, m in enumerate(MEMBERS):
        cols[f"{m}_shard"] = shard_col
        cols[f"{m}_offset"] = offset + k * 400_000
        cols[f"{m}_size"] = rng.integers(300, 400_000, n)
    arrays = [pa.array(cols[f.name], f.type) for f in MANIFEST_SCHEMA]
    return pa.Table.from_arrays(arrays, schema=MANIFEST_SCHEMA)


def median_ms(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Median wall time (ms) over ``repeats`` runs after one warm-up; and the last result."""
    result = fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rows", type=int, default=1_000_000)
    p.add_argument("--row-group", type=int, default=10_000)
    p.add_argument("--box-deg", type=float, default=0.01, help="query box side (degrees)")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench-manifest-") as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        table = synthetic_manifest(args.rows, args.seed)
        t_gen = time.perf_counter() - t
        t = time.perf_counter()
        write_parquet_atomic(table, root / "manifest.parquet", row_group_size=args.row_group)
        t_write = time.perf_counter() - t
        del table
        meta = pq.ParquetFile(root / "manifest.parquet").metadata
        size_mb = (root / "manifest.parquet").stat().st_size / 1e6

        cx, cy = 77.43, 18.45  # near the Perseverance landing site
        h = args.box_deg / 2
        box = (cx - h, cy - h, cx + h, cy + h)
        light = ["key", *(f"{m}_{c}" for m in ("ground", "ortho") for c in ("shard", "offset"))]

        def pushed_len() -> int:
            return len(Manifest.open(root).filter(bbox_lonlat=box))

        def pushed_light() -> int:
            return Manifest.open(root).filter(bbox_lonlat=box).to_table(columns=light).num_rows

        def pushed_all() -> int:
            return Manifest.open(root).filter(bbox_lonlat=box).to_table().num_rows

        def mask(t: pa.Table) -> np.ndarray:
            lon = t.column("longitude").to_numpy()
            lat = t.column("latitude").to_numpy()
            return np.flatnonzero(
                (lon >= box[0]) & (lon <= box[2]) & (lat >= box[1]) & (lat <= box[3])
            )

        def scan_all() -> int:
            t = pq.read_table(root / "manifest.parquet")
            return t.take(mask(t)).num_rows

        def scan_lonlat() -> int:
            t = pq.read_table(root / "manifest.parquet", columns=["longitude", "latitude"])
            return len(mask(t))

        cases: list[tuple[str, Callable[[], int]]] = [
            ("full scan (all columns) + numpy mask + take", scan_all),
            ("full scan (lon/lat columns only) + numpy mask", scan_lonlat),
            ("Manifest.filter(bbox_lonlat).to_table() (all columns)", pushed_all),
            ("Manifest.filter(bbox_lonlat).to_table(key + 4 offsets)", pushed_light),
            ("len(Manifest.filter(bbox_lonlat))", pushed_len),
        ]
        results = [(label, *median_ms(fn, args.repeats)) for label, fn in cases]

    counts = {r[2] for r in results}
    assert len(counts) == 1, f"the queries disagree: {results}"
    expected = (
        args.rows
        * (args.box_deg / (JEZERO[2] - JEZERO[0]))
        * (args.box_deg / (JEZERO[3] - JEZERO[1]))
    )
    print(
        f"\n{args.rows:,} rows in {meta.num_row_groups} row groups of {args.row_group:,} "
        f"({size_mb:.0f} MB, zstd; generated in {t_gen:.1f} s, written in {t_write:.1f} s); "
        f"box {args.box_deg} deg ({math.radians(args.box_deg) * MARS_RADIUS_M / 1e3:.2f} km) "
        f"-> {counts.pop():,} rows (expected ~{expected:.0f})\n"
    )
    base = results[0][1]
    print("| query | median ms | speed-up vs full scan |")
    print("|---|---:|---:|")
    for label, ms, _ in results:
        print(f"| {label} | {ms:.1f} | {base / ms:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
