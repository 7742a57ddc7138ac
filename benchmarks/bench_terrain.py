"""What terrain labels cost a build, and how long merging them into one map takes.

    python benchmarks/bench_terrain.py [--mission DIR] [--images N] [--repeats R]

Builds the first ``--images`` labels of a synthetic mission generated with its AI4Mars-layout
truth (``mars-pairs synth --size demo --terrain-labels``; ``--mission DIR`` reuses one, else a
demo-size mission of 20 stops is generated into a temporary folder) with the demo's geometry
(radius 100 m, 128 m chips of 256 px, the local engine with 1 worker: the build in this
process), without terrain labels (the anchor) and with them (``inputs.terrain_labels``: the
``terrain`` and ``terrain_on_map`` members and the class-count columns), alternated, best of
``--repeats`` each, in the same run. Then ``terrain-map`` over the labelled build (best of
``--repeats``; CPU seconds of this process beside the wall time). Prints markdown tables with
the load average: compare rows of one run only.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.runtime import configure_process
from mars_pairs.synth import generate_mission


def _config(mission: Path, out: Path, labels: list[str], terrain: bool) -> dict:
    inputs = {
        "labels": labels,
        "places": str(mission / "places" / "best_interp.csv"),
        "dem": str(mission / "orbital" / "dem.tif"),
        "ortho": str(mission / "orbital" / "ortho.tif"),
    }
    if terrain:
        inputs["terrain_labels"] = {"format": "ai4mars", "root": str(mission / "ai4mars")}  # type: ignore[assignment]
    return {
        "inputs": inputs,
        "geometry": {"radius": 100, "viewshed": "both", "ray_stride": 8},
        "chips": {"size_m": 128, "size_px": 256},
        "output": {"dir": str(out), "shard_size": 32},
        "splits": {"block_m": 200},
    }


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission", type=Path, help="a mission with ai4mars/ (kept, reused)")
    parser.add_argument("--images", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    configure_process()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        mission = args.mission
        if mission is None or not (mission / "ai4mars").is_dir():
            mission = mission or root / "mission"
            generate_mission(mission, seed=0, stops=20, images_per_stop=3, size="demo",
                             terrain_labels=True)  # fmt: skip
        labels = sorted(str(p) for p in (mission / "labels").glob("*.xml"))[: args.images]
        load0 = os.getloadavg()
        best = {"off": 0.0, "on": 0.0}
        n = 0
        for rep in range(args.repeats):
            for mode in ("off", "on"):
                out = root / f"{mode}{rep}"
                doc = _config(mission, out, labels, terrain=mode == "on")
                summary = run_build(parse_config(doc, root), workers=1, progress=False)
                n = summary.samples
                best[mode] = max(best[mode], summary.samples / summary.seconds)
        from mars_pairs.cli.terrain_map import merge_splits

        wall, cpu, got = float("inf"), float("inf"), {}
        for rep in range(args.repeats):
            t0, c0 = time.perf_counter(), _cpu()
            got = merge_splits(root / "on0", root / f"map{rep}.tif", None)
            wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, _cpu() - c0)
        load1 = os.getloadavg()
    print(f"{n} samples of {mission}, local engine, 1 worker, best of {args.repeats}; "
          f"{os.cpu_count()} CPUs, load average {', '.join(f'{v:.2f}' for v in load0)} before, "
          f"{', '.join(f'{v:.2f}' for v in load1)} after\n")  # fmt: skip
    print("| build | samples/s | vs without |\n|---|---:|---:|")
    for mode, name in (("off", "without terrain labels"), ("on", "with terrain labels")):
        print(f"| {name} | {best[mode]:.2f} | {best[mode] / best['off']:.2f}x |")
    print(f"\n| terrain-map over {got.get('samples')} samples | wall s | CPU s |\n|---|---:|---:|")
    print(f"| {got.get('cells_seen')} cells seen | {wall:.2f} | {cpu:.2f} |")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
