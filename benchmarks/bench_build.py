"""Build throughput on the demo mission: samples/s with 1 and 2 workers, time per stage.

    python benchmarks/bench_build.py [--images-per-stop M] [--stops K]

Generates the synthetic mission (configs/demo.yaml's, or larger with the options) into a
temporary folder, builds it with 512 px chips, and prints a markdown table. The anchor is the
study's QGIS tool: tens of seconds per image.
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


def _config(mission: Path, out: Path) -> dict:
    return {
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--stops", type=int, default=8)
    parser.add_argument("--images-per-stop", type=int, default=8)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        generate_mission(root / "mission", seed=0, mission="m2020", stops=args.stops,
                         images_per_stop=args.images_per_stop, size="small")  # fmt: skip
        gen = time.perf_counter() - t
        # warm numba caches and the OS file cache, not timed
        run_build(parse_config(_config(root / "mission", root / "warm"), root), progress=False,
                  limit=4)  # fmt: skip
        rows = []
        stages: dict[str, float] = {}
        for workers in (1, 2):
            cfg = parse_config(_config(root / "mission", root / f"ds{workers}"), root)
            summary = run_build(cfg, workers=workers, progress=False)
            rate = summary.samples / summary.seconds
            rows.append((workers, summary.samples, summary.seconds, rate))
            if workers == 1:
                stages = {k: v / max(summary.samples, 1) for k, v in summary.stage_seconds.items()}
    load = os.getloadavg()
    print(f"build benchmark: {rows[0][1]} samples, 512 px chips, radius 1000 m, "
          f"ray stride 8; mission generated in {gen:.1f} s; load {load[0]:.2f} on "
          f"{os.cpu_count()} cores\n")  # fmt: skip
    print("| workers | samples | seconds | samples/s | vs study (1 image / 20 s) |")
    print("|---:|---:|---:|---:|---:|")
    for workers, n, secs, rate in rows:
        print(
            f"| {workers} | {n} | {secs:.2f} | {rate:.1f} | {rate * STUDY_SECONDS_PER_IMAGE:.0f}x |"
        )
    print("\n| stage (1 worker) | ms per sample |")
    print("|---|---:|")
    for name, secs in stages.items():
        print(f"| {name} | {secs * 1000:.1f} |")
    print(f"| **total** | {sum(stages.values()) * 1000:.1f} |")


if __name__ == "__main__":
    main()
