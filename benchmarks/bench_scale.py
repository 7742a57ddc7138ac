"""The build driver at scale: its peak memory and CPU per label for 10k to 1M labels.

    python benchmarks/bench_scale.py [--sizes 10000 100000] [--per-dir 1000]
                                     [--anchor-sizes 10000 100000]
    python benchmarks/bench_build.py --scale [--sizes ...]

For each size, writes empty label files into a temp dir (``synth/label_tree.py``, per sol:
``--per-dir`` labels a folder, with tiny rasters) and runs ``run_build`` over them with the
chunk job stubbed: the engine hands each chunk to :func:`stub_chunk` (a module-level
function, so it pickles by name), which builds no sample and returns one tiny outcome a
label, so what is measured is the driver: listing, chunking, the duplicate-key check, the
parts it writes and the finish. Two stubs: ``dropped`` (the sample owns its key, so the key
check records every key, and no manifest row is written) and ``sample`` (every label a
manifest row of a few columns, at a pseudo-random Hilbert index, the rovers on a 300 m grid,
and one empty shard file a chunk: the finish sorts and writes a manifest of every label).
After the ``sample`` build, ``labels/100`` new labels are written and an append is planned
over the dataset (``append.plan_append``: the base's keys and label paths into the on-disk
index, the release listed).

Each case runs in a fresh subprocess, which reports the growth of its peak resident set
(``VmHWM`` in ``/proc/self/status``, reset through ``/proc/self/clear_refs`` as each phase
starts) over the resident set as the phase starts: the commit pass (planning, listing,
chunks, key check, parts; over the value after the imports and a warm-up build), the merge
(``merge_parts``: manifest and failures), the leak check (``streamed_leak_report``: a sweep
over the samples sorted on disk) and the rest of the finish; the whole build's growth is the
largest phase peak over the commit pass's start, and its peak that largest ``VmHWM`` itself
(imports included: what "flat" compares, 1M labels against 10k, within 10 %). CPU per label
from ``resource.getrusage``, for the whole build and a phase.
The anchor, "dict (before)", is the ``dropped`` build with the keys in a ``dict`` in the
driver (what ``key_index.KeyIndex`` replaced), alternated with it at ``--anchor-sizes``.
Prints markdown tables with the load average (1 min) after each case.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pickle
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from bench_plan import _vm_hwm_kib  # a script beside this one

INDEXES = {"sqlite": "SQLite index (KeyIndex)", "dict": "dict (before)"}
#: ``plan_config``'s chunk size, and the grid of the stubbed samples' rover positions (m:
#: wider than a 256 m chip).
SHARD_SIZE = 64
SPACING_M = 300.0


def stub_chunk(config: Any, task: Any, kind: str = "dropped") -> Any:
    """A chunk's result without building it: one outcome a label, keyed by its file name;
    ``kind`` ``dropped`` (no row) or ``sample`` (a manifest row of a few columns; the chunk's
    empty shard file written)."""
    from mars_pairs.pipeline.builder.engine import ChunkResult, Outcome
    from mars_pairs.pipeline.sample.record import labels_root

    if kind == "dropped":
        outcomes = tuple(
            Outcome("dropped", label, "k_" + Path(label).stem) for label in task.labels
        )
        return ChunkResult(task.index, outcomes, (), 0.0, "stub:0")
    out, root = config.output.dir, labels_root(config.inputs.labels)
    shard = f"shards/shard-{task.index:06d}-train.tar"
    (out / "shards").mkdir(parents=True, exist_ok=True)
    (out / shard).touch()
    rows = []
    for j, label in enumerate(task.labels):
        key = "k_" + Path(label).stem
        i = task.index * SHARD_SIZE + j  # on a grid of SPACING_M: no two chips meet
        row = {"key": key, "label_path": os.path.relpath(label, root), "mission": "msl",
               "split": "train", "hilbert": zlib.crc32(key.encode()),
               "easting": float(i % 1000 * SPACING_M), "northing": float(i // 1000 * SPACING_M),
               "meta_shard": shard}  # fmt: skip
        rows.append(Outcome("ok", label, key, row))
    return ChunkResult(task.index, tuple(rows), (), 0.0, "stub:0")


class StubEngine:
    """The ``Engine`` contract, every chunk through :func:`stub_chunk` in this process."""

    def __init__(self, kind: str = "dropped") -> None:
        self.kind = kind

    def run(self, config: Any, chunks: Iterable[Any]) -> Iterator[Any]:
        for task in chunks:
            yield stub_chunk(config, task, self.kind)


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


def _vm_rss_kib() -> int:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


class _Phases:
    """Peak resident set growth a phase: :meth:`start` ends the phase running (its peak
    noted) and resets the peak (``/proc/self/clear_refs``)."""

    def __init__(self) -> None:
        self.base = _vm_hwm_kib()
        self.name, self.at, self.peaks = "commit", self.base, {}  # type: ignore[var-annotated]
        self.highest = self.base
        self.cpu: dict[str, float] = {}  # seconds of CPU a phase
        self.cpu_at = _cpu()

    def start(self, name: str) -> None:
        hwm = _vm_hwm_kib()
        self.highest = max(self.highest, hwm)
        self.peaks[self.name] = max(self.peaks.get(self.name, 0), hwm - self.at)
        now = _cpu()
        self.cpu[self.name] = self.cpu.get(self.name, 0.0) + now - self.cpu_at
        self.cpu_at = now
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")
        self.name, self.at = name, _vm_rss_kib()

    def wrap(self, fn: Callable[..., Any], name: str, after: str) -> Callable[..., Any]:
        def timed(*args: Any, **kw: Any) -> Any:
            self.start(name)
            try:
                return fn(*args, **kw)
            finally:
                self.start(after)

        return timed


def _child(index: str, root: Path, pattern: str, kind: str) -> None:
    """One build in this fresh process; prints a JSON line."""
    from mars_pairs.pipeline.builder import finish, run
    from mars_pairs.synth.label_tree import plan_config, write_label_tree

    if index == "dict":
        run.open_index = _dict_index  # type: ignore[assignment]
    warm = write_label_tree(root / "warm-labels", 64, per_dir=None)
    run.run_build(plan_config(root / "inputs", warm, root / "warm"), engine=StubEngine(kind),
                  progress=False)  # fmt: skip
    config = plan_config(root / "inputs", pattern, root / "dataset")
    (root / "config.pickle").write_bytes(pickle.dumps(config))
    phases = _Phases()
    run.merge_parts = phases.wrap(run.merge_parts, "merge", "finish")  # type: ignore[assignment]
    finish.streamed_leak_report = phases.wrap(  # type: ignore[assignment]
        finish.streamed_leak_report, "leak", "finish"
    )
    cpu, start = _cpu(), time.perf_counter()
    summary = run.run_build(config, engine=StubEngine(kind), progress=False)
    seconds, cpu = time.perf_counter() - start, _cpu() - cpu
    phases.start("end")
    dataset = json.loads((root / "dataset" / "dataset.json").read_text())
    print(json.dumps({"peaks": phases.peaks, "rss_kib": phases.highest - phases.base,
                      "peak_kib": phases.highest, "phase_cpu": phases.cpu,
                      "cpu": cpu, "seconds": seconds, "samples": summary.samples,
                      "counts": dataset.get("counts")}))  # fmt: skip


def _append_child(root: Path) -> None:
    """An append planned over the dataset of the ``sample`` build; prints a JSON line."""
    from mars_pairs.pipeline.builder import run
    from mars_pairs.pipeline.builder.append import plan_append
    from mars_pairs.synth.label_tree import plan_config, write_label_tree

    config = pickle.loads((root / "config.pickle").read_bytes())
    labels = write_label_tree(root / "warm-labels", 64, per_dir=None)
    warm = plan_config(root / "warm-inputs", labels, root / "warm")
    run.run_build(warm, engine=StubEngine("sample"), progress=False)
    plan_append(warm)  # the imports and first opens: not the plan's growth
    base, cpu, start = _vm_hwm_kib(), _cpu(), time.perf_counter()
    plan = plan_append(config)
    seconds, cpu = time.perf_counter() - start, _cpu() - cpu
    print(json.dumps({"rss_kib": _vm_hwm_kib() - base, "cpu": cpu, "seconds": seconds,
                      "new": plan.labels_new, "known": plan.labels_known}))  # fmt: skip


def _run(*args: str) -> dict[str, Any]:
    here = str(Path(__file__).resolve())
    command = [sys.executable, here, "--child", *args]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode:
        raise RuntimeError(done.stderr[-3000:])
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def _phase_cpu(cpu: dict[str, float], size: int) -> str:
    return " / ".join(
        f"{cpu.get(k, 0.0) * 1e6 / size:.0f}" for k in ("commit", "merge", "leak", "finish")
    )


def _mib(kib: float) -> str:
    return f"{kib / 1024:.1f}"


def scale_table(
    sizes: list[int],
    per_dir: int,
    anchor_sizes: list[int] | None = None,
    stubs: tuple[str, ...] = ("dropped", "sample"),
) -> None:
    """Print the tables for ``sizes`` labels (``per_dir`` a folder); the dict anchor at
    ``anchor_sizes`` (default: every size); the stubs ``stubs`` (the append plan needs
    ``sample``)."""
    from mars_pairs.synth.label_tree import write_label_tree

    anchors = sizes if anchor_sizes is None else anchor_sizes
    print(
        f"{os.cpu_count()} CPUs, load average (1, 5, 15 min) "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} before; chunk job stubbed "
        f"(no sample built), each case in a fresh process\n"
    )
    print("| labels | stub | duplicate-key record | peak RSS growth MiB: commit pass | merge "
          "| leak check | rest of the finish | whole build | whole build peak RSS MiB "
          "| CPU us/label | CPU us/label: commit / merge / leak / rest | seconds "
          "| load (1 min) |")  # fmt: skip
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    appends = []
    for size in sizes:
        root = Path(tempfile.mkdtemp(prefix="bench_scale_"))
        try:
            pattern = write_label_tree(root / "labels", size, per_dir=per_dir)
            cases = [("dropped", "sqlite")] if "dropped" in stubs else []
            cases += [("dropped", "dict")] if size in anchors and "dropped" in stubs else []
            cases += [("sample", "sqlite")] if "sample" in stubs else []
            for kind, index in cases:
                for name in ("dataset", "warm", "warm-labels"):
                    shutil.rmtree(root / name, ignore_errors=True)
                r = _run(index, str(root), pattern, kind)
                assert r["samples"] == (size if kind == "sample" else 0), r
                p = r["peaks"]
                print(
                    f"| {size:,} | {kind} | {INDEXES[index]} | {_mib(p['commit'])} "
                    f"| {_mib(p['merge'])} | {_mib(p.get('leak', 0))} | {_mib(p['finish'])} "
                    f"| {_mib(r['rss_kib'])} | {_mib(r['peak_kib'])} "
                    f"| {r['cpu'] * 1e6 / size:.0f} | {_phase_cpu(r['phase_cpu'], size)} "
                    f"| {r['seconds']:.1f} | {os.getloadavg()[0]:.2f} |",
                    flush=True,
                )
            if "sample" not in stubs:
                continue
            new = max(100, size // 100)  # a new release: sols after the dataset's
            for i in range(new):
                sol, j = divmod(i, per_dir)
                folder = root / "labels" / "sol" / f"9{sol:05d}" / "ids"
                folder.mkdir(parents=True, exist_ok=True)
                (folder / f"ZLF_9{sol:05d}_{j:04d}.xml").touch()
            for name in ("warm", "warm-labels", "warm-inputs"):
                shutil.rmtree(root / name, ignore_errors=True)
            r = _run("append", str(root), "", "")
            assert (r["known"], r["new"]) == (size, new), r
            appends.append((size, new, r, os.getloadavg()[0]))
        finally:
            shutil.rmtree(root, ignore_errors=True)
    print("\n| dataset samples | new labels | append plan peak RSS growth MiB "
          "| CPU us/label seen | seconds | load (1 min) |")  # fmt: skip
    print("|---:|---:|---:|---:|---:|---:|")
    for size, new, r, load in appends:
        cpu = r["cpu"] * 1e6 / (size + new)
        print(f"| {size:,} | {new:,} | {_mib(r['rss_kib'])} "
              f"| {cpu:.0f} | {r['seconds']:.1f} | {load:.2f} |")  # fmt: skip
    print(f"\nload average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--anchor-sizes", type=int, nargs="*")
    parser.add_argument("--per-dir", type=int, default=1000)
    parser.add_argument("--stubs", nargs="+", choices=["dropped", "sample"],
                        default=["dropped", "sample"])  # fmt: skip
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        index, root, pattern, kind = args.child
        if index == "append":
            _append_child(Path(root))
        else:
            _child(index, Path(root), pattern, kind)
        return
    scale_table(args.sizes, args.per_dir, args.anchor_sizes, tuple(args.stubs))


if __name__ == "__main__":
    main()
