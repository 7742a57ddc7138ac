"""Build throughput: samples/s with 1 and 2 workers on the local and the Dask engine.

    python benchmarks/bench_build.py [--stops K] [--images-per-stop M] [--mission DIR]
                                     [--dense]

Generates a synthetic mission (64 stops x 8 images = 512 samples by default; generating it
takes minutes, so ``--mission DIR`` keeps it in DIR and reuses it) and builds it with 512 px
chips on each engine (Dask: a LocalCluster of processes, one thread each; the times include
the start-up of the cluster or the pool), and prints a markdown table with the load average.
The anchor is the study's QGIS tool: tens of seconds per image. ``--dense`` adds, in the
same run, the local 1-worker build with every dense member on (``output.members: all``)
against the same build without them, alternated, best of 2 each, and each dense member's
mean size per sample.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from mars_pairs.pipeline.build import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.synth import generate_mission

STUDY_SECONDS_PER_IMAGE = 20.0  # "tens of seconds per image" (Sheppard and Skinner)


def _config(mission: Path, out: Path, members: str | None = None) -> dict:
    doc = {
        "inputs": {
            "labels": str(mission / "labels" / "*.xml"),
            "places": str(mission / "places" / "best_interp.csv"),
            "dem": str(mission / "orbital" / "dem.tif"),
            "ortho": str(mission / "orbital" / "ortho.tif"),
        },
        "geometry": {"radius": 1000, "viewshed": "both", "ray_stride": 8},
        "chips": {"size_m": 256, "size_px": 512},
        "output": {"dir": str(out), "shard_size": 16},
        "splits": {"block_m": 200},
    }
    if members is not None:
        doc["output"]["members"] = members  # type: ignore[index]
    return doc


def dense_rows(mission: Path, root: Path) -> list[str]:
    """The lines of samples/s without and with every dense member (local, 1 worker, alternated,
    best of 2) and the dense members' mean sizes."""
    import pyarrow.parquet as pq

    from mars_pairs.store.manifest import DENSE_FIELDS

    best = {"off": 0.0, "on": 0.0}
    n = 0
    for rep in range(2):
        for mode in ("off", "on"):
            out = root / f"dense-{mode}{rep}"
            cfg = parse_config(_config(mission, out, "all" if mode == "on" else None), root)
            summary = run_build(cfg, workers=1, progress=False)
            n = summary.samples
            best[mode] = max(best[mode], summary.samples / summary.seconds)
    lines = [f"\n| dense members ({n} samples, local, 1 worker) | samples/s | vs off |",
             "|---|---:|---:|"]  # fmt: skip
    for mode in ("off", "on"):
        lines.append(f"| {mode} | {best[mode]:.1f} | {best[mode] / best['off']:.2f}x |")
    table = pq.read_table(root / "dense-on0" / "manifest.parquet")
    lines += ["\n| member | mean KiB per sample |", "|---|---:|"]
    for field in ("ground", "ortho", "dem", "viewshed", "corr", *DENSE_FIELDS):
        if f"{field}_size" in table.column_names:
            size = table[f"{field}_size"].to_numpy().mean() / 1024
            lines.append(f"| {field} | {size:.1f} |")
    return lines


def _engine(name: str, workers: int) -> object:
    if name == "local":
        return None
    from mars_pairs.pipeline.dask_engine import DaskEngine

    return DaskEngine(workers=workers, announce=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--stops", type=int, default=64)
    parser.add_argument("--images-per-stop", type=int, default=8)
    parser.add_argument("--mission", type=Path, help="keep (or reuse) the mission here")
    parser.add_argument("--engines", default="local,dask")
    parser.add_argument("--dense", action="store_true", help="dense members on vs off")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        mission = args.mission or root / "mission"
        t = time.perf_counter()
        if not (mission / "places").is_dir():
            generate_mission(mission, seed=0, mission="m2020", stops=args.stops,
                             images_per_stop=args.images_per_stop, size="small")  # fmt: skip
        gen = time.perf_counter() - t
        # warm numba caches and the OS file cache, not timed
        run_build(parse_config(_config(mission, root / "warm"), root), progress=False,
                  limit=4)  # fmt: skip
        if args.dense:
            run_build(parse_config(_config(mission, root / "warm-dense", "all"), root),
                      progress=False, limit=4)  # fmt: skip
        rows = []
        stages: dict[str, float] = {}
        for name in args.engines.split(","):
            for workers in (1, 2):
                engine = _engine(name, workers)
                cfg = parse_config(_config(mission, root / f"ds-{name}{workers}"), root)
                before = os.getloadavg()[0]
                summary = run_build(cfg, workers=workers, progress=False, engine=engine)
                rate = summary.samples / summary.seconds
                load = max(before, os.getloadavg()[0])
                rows.append((name, workers, summary.samples, summary.seconds, rate, load))
                if workers == 1 and name == "local":
                    stages = {k: v / max(summary.samples, 1)
                              for k, v in summary.stage_seconds.items()}  # fmt: skip
        dense = dense_rows(mission, root) if args.dense else []
    print(f"build benchmark: {rows[0][2]} samples, 512 px chips, radius 1000 m, "
          f"ray stride 8; mission ready in {gen:.1f} s; {os.cpu_count()} cores\n")  # fmt: skip
    print("| engine | workers | samples | seconds | samples/s | load (1 min) | vs study |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, workers, n, secs, rate, load in rows:
        print(
            f"| {name} | {workers} | {n} | {secs:.2f} | {rate:.1f} | {load:.2f} "
            f"| {rate * STUDY_SECONDS_PER_IMAGE:.0f}x |"
        )
    print("\n| stage (1 worker) | ms per sample |")
    print("|---|---:|")
    for name, secs in stages.items():
        print(f"| {name} | {secs * 1000:.1f} |")
    print(f"| **total** | {sum(stages.values()) * 1000:.1f} |")
    print("\n".join(dense))


if __name__ == "__main__":
    main()
