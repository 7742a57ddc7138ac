"""Build throughput and the driver's own CPU per sample, on the local and the Dask engine.

    python benchmarks/bench_build.py [--stops K] [--images-per-stop M] [--size-px P]
                                     [--shard-size S] [--mission DIR] [--engines local,dask]
                                     [--dense]
    python benchmarks/bench_build.py --scale [--sizes 10000 100000]
    python benchmarks/bench_build.py --slope [--anchor-root DIR] [--slope-sizes 135 270]
                                     [--slope-reps 3] [--workers W] [--mission DIR]

Generates a synthetic mission (64 stops x 8 images = 512 samples by default; generating it
takes minutes, so ``--mission DIR`` keeps it in DIR and reuses it) and builds it with
``--size-px`` chips: on the local engine with 1 worker (the build in the driver process: the
anchor) and 2 worker processes, and on Dask with an external scheduler and 2 workers
(``dask scheduler`` and ``dask worker`` started here as subprocesses, so the driver's CPU
is the client's alone). The times include the start-up of the pool or the client.

The driver's CPU is ``resource.getrusage(RUSAGE_SELF)`` of this process over the build
(worker processes excluded), and of it the part that grows with the samples (streaming:
without the planning and finishing steps, timed apart); the target is <= 0.3 ms per sample.
The driver saturates at about (worker ms per sample) / (streaming driver ms per sample)
workers: the projection column, with the worker cost taken from the 1-worker build's stage
times. Prints markdown tables with the load average; the other anchor is the study's QGIS
tool: tens of seconds per image. ``--dense`` adds, in the same run, the local 1-worker build
with every dense member on (``output.members: all``) against the same build without them,
alternated, best of 2 each: samples/s and this process's CPU ms per sample (all its
threads: numba's too), and each member's mean size per sample. ``--scale``
instead runs ``bench_scale.py``: the driver's peak memory and CPU per label at ``--sizes``
labels, the chunk job stubbed.

``--slope`` instead measures the build's marginal CPU per sample on the demo's labels
(``configs/demo.yaml``; its mission in ``out/demo/mission`` unless ``--mission``, generated
when absent): each build a fresh subprocess (``--workers`` 1: in the process; more: a local
pool) over N and 2N labels (``--slope-sizes``): the first 2N in name order, and every other
one of them (so both sets, and the N samples between them, mix the cameras as the archive
does: the demo's names list the Navcam frames first), its CPU the process's own
(``getrusage``) plus its worker processes' (psutil, polled every 50 ms). The slope
(CPU(2N) - CPU(N)) / (2N - N samples), from each size's least CPU over the reps, leaves out
what a build pays once (imports, loading the compiled kernels, opening the rasters, the
finish). ``--anchor-root DIR``: a checkout of another commit (``git worktree add DIR
COMMIT``) built the same way, interleaved with this one in the same run; its kernels are
compiled (or loaded) in an untimed warm-up build first.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.runtime import configure_process
from mars_pairs.synth import generate_mission

STUDY_SECONDS_PER_IMAGE = 20.0  # "tens of seconds per image" (Sheppard and Skinner)
TARGET_DRIVER_MS = 0.3  # driver CPU per sample that lets one driver feed ~100 workers


def _config(
    mission: Path, out: Path, size_px: int, shard_size: int = 16, members: str | None = None
) -> dict:
    doc = {
        "inputs": {
            "labels": str(mission / "labels" / "*.xml"),
            "places": str(mission / "places" / "best_interp.csv"),
            "dem": str(mission / "orbital" / "dem.tif"),
            "ortho": str(mission / "orbital" / "ortho.tif"),
        },
        "geometry": {"radius": 1000, "viewshed": "both", "ray_stride": 8},
        "chips": {"size_m": 256, "size_px": size_px},
        "output": {"dir": str(out), "shard_size": shard_size},
        "splits": {"block_m": 200},
    }
    if members is not None:
        doc["output"]["members"] = members  # type: ignore[index]
    return doc


def dense_rows(mission: Path, root: Path, size_px: int) -> list[str]:
    """The lines of samples/s and CPU ms a sample (this process's, all its threads) without
    and with every dense member (local, 1 worker, alternated, best of 2 each) and the
    dense members' mean sizes."""
    import pyarrow.parquet as pq

    from mars_pairs.store.members import DENSE_FIELDS

    best = {"off": 0.0, "on": 0.0}
    cpu_ms = {"off": float("inf"), "on": float("inf")}
    n = 0
    for rep in range(2):
        for mode in ("off", "on"):
            out = root / f"dense-{mode}{rep}"
            members = "all" if mode == "on" else None
            cfg = parse_config(_config(mission, out, size_px, members=members), root)
            start = _cpu()
            summary = run_build(cfg, workers=1, progress=False)
            n = summary.samples
            best[mode] = max(best[mode], summary.samples / summary.seconds)
            cpu_ms[mode] = min(cpu_ms[mode], 1000 * (_cpu() - start) / summary.samples)
    lines = [f"\n| dense members ({n} samples, local, 1 worker) | samples/s | vs off "
             "| CPU ms/sample | vs off (by CPU) |",
             "|---|---:|---:|---:|---:|"]  # fmt: skip
    for mode in ("off", "on"):
        lines.append(
            f"| {mode} | {best[mode]:.1f} | {best[mode] / best['off']:.2f}x "
            f"| {cpu_ms[mode]:.1f} | {cpu_ms['off'] / cpu_ms[mode]:.2f}x |"
        )
    table = pq.read_table(root / "dense-on0" / "manifest.parquet")
    lines += ["\n| member | mean KiB per sample |", "|---|---:|"]
    for field in ("ground", "ortho", "dem", "viewshed", "corr", *DENSE_FIELDS):
        if f"{field}_size" in table.column_names:
            size = table[f"{field}_size"].to_numpy().mean() / 1024
            lines.append(f"| {field} | {size:.1f} |")
    return lines


def _cpu() -> float:
    """This process's CPU seconds (user + system, all its threads, no children)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


_ENDS = ("plan_build", "merge_parts", "write_dataset_json", "write_wids_index", "write_card",
         "remove_parts")  # fmt: skip
_ENDS_CPU = [0.0]


def _time_the_ends() -> None:
    """Count the driver's CPU in the build's planning and finishing steps (once per build,
    whatever its size) in ``_ENDS_CPU``, to tell them from the CPU that grows with the
    samples (streaming the chunks and committing them)."""
    from mars_pairs.pipeline.builder import run as build

    for name in _ENDS:
        fn = getattr(build, name, None)
        if fn is None:  # an older build without this step
            continue

        def timed(*args: object, _fn=fn, **kw: object) -> object:
            start = _cpu()
            try:
                return _fn(*args, **kw)
            finally:
                _ENDS_CPU[0] += _cpu() - start

        setattr(build, name, timed)


class _ExternalCluster:
    """A Dask scheduler and ``workers`` single-threaded workers, each its own subprocess,
    preloaded as a long-lived cluster's would be (``pipeline.builder.dask_preload``)."""

    def __init__(self, root: Path, workers: int) -> None:
        dask = Path(sys.executable).with_name("dask")
        file = root / "scheduler.json"
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        self.procs = [
            subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", "0",
                              "--no-dashboard", "--scheduler-file", str(file)], **quiet)
        ]  # fmt: skip
        deadline = time.monotonic() + 60
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        self.procs.append(
            subprocess.Popen([str(dask), "worker", "--scheduler-file", str(file), "--nworkers",
                              str(workers), "--nthreads", "1", "--no-dashboard",
                              "--preload", "mars_pairs.pipeline.builder.dask_preload"], **quiet)
        )  # fmt: skip
        from distributed import Client

        with Client(scheduler_file=str(file), timeout="60s") as client:
            client.wait_for_workers(workers, timeout=120)
            self.address = client.scheduler.address

    def close(self) -> None:
        for proc in reversed(self.procs):
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


_SLOPE_CHILD = """
import json, resource, sys, threading
from pathlib import Path
from mars_pairs.runtime import configure_process
configure_process()
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
doc, workers, limit = json.loads(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
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
if workers > 1:
    poller.start()
summary = run_build(parse_config(doc, Path(doc["output"]["dir"]).parent), workers=workers,
                    progress=False, limit=limit)
done.set()
if workers > 1:
    poller.join()
own = resource.getrusage(resource.RUSAGE_SELF)
cpu = own.ru_utime + own.ru_stime + sum(seen.values())
print(json.dumps({"samples": summary.samples, "seconds": summary.seconds, "cpu": cpu}))
"""


def _demo_doc(mission: Path) -> dict:
    """configs/demo.yaml without its synthetic section, the inputs in ``mission``; the
    mission generated as the demo generates it when absent."""
    import yaml

    doc = yaml.safe_load((Path(__file__).parents[1] / "configs" / "demo.yaml").read_text())
    synth = doc["inputs"].pop("synthetic")
    if not (mission / "places").is_dir():
        generate_mission(mission, seed=synth["seed"], mission=synth["mission"],
                         stops=synth["stops"], images_per_stop=synth["images_per_stop"],
                         size=synth["size"])  # fmt: skip
    doc["inputs"].update({
        "labels": str(mission / "labels" / "*.xml"),
        "places": str(mission / "places" / "best_interp.csv"),
        "dem": str(mission / "orbital" / "dem.tif"),
        "ortho": str(mission / "orbital" / "ortho.tif"),
    })  # fmt: skip
    return doc


def _child_build(
    code: Path, doc: dict, out: Path, workers: int, limit: int
) -> tuple[int, float, float]:
    """(samples, seconds, CPU seconds of the process and its workers) of one build of ``doc``
    into ``out`` by the package in ``code``, in a fresh subprocess (the workers' CPU polled
    every 50 ms while they run: what a worker spends in its last 50 ms may be missed)."""
    doc = {**doc, "output": {**doc["output"], "dir": str(out)}}
    env = {**os.environ, "PYTHONPATH": str(code), "PYTHONWARNINGS": "ignore"}
    args = [sys.executable, "-c", _SLOPE_CHILD, json.dumps(doc), str(workers), str(limit)]
    proc = subprocess.run(args, env=env, capture_output=True, text=True, cwd=str(out.parent))
    if proc.returncode != 0:
        raise RuntimeError(f"build by {code} failed:\n{proc.stderr[-3000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    return result["samples"], result["seconds"], result["cpu"]


def slope_table(mission: Path, sizes: list[int], reps: int, workers: int,
                anchor: Path | None) -> None:  # fmt: skip
    """Print the marginal CPU per sample of this checkout (and ``anchor``'s), interleaved."""
    here = Path(__file__).resolve().parents[1]
    codes = ({"anchor": anchor.resolve()} if anchor is not None else {}) | {"this": here}
    doc = _demo_doc(mission)
    n1, n2 = sizes
    names = sorted(glob.glob(doc["inputs"]["labels"]))[:n2]
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        docs = {}  # each set's labels (and the images beside them) copied to a folder of its own
        for n, chosen in ((n1, names[::2][:n1]), (n2, names)):
            folder = root / f"labels-{n}"
            folder.mkdir()
            for label in map(Path, chosen):
                for path in label.parent.glob(label.stem + ".*"):
                    shutil.copy2(path, folder / path.name)
            docs[n] = {**doc, "inputs": {**doc["inputs"], "labels": str(folder / "*.xml")}}
        for name, code in codes.items():  # compile or load the kernels, not timed
            _child_build(code, docs[n1], root / f"warm-{name}", workers, 4)
        cases: dict[tuple[str, int], list[tuple[int, float, float]]] = {}
        for rep in range(reps):
            for n in (n1, n2):
                for name, code in codes.items():
                    out = root / f"{name}-{n}-{rep}"
                    build = _child_build(code, docs[n], out, workers, n)
                    cases.setdefault((name, n), []).append(build)
                    loads.append(os.getloadavg()[0])
    print(
        f"build slope: the demo's labels (configs/demo.yaml), the first {n2} in name order "
        f"and every other one of them ({n1}); "
        f"workers {workers}; best of {reps} builds per case, each a fresh process, "
        f"interleaved; {os.cpu_count()} cores; load (1 min) {min(loads):.2f}-{max(loads):.2f}\n"
    )
    print("| code | samples | seconds | samples/s | CPU s | CPU ms/sample "
          "| marginal CPU ms/sample (slope) | vs anchor |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    slopes = {}
    for name in codes:
        small = min(cases[(name, n1)], key=lambda c: c[2])
        large = min(cases[(name, n2)], key=lambda c: c[2])
        # the slope between each size's least-disturbed build (the load only adds CPU);
        # every rep's own pair beside it, to show the spread
        slopes[name] = (large[2] - small[2]) / max(large[0] - small[0], 1)
        pairs = [(b[2] - a[2]) / max(b[0] - a[0], 1) for a, b in
                 zip(cases[(name, n1)], cases[(name, n2)], strict=True)]  # fmt: skip
        for n, secs, cpu in (small, large):
            print(
                f"| {name} | {n} | {secs:.2f} | {n / secs:.1f} | {cpu:.2f} "
                f"| {cpu * 1000 / n:.1f} | | |"
            )
        spread = ", ".join(f"{p * 1000:.1f}" for p in pairs)
        ratio = f"{slopes[name] / slopes['anchor']:.2f}x" if "anchor" in slopes else "-"
        print(
            f"| **{name}** slope | {n2 - n1} more | | | | | **{slopes[name] * 1000:.1f}** "
            f"(each rep's: {spread}) | {ratio} |"
        )


def main() -> None:
    configure_process()
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--stops", type=int, default=64)
    parser.add_argument("--images-per-stop", type=int, default=8)
    parser.add_argument("--size-px", type=int, default=512)
    parser.add_argument("--shard-size", type=int, default=16)
    parser.add_argument("--mission", type=Path, help="keep (or reuse) the mission here")
    parser.add_argument("--engines", default="local,dask")
    parser.add_argument("--dense", action="store_true", help="add the dense members' cost")
    parser.add_argument("--scale", action="store_true", help="the driver at scale (bench_scale)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--slope", action="store_true", help="marginal CPU per sample (demo)")
    parser.add_argument("--anchor-root", type=Path, help="--slope: another commit's checkout")
    parser.add_argument("--slope-sizes", type=int, nargs=2, default=[135, 270])
    parser.add_argument("--slope-reps", type=int, default=3)
    parser.add_argument("--workers", type=int, default=1, help="--slope: build workers")
    args = parser.parse_args()
    if args.slope:
        mission = args.mission or Path(__file__).resolve().parents[1] / "out/demo/mission"
        slope_table(mission, args.slope_sizes, args.slope_reps, args.workers, args.anchor_root)
        return
    if args.scale:
        from bench_scale import scale_table

        scale_table(args.sizes, per_dir=1000)
        return
    runs = [("local", 1), ("local", 2)] if "local" in args.engines else []
    runs += [("dask", 2)] if "dask" in args.engines else []
    _time_the_ends()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        mission = args.mission or root / "mission"
        t = time.perf_counter()
        if not (mission / "places").is_dir():
            generate_mission(mission, seed=0, mission="m2020", stops=args.stops,
                             images_per_stop=args.images_per_stop, size="small")  # fmt: skip
        gen = time.perf_counter() - t
        # warm numba caches and the OS file cache, not timed
        run_build(parse_config(_config(mission, root / "warm", args.size_px), root),
                  progress=False, limit=4)  # fmt: skip
        if args.dense:
            warm = _config(mission, root / "warm-dense", args.size_px, members="all")
            run_build(parse_config(warm, root), progress=False, limit=4)
        rows = []
        stages: dict[str, float] = {}
        for name, workers in runs:
            cluster, engine = None, None
            if name == "dask":
                from mars_pairs.pipeline.builder.dask_engine import DaskEngine

                cluster = _ExternalCluster(root, workers)
                engine = DaskEngine(scheduler=cluster.address, announce=False)
            try:
                out = root / f"ds-{name}{workers}"
                cfg = parse_config(_config(mission, out, args.size_px, args.shard_size), root)
                before = os.getloadavg()[0]
                _ENDS_CPU[0], cpu = 0.0, _cpu()
                summary = run_build(cfg, workers=workers, progress=False, engine=engine)
                cpu = _cpu() - cpu
                ends = _ENDS_CPU[0]
            finally:
                if cluster is not None:
                    cluster.close()
            n = max(summary.samples, 1)
            load = max(before, os.getloadavg()[0])
            rows.append((name, workers, summary.samples, summary.seconds, summary.samples /
                         summary.seconds, cpu * 1000 / n, (cpu - ends) * 1000 / n,
                         load))  # fmt: skip
            if workers == 1 and name == "local":
                stages = {k: v / n for k, v in summary.stage_seconds.items()}
        dense = dense_rows(mission, root, args.size_px) if args.dense else []
    worker_ms = sum(stages.values()) * 1000
    print(f"build benchmark: {rows[0][2]} samples, {args.size_px} px chips, radius 1000 m, "
          f"ray stride 8, {args.shard_size} samples a shard; mission ready in {gen:.1f} s; "
          f"{os.cpu_count()} cores; dask: external scheduler + workers\n")  # fmt: skip
    anchor = rows[0][4]
    print("| engine | workers | samples | seconds | samples/s | vs local 1 | driver CPU ms/sample "
          "| of it streaming | streaming vs target | driver saturates at (workers) "
          "| load (1 min) | vs study |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, workers, n, secs, rate, driver_ms, streaming_ms, load in rows:
        in_driver = name == "local" and workers == 1  # the samples are built in the driver
        saturates = "-" if in_driver or not worker_ms else f"{worker_ms / streaming_ms:.0f}"
        print(
            f"| {name} | {workers} | {n} | {secs:.2f} | {rate:.1f} | {rate / anchor:.2f}x "
            f"| {driver_ms:.2f} | {streaming_ms:.2f} | {streaming_ms / TARGET_DRIVER_MS:.1f}x "
            f"| {saturates} | {load:.2f} | {rate * STUDY_SECONDS_PER_IMAGE:.0f}x |"
        )
    print("\ndriver CPU: getrusage(RUSAGE_SELF) of this process over the build; streaming: "
          "without the planning and finishing steps (plan_build, merge_parts, dataset.json, "
          "the shard index, the card, removing parts/), which run once per build; the driver "
          "saturates at worker ms per sample / streaming driver ms per sample; target <= "
          f"{TARGET_DRIVER_MS} ms")  # fmt: skip
    print("\n| stage (1 worker) | ms per sample |")
    print("|---|---:|")
    for name, secs in stages.items():
        print(f"| {name} | {secs * 1000:.1f} |")
    print(f"| **total** (worker ms per sample) | {worker_ms:.1f} |")
    print("\n".join(dense))


if __name__ == "__main__":
    main()
