"""The build driver at scale: its peak memory and CPU per label for 10k to 1M labels.

    python benchmarks/bench_scale.py [--sizes 10000 100000] [--per-dir 1000]
    python benchmarks/bench_build.py --scale [--sizes ...]

For each size, writes empty label files into a temp dir (``synth/label_tree.py``, per sol:
``--per-dir`` labels a folder, with tiny rasters) and runs ``run_build`` over them with the
chunk job stubbed: the engine hands each chunk to :func:`stub_chunk` (a module-level
function, so it pickles by name), which builds no sample and returns one tiny outcome a
label (``dropped``: it owns its key, so the duplicate-key check records every key, and no
shard is written). So what is measured is the driver: listing, chunking, the duplicate-key
check, the parts it writes and the finish. Each case runs in a fresh subprocess, which
reports the growth of its peak resident set (``VmHWM`` in ``/proc/self/status``, over the
value after the imports and a warm-up build) up to the finish (the commit pass: listing,
chunks, key check, parts; taken as ``merge_parts`` starts) and over the whole build, and its
CPU per label
(``resource.getrusage``). The anchor, "dict (before)", is the same build with the keys in a
``dict`` in the driver (what ``key_index.KeyIndex`` replaced), alternated with it per size.
Prints a markdown table with the load average (1 min) after each case.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from bench_plan import _vm_hwm_kib  # a script beside this one

INDEXES = {"sqlite": "SQLite index (KeyIndex)", "dict": "dict (before)"}


def stub_chunk(config: Any, task: Any) -> Any:
    """A chunk's result without building it: one ``dropped`` outcome a label, keyed by its
    file name."""
    from mars_pairs.pipeline.builder.engine import ChunkResult, Outcome

    outcomes = tuple(Outcome("dropped", label, "k_" + Path(label).stem) for label in task.labels)
    return ChunkResult(task.index, outcomes, (), 0.0, "stub:0")


class StubEngine:
    """The ``Engine`` contract, every chunk through :func:`stub_chunk` in this process."""

    def run(self, config: Any, chunks: Iterable[Any]) -> Iterator[Any]:
        for task in chunks:
            yield stub_chunk(config, task)


class _DictIndex(dict[str, str]):
    """The anchor: the keys in a dict in the driver, as the build held them before."""

    def add_parts(self, out: Any, done: Iterable[int]) -> None:
        assert not list(done)  # a fresh build


@contextlib.contextmanager
def _dict_index(out: Any) -> Iterator[_DictIndex]:
    yield _DictIndex()


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _child(index: str, root: Path, pattern: str) -> None:
    """One case in this fresh process; prints a JSON line."""
    from mars_pairs.pipeline.builder import run
    from mars_pairs.synth.label_tree import plan_config, write_label_tree

    if index == "dict":
        run.open_index = _dict_index  # type: ignore[assignment]
    warm = write_label_tree(root / "warm-labels", 64, per_dir=None)
    run.run_build(plan_config(root / "inputs", warm, root / "warm"), engine=StubEngine(),
                  progress=False)  # fmt: skip
    config = plan_config(root / "inputs", pattern, root / "dataset")
    merge, at_merge = run.merge_parts, [0]

    def timed_merge(*args: Any) -> Any:  # the commit pass ends where the finish starts
        at_merge[0] = _vm_hwm_kib()
        return merge(*args)

    run.merge_parts = timed_merge  # type: ignore[assignment]
    base, cpu, start = _vm_hwm_kib(), _cpu(), time.perf_counter()
    summary = run.run_build(config, engine=StubEngine(), progress=False)
    seconds, cpu = time.perf_counter() - start, _cpu() - cpu
    dataset = json.loads((root / "dataset" / "dataset.json").read_text())
    print(json.dumps({"rss_kib": _vm_hwm_kib() - base, "commit_kib": at_merge[0] - base,
                      "cpu": cpu, "seconds": seconds,
                      "samples": summary.samples, "counts": dataset.get("counts")}))  # fmt: skip


def _run(index: str, root: Path, pattern: str) -> dict[str, Any]:
    here = str(Path(__file__).resolve())
    command = [sys.executable, here, "--child", index, str(root), pattern]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode:
        raise RuntimeError(done.stderr[-3000:])
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def scale_table(sizes: list[int], per_dir: int) -> None:
    """Print the table for ``sizes`` labels (``per_dir`` a folder)."""
    from mars_pairs.synth.label_tree import write_label_tree

    print(
        f"{os.cpu_count()} CPUs, load average (1, 5, 15 min) "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} before; chunk job stubbed "
        f"(no sample built), each case in a fresh process\n"
    )
    print("| labels | duplicate-key record | driver peak RSS growth MiB: to the finish "
          "| whole build | CPU us/label | seconds | load (1 min) |")  # fmt: skip
    print("|---:|---|---:|---:|---:|---:|---:|")
    for size in sizes:
        root = Path(tempfile.mkdtemp(prefix="bench_scale_"))
        try:
            pattern = write_label_tree(root / "labels", size, per_dir=per_dir)
            for index, name in INDEXES.items():
                shutil.rmtree(root / "dataset", ignore_errors=True)
                shutil.rmtree(root / "warm", ignore_errors=True)
                r = _run(index, root, pattern)
                print(
                    f"| {size:,} | {name} | {r['commit_kib'] / 1024:.1f} "
                    f"| {r['rss_kib'] / 1024:.1f} "
                    f"| {r['cpu'] * 1e6 / size:.0f} | {r['seconds']:.1f} "
                    f"| {os.getloadavg()[0]:.2f} |",
                    flush=True,
                )
        finally:
            shutil.rmtree(root, ignore_errors=True)
    print(f"\nload average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--per-dir", type=int, default=1000)
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        index, root, pattern = args.child
        _child(index, Path(root), pattern)
        return
    scale_table(args.sizes, args.per_dir)


if __name__ == "__main__":
    main()
