"""Build planning at scale: the dry run's time and the driver's memory for 10k to 100k labels.

    python benchmarks/bench_plan.py [--sizes 10000 50000 100000] [--per-dir 100] [--repeats 3]

For each size, writes empty label files into a temp dir in two layouts: per sol (``--per-dir``
labels in each ``sol/NNNNN/ids/`` folder, the archive's layout: 1,000 folders at 100k) and
flat (every label in one folder), with tiny rasters (``synth/label_tree.py``). Each case runs
in a fresh subprocess, which measures ``plan_build`` (what ``mars-pairs build --dry-run``
runs: check the inputs, list, chunk, fingerprint, chunks done): the median wall time of
``--repeats`` runs, the growth of the peak resident set (``VmHWM`` in ``/proc/self/status``,
after the imports and a first input check), and the tracemalloc peak of one more run. The
anchor, "glob + sorted (before)", is the planning this replaced, in the same subprocess
setup: the inputs checked, ``sorted`` of the set of every ``glob.glob`` match as ``Path``,
the chunk lists, the fingerprint over the joined names and the list of pending label
strings. Prints a markdown table with the load average (1 min) before and after each case.
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

METHODS = {"stream": "streamed (plan_build)", "glob": "glob + sorted (before)"}


def _vm_hwm_kib() -> int:
    """This process's peak resident set so far, KiB (Linux)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    raise RuntimeError("no VmHWM in /proc/self/status")


def _glob_plan(config: Any) -> tuple[int, int, str]:
    """The planning before streaming (run_build up to the engine): every label at once."""
    from mars_pairs.pipeline.builder.plan import check_inputs

    check_inputs(config)
    found = {
        Path(p) for pattern in config.inputs.labels for p in glob.glob(pattern, recursive=True)
    }
    labels = sorted(found)
    size = config.output.shard_size
    chunks = [labels[i : i + size] for i in range(0, len(labels), size)]
    digest = hashlib.sha256("\n".join(str(p) for p in labels).encode()).hexdigest()
    pending = [str(p) for chunk in chunks for p in chunk]
    return len(pending), len(chunks), digest


def _stream_plan(config: Any) -> tuple[int, int, str]:
    from mars_pairs.pipeline.builder.plan import plan_build

    plan = plan_build(config)
    return plan.labels, plan.chunks, plan.fingerprint["labels"]


def _child(method: str, root: Path, pattern: str, repeats: int) -> None:
    """One case in this fresh process; prints a JSON line."""
    from mars_pairs.pipeline.builder.plan import check_inputs
    from mars_pairs.synth.label_tree import plan_config

    config = plan_config(root / "inputs", pattern, root / "dataset")
    check_inputs(config)  # imports, GDAL drivers: not what is measured
    plan = _stream_plan if method == "stream" else _glob_plan
    base = _vm_hwm_kib()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        labels, chunks, digest = plan(config)
        times.append(time.perf_counter() - start)
    rss = _vm_hwm_kib() - base
    tracemalloc.start()
    plan(config)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(
        json.dumps(
            {
                "labels": labels,
                "chunks": chunks,
                "digest": digest,
                "seconds": statistics.median(times),
                "rss_kib": rss,
                "traced_bytes": peak,
            }
        )
    )


def _run(method: str, root: Path, pattern: str, repeats: int) -> dict[str, Any]:
    here = str(Path(__file__).resolve())
    command = [sys.executable, here, "--child", method, str(root), pattern, str(repeats)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 50_000, 100_000])
    parser.add_argument("--per-dir", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        method, root, pattern, repeats = args.child
        _child(method, Path(root), pattern, int(repeats))
        return
    from mars_pairs.synth.label_tree import write_label_tree

    print(
        f"{os.cpu_count()} CPUs, load average (1, 5, 15 min) "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} before; "
        f"median of {args.repeats} plans per case, each case in a fresh process\n"
    )
    print(
        "| layout | labels | planning | median s | tracemalloc peak MiB | RSS growth MiB | load |"
    )
    print("|---|---:|---|---:|---:|---:|---:|")
    for layout, per_dir in (("per sol", args.per_dir), ("flat", None)):
        for size in args.sizes:
            root = Path(tempfile.mkdtemp(prefix="bench_plan_"))
            try:
                pattern = write_label_tree(root / "labels", size, per_dir=per_dir)
                digests = set()
                for method, name in METHODS.items():
                    r = _run(method, root, pattern, args.repeats)
                    assert r["labels"] == size, r
                    digests.add(r["digest"])
                    where = f"{size // per_dir} x {per_dir}" if per_dir else "1 folder"
                    print(
                        f"| {layout} ({where}) | {size:,} | {name} | {r['seconds']:.2f} "
                        f"| {r['traced_bytes'] / 2**20:.2f} | {r['rss_kib'] / 1024:.1f} "
                        f"| {os.getloadavg()[0]:.2f} |",
                        flush=True,
                    )
                assert len(digests) == 1, "the two plannings disagree on the label list"
            finally:
                shutil.rmtree(root, ignore_errors=True)
    print(f"\nload average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
