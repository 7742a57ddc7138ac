"""Speed of the footprint catalogue.

1. The catalogue against the build, same run, same labels (the demo config's), 2 workers:
   images per second of ``run_catalog`` and of ``run_build`` (the anchor), and their ratio.
2. Pairs of a large synthetic catalogue: N footprints (view wedges of 30-100 m, 3 images a
   stop, stops 8 m apart along a winding traverse) paired by ``store.pairs.write_pairs``, at
   N = 10k, 30k, 100k, on 1 and 2 threads, each in a fresh process: seconds, microseconds
   per image, pairs, peak RSS and its growth during pairing (flat: the pairs are streamed
   to disk block by block), and beside them the largest relative difference of 2,000
   sampled rows' areas from GEOS's own intersection.

usage: python benchmarks/bench_catalog.py [--config C] [--skip-build] [--sizes N ...]
       [--threads T ...]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import shapely

from mars_pairs.store.pairs import Footprints, write_pairs


def synthetic_footprints(n: int, seed: int = 0) -> Footprints:
    """``n`` wedge footprints along a winding traverse (map metres)."""
    rng = np.random.default_rng(seed)
    stops = (n + 2) // 3
    heading = np.cumsum(rng.normal(0, 0.2, stops))
    x = np.cumsum(8.0 * np.cos(heading))
    y = np.cumsum(8.0 * np.sin(heading))
    sx, sy = np.repeat(x, 3)[:n], np.repeat(y, 3)[:n]
    az = rng.uniform(0, 2 * np.pi, n)
    half = np.radians(rng.uniform(10, 25, n))
    reach = rng.uniform(30, 100, n)
    t = np.linspace(-1, 1, 9)
    angles = az[:, None] + half[:, None] * t[None, :]
    ring_x = np.concatenate([sx[:, None], sx[:, None] + reach[:, None] * np.sin(angles)], axis=1)
    ring_y = np.concatenate([sy[:, None], sy[:, None] + reach[:, None] * np.cos(angles)], axis=1)
    coords = np.stack([ring_x, ring_y], axis=-1)
    geoms = shapely.polygons(coords)
    return Footprints(
        keys=np.array([f"img{i:07d}" for i in range(n)], dtype=object),
        geometry=geoms,
        area_m2=shapely.area(geoms),
        lon=sx / 59274.0,
        lat=sy / 59274.0,
        z=np.zeros(n),
        azimuth=np.degrees(az) % 360.0,
        position=np.repeat(np.arange(stops), 3)[:n].astype(str).astype(object),
    )


def rss_mb() -> float:
    """Peak resident set size of this process so far, MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def pairs_once(n: int, threads: int, kernel: bool = True) -> dict[str, float]:
    """Pair ``n`` synthetic footprints into a temporary pairs.parquet (this process: run
    it in a fresh one for its peak RSS); seconds, pairs, peak RSS before and after, and the
    largest relative difference of 2,000 sampled rows' ``intersection_m2`` from GEOS's
    (``shapely.intersection`` of the two footprints). ``kernel`` False: every area from
    GEOS (the anchor: ``KERNEL_VERTICES`` below any pair's). The kernel is loaded first
    (numba's cached code, a constant ~100 MB), outside the measure."""
    import pyarrow.parquet as pq

    from mars_pairs.store import pairs

    if not kernel:
        pairs.KERNEL_VERTICES = -1
    warm = Path(tempfile.mkdtemp(prefix="warm-"))
    write_pairs(warm / "p.parquet", synthetic_footprints(30))
    shutil.rmtree(warm)
    fp = synthetic_footprints(n)
    out = Path(tempfile.mkdtemp(prefix="pairs-")) / "pairs.parquet"
    before = rss_mb()
    start = time.perf_counter()
    count = write_pairs(out, fp, threads=threads)
    seconds = time.perf_counter() - start
    peak = rss_mb()
    table = pq.read_table(out, columns=["key_a", "key_b", "intersection_m2"])
    rows = np.random.default_rng(1).choice(table.num_rows, min(2000, table.num_rows), False)
    row_of = {k: i for i, k in enumerate(fp.keys)}
    a = np.array([row_of[k] for k in table["key_a"].take(rows).to_pylist()])
    b = np.array([row_of[k] for k in table["key_b"].take(rows).to_pylist()])
    geos = shapely.area(shapely.intersection(fp.geometry[a], fp.geometry[b]))
    got = table["intersection_m2"].take(rows).to_numpy()
    shutil.rmtree(out.parent)
    return {
        "seconds": seconds, "pairs": count, "before": before, "peak": peak,
        "rel": float(np.max(np.abs(got - geos) / geos)),
    }  # fmt: skip


def bench_pairs(sizes: list[int], threads: list[int]) -> None:
    """Each size and thread count in a fresh process (its own peak RSS), interleaved with
    the anchor: GEOS for every area, on the most threads."""
    import json
    import os
    import subprocess
    import sys

    print(f"load average {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f}")
    print(
        "| footprints | areas | threads | seconds | us / image | pairs | peak RSS (MB) |"
        " peak RSS growth while pairing (MB) | max rel. diff. from GEOS (2,000 rows) |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")  # fmt: skip
    for n in sizes:
        for t, kernel in [*((t, True) for t in threads), (max(threads), False)]:
            call = f"b.pairs_once({n}, {t}, {kernel})"
            code = f"import json, bench_catalog as b; print(json.dumps({call}))"
            env = dict(os.environ, PYTHONPATH=str(Path(__file__).parent))
            done = subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
            )
            r = json.loads(done.stdout.strip().splitlines()[-1])
            print(
                f"| {n:,} | {'kernel' if kernel else 'GEOS'} | {t} | {r['seconds']:.2f} | "
                f"{r['seconds'] / n * 1e6:.1f} | "
                f"{r['pairs']:,} | {r['peak']:.0f} | {r['peak'] - r['before']:.0f} | "
                f"{r['rel']:.1e} |",
                flush=True,
            )
    print(f"load average {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f}")


_ENGINE_CHILD = """
import json, resource, sys, threading, time
from dataclasses import replace
from pathlib import Path
from mars_pairs.runtime import configure_process
configure_process()
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.pipeline.config import load_config
config_path, name, out, workers = sys.argv[1], sys.argv[2], Path(sys.argv[3]), int(sys.argv[4])
seen, done = {}, threading.Event()

def poll():  # the worker processes' CPU (they are not this process's children to reap)
    import psutil
    me = psutil.Process()
    while True:
        for proc in me.children(recursive=True):
            try:
                times = proc.cpu_times()
                seen[proc.pid] = times.user + times.system
            except psutil.Error:
                pass
        if done.wait(0.05):
            return

poller = threading.Thread(target=poll, daemon=True)
poller.start()
config = load_config(config_path)
start = time.perf_counter()
if name == "build":
    cfg = replace(config, output=replace(config.output, dir=out))
    n = run_build(cfg, workers=workers, progress=False).samples
else:
    n = run_catalog(config, out, workers=workers, progress=False).images
seconds = time.perf_counter() - start
done.set()
poller.join()
own = resource.getrusage(resource.RUSAGE_SELF)
cpu = own.ru_utime + own.ru_stime + sum(seen.values())
print(json.dumps({"images": n, "seconds": seconds, "cpu": cpu}))
"""


def bench_engines(config_path: str, workers: int, reps: int = 2) -> None:
    """The build and the catalogue of the same labels on ``workers`` processes, each run a
    fresh process, interleaved (build, catalogue, build, ...), ``reps`` each: images per
    second (wall, from the run's start to its summary, imports excluded) and CPU per image
    (the run's process, imports included, plus its workers' polled every 50 ms), best of
    the reps; ratios to the build."""
    import json
    import subprocess
    import sys

    base = Path(tempfile.mkdtemp(prefix="bench-catalog-"))
    best: dict[str, dict[str, float]] = {}
    loads = [os.getloadavg()[0]]
    for rep in range(reps):
        for name in ("build", "catalog"):
            out = base / f"{name}-{rep}"
            done = subprocess.run(
                [sys.executable, "-c", _ENGINE_CHILD, config_path, name, str(out), str(workers)],
                capture_output=True, text=True, check=True,
            )  # fmt: skip
            r = json.loads(done.stdout.strip().splitlines()[-1])
            shutil.rmtree(out, ignore_errors=True)
            old = best.get(name)
            best[name] = {
                "images": r["images"],
                "seconds": min(r["seconds"], old["seconds"]) if old else r["seconds"],
                "cpu": min(r["cpu"], old["cpu"]) if old else r["cpu"],
            }
            loads.append(os.getloadavg()[0])
    anchor = best["build"]
    print(f"load average {min(loads):.2f} .. {max(loads):.2f}")
    print(
        f"| run ({workers} workers, best of {reps}) | images | seconds | images/s | "
        "ratio to build | CPU ms / image | CPU ratio (build / this) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, r in best.items():
        rate = r["images"] / r["seconds"]
        cpu = r["cpu"] / r["images"] * 1e3
        print(
            f"| {name} | {r['images']:.0f} | {r['seconds']:.1f} | {rate:.1f} | "
            f"{rate / (anchor['images'] / anchor['seconds']):.2f}x | {cpu:.1f} | "
            f"{anchor['cpu'] / anchor['images'] / (r['cpu'] / r['images']):.2f}x |"
        )
    shutil.rmtree(base)


def main() -> None:
    from mars_pairs import runtime

    runtime.configure_process()  # as a worker runs: no OpenMP busy-wait in this process
    parser = argparse.ArgumentParser()
    parser.add_argument("--config", default="configs/demo.yaml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-build", action="store_true")
    parser.add_argument("--sizes", type=int, nargs="*", default=[10_000, 30_000, 100_000])
    parser.add_argument("--threads", type=int, nargs="*", default=[1, 2])
    args = parser.parse_args()
    if not args.skip_build:
        bench_engines(args.config, args.workers)
        print()
        bench_per_image(args.config)
        print()
    bench_pairs(args.sizes, args.threads)


def bench_per_image(config_path: str, count: int = 270) -> None:
    """Per image in one process, start-up excluded: the build's ``build_sample`` against the
    catalogue's ``catalog_entry`` on the same labels (the first one warms both), CPU time
    (``time.process_time``), interleaved: each label through both in turn."""
    from mars_pairs.pipeline.builder.label_list import iter_matches
    from mars_pairs.pipeline.catalog.entry import catalog_entry
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.pipeline.sample.build_sample import build_sample
    from mars_pairs.pipeline.sample.context import SampleContext

    config = load_config(config_path)
    labels = [Path(p) for p in list(iter_matches(config.inputs.labels))[: count + 1]]
    ctx = SampleContext.open(config)
    fns = {"build_sample": build_sample, "catalog_entry": catalog_entry}
    cpu = dict.fromkeys(fns, 0.0)
    for fn in fns.values():
        fn(labels[0], ctx)
    for label in labels[1:]:
        for name, fn in fns.items():
            start = time.process_time()
            fn(label, ctx)
            cpu[name] += time.process_time() - start
    ctx.close()
    n = len(labels) - 1
    print(f"load average {os.getloadavg()[0]:.2f}")
    print("| per image, one process (start-up excluded) | CPU ms / image | ratio to build |")
    print("|---|---:|---:|")
    for name, seconds in cpu.items():
        print(f"| {name} | {seconds / n * 1e3:.2f} | {cpu['build_sample'] / seconds:.2f}x |")


if __name__ == "__main__":
    main()
