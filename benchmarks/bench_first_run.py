"""The first run's mission: the demo's synthetic mission generated with its images rendered
in this process (the anchor: ``workers=1``, two rendering threads) and by worker processes.

    python benchmarks/bench_first_run.py [--stops N] [--workers W] [--repeats R]

Generates the demo mission (configs/demo.yaml: seed 0, m2020, size demo, 3 images a stop;
``--stops`` of its 90 stops) into a temporary folder with 1 worker and with ``--workers``,
alternated, ``--repeats`` rounds, and checks that every round wrote the same files, byte for
byte (sha256 of every file), as the first. Prints a markdown table (wall seconds, images/s)
with the load average: compare rows of one run only.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

from mars_pairs.runtime import configure_process
from mars_pairs.synth import generate_mission


def _digests(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stops", type=int, default=90)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    configure_process()
    print(f"load average at start: {', '.join(f'{v:.1f}' for v in os.getloadavg())}")
    times: dict[int, list[float]] = {1: [], args.workers: []}
    reference: dict[str, str] | None = None
    same = True
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for workers in times:
                out = Path(tmp) / f"w{workers}"
                t = time.perf_counter()
                result = generate_mission(
                    out,
                    seed=0,
                    mission="m2020",
                    stops=args.stops,
                    images_per_stop=3,
                    size="demo",
                    workers=workers,
                )
                times[workers].append(time.perf_counter() - t)
                digests = _digests(out)
                reference = reference or digests
                same = same and digests == reference
                shutil.rmtree(out)
    images = result["images"]
    print(f"load average at end: {', '.join(f'{v:.1f}' for v in os.getloadavg())}")
    print(
        f"\n{images} images ({args.stops} stops), best of {args.repeats}; bytes identical: {same}\n"
    )
    print("| render | mission generation (s) | images/s | vs 1 worker |")
    print("|---|---:|---:|---:|")
    base = min(times[1])
    for workers, ts in times.items():
        best = min(ts)
        label = "1 worker (this process, 2 threads)" if workers == 1 else f"{workers} workers"
        print(f"| {label} | {best:.1f} | {images / best:.1f} | {base / best:.2f}x |")


if __name__ == "__main__":
    main()
