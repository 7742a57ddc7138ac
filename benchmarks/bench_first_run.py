"""The first run: a fresh ``mars-pairs viewshed`` process (numba's cache warm and cold), and
the demo's synthetic mission generated with its images rendered in this process (the anchor:
``workers=1``, two rendering threads) and by worker processes.

    python benchmarks/bench_first_run.py [--stops N] [--workers W] [--repeats R]
                                         [--dem-size 4096] [--radius 2000] [--cli-repeats 3]
                                         [--no-mission] [--no-cold]

Fresh processes: ``mars-pairs viewshed`` full circle on a ``--dem-size``^2 fractal DEM
GeoTIFF at 1 m (written to a temporary folder), observer 2 m above its centre, ``--radius``
metres, run as a new process each time: with numba's cache warm (``python -m
mars_pairs.warmup`` ran first) and cold (``NUMBA_CACHE_DIR`` an empty temporary folder: every
kernel the command runs compiles), interleaved with the anchor, ``python -c pass`` (the
interpreter's own start), and ``python -c "import mars_pairs.cli.main"`` (the parser's
imports). Wall seconds (median) and the child's CPU seconds (user + sys).

The mission: generates the demo mission (configs/demo.yaml: seed 0, m2020, size demo, 3
images a stop; ``--stops`` of its 90 stops) into a temporary folder with 1 worker and with
``--workers``, alternated, ``--repeats`` rounds, and checks that every round wrote the same
files, byte for byte (sha256 of every file), as the first. Prints markdown tables (wall
seconds, images/s) with the load average: compare rows of one run only.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_viewshed import X0, Y0, fractal_dem, write_dem

from mars_pairs.runtime import configure_process
from mars_pairs.synth import generate_mission


def _digests(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _load() -> str:
    return ", ".join(f"{v:.1f}" for v in os.getloadavg())


def _child(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, CPU s: user + sys) of ``cmd`` run as a new process; it must succeed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def fresh_processes(dem_size: int, radius: float, repeats: int, cold: bool) -> None:
    """The fresh-process table: ``mars-pairs viewshed`` with a warm and a cold numba cache,
    the interpreter's start and the parser's imports (see the module docstring)."""
    exe = str(Path(sys.executable).with_name("mars-pairs"))
    subprocess.run([sys.executable, "-m", "mars_pairs.warmup"], check=True)
    print(f"\nfresh processes, load average at start: {_load()}")
    with tempfile.TemporaryDirectory() as tmp:
        dem = Path(tmp) / "dem.tif"
        write_dem(dem, fractal_dem(dem_size), 1.0)
        x, y = X0 + dem_size / 2, Y0 - dem_size / 2
        out = str(Path(tmp) / "v.tif")
        viewshed = [exe, "viewshed", "--dem", str(dem), "--out", out, "--x", str(x),
                    "--y", str(y), "--height", "2", "--radius", str(radius)]  # fmt: skip
        rows = {
            "`python -c pass` (the interpreter's start: the anchor)": [
                sys.executable, "-c", "pass"],
            "`import mars_pairs.cli.main` (the parser of every command)": [
                sys.executable, "-c", "import mars_pairs.cli.main"],
            "`mars-pairs viewshed`, numba cache warm": viewshed,
        }  # fmt: skip
        cold_row = "`mars-pairs viewshed`, numba cache cold (every kernel compiles)"
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in rows}
        if cold:
            times[cold_row] = []
        for k in range(repeats):
            for name, cmd in rows.items():
                times[name].append(_child(cmd))
            if cold and k == 0:  # once: it costs tens of CPU seconds
                cache = Path(tmp) / "numba-cache"
                env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
                times[cold_row].append(_child(viewshed, env))
                shutil.rmtree(cache)
    print(f"load average at end: {_load()}")
    print(f"\n{dem_size} x {dem_size} DEM at 1 m, full circle, radius {radius:g} m; median of "
          f"{repeats} (cold: 1 run)\n")  # fmt: skip
    print("| new process | wall (s) | CPU (s) |")
    print("|---|---:|---:|")
    for name, ts in times.items():
        wall = statistics.median(t[0] for t in ts)
        cpu = statistics.median(t[1] for t in ts)
        print(f"| {name} | {wall:.2f} | {cpu:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stops", type=int, default=90)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--dem-size", type=int, default=4096)
    parser.add_argument("--radius", type=float, default=2000.0)
    parser.add_argument("--cli-repeats", type=int, default=3)
    parser.add_argument("--no-mission", action="store_true", help="the fresh processes only")
    parser.add_argument("--no-cold", action="store_true", help="no cold-cache viewshed row")
    args = parser.parse_args()
    configure_process()
    fresh_processes(args.dem_size, args.radius, args.cli_repeats, not args.no_cold)
    if args.no_mission:
        return
    print(f"\nthe mission, load average at start: {_load()}")
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
    print(f"load average at end: {_load()}")
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
