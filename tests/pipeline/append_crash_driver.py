"""Kill an ``--append`` at its file operations; rerun it; compare with an uninterrupted append.

Run by tests/pipeline/test_build_append.py as
``python append_crash_driver.py BASE.yaml RELEASE.yaml STRIDE`` (both configs write the same
output folder). This process only imports; every build runs in a forked child
(``crash_driver._in_child``). Steps:

1. clear the folder, build BASE, keep a copy of the folder.
2. reference: append RELEASE over it with each file operation under the output folder
   recorded in order (``crash_driver._patch``); keep every file's bytes (dataset.json
   without its build time and the append's time).
3. for every STRIDE-th operation N (STRIDE 0: one in each phase of the append,
   ``_key_points``): restore the base, append with the child SIGKILLing itself just before
   operation N, then append again in a fresh child (with ``resume=True`` every other time:
   the same); the folder must equal the reference, and every shard of the base must keep
   its bytes and mtime.

Prints one JSON line: the operations of the append and the kill points that did not match.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
from pathlib import Path
from typing import Any

from crash_driver import _in_child, _patch, _snapshot

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config


def _shard_stats(out: Path) -> dict[str, tuple[int, int]]:
    return {
        p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in (out / "shards").glob("*.tar")
    }


def _after(ops: list[list[str]], op: str, prefix: str, nth: int = 1) -> int:
    """The kill point just after the ``nth`` operation ``op`` on a path starting ``prefix``."""
    hits = [i for i, (o, path) in enumerate(ops, 1) if o == op and path.startswith(prefix)]
    return hits[nth - 1] + 1


def _key_points(ops: list[list[str]]) -> list[int]:
    """Kill points at each phase of an append: after the stamp (the base snapshot taken, no
    chunk built), after the second new chunk's commit, after the merged manifest is in place
    (failures.parquet and dataset.json still the base's), and after the stamp is removed
    (the dataset whole, the base snapshot left)."""
    return [
        _after(ops, "replace", "parts/.build.json"),
        _after(ops, "replace", "parts/.manifest-", nth=2),
        _after(ops, "replace", ".manifest.parquet"),
        _after(ops, "unlink", "parts/build.json"),
    ]


def _append(config_path: Path, **kw: Any) -> Any:
    return lambda: run_build(load_config(config_path), progress=False, append=True, **kw)


def main(base: Path, release: Path, stride: int) -> dict[str, Any]:
    out = load_config(base).output.dir
    assert load_config(release).output.dir == out
    shutil.rmtree(out, ignore_errors=True)
    assert _in_child(lambda: run_build(load_config(base), progress=False)) == 0
    base_state = out.with_name(out.name + "-base")
    shutil.rmtree(base_state, ignore_errors=True)
    shutil.copytree(out, base_state)
    base_shards = _shard_stats(base_state)

    def restore() -> None:
        shutil.rmtree(out)
        shutil.copytree(base_state, out)  # copy2: the shards keep their mtimes

    log_path = out.with_name("append-ops.json")

    def counted() -> None:
        log: list[tuple[str, str]] = []
        _patch(out, None, log)
        run_build(load_config(release), progress=False, append=True)
        log_path.write_text(json.dumps(log))

    assert _in_child(counted) == 0  # over the base just built: the uninterrupted append
    reference = _snapshot(out)
    ops = json.loads(log_path.read_text())
    points = _key_points(ops) if stride == 0 else sorted({*range(1, len(ops) + 1, stride)})
    mismatched: list[dict[str, Any]] = []
    killed = 0
    for i, n in enumerate(points):
        restore()

        def kill(n: int = n) -> None:
            _patch(out, n, [])
            run_build(load_config(release), progress=False, append=True)

        killed += _in_child(kill) == -signal.SIGKILL
        rerun = _in_child(_append(release, resume=bool(i % 2)))
        got = _snapshot(out) if rerun == 0 else {}
        kept = {k: v for k, v in _shard_stats(out).items() if k in base_shards}
        if rerun != 0 or got != reference or kept != base_shards:
            diff = sorted(k for k in set(got) | set(reference) if got.get(k) != reference.get(k))
            bad = {"kill_at": n, "op": ops[n - 1], "rerun": rerun, "diff": diff}
            mismatched.append({**bad, "base_shards_changed": kept != base_shards})
    return {
        "ops": ops,
        "points": points,
        "killed": killed,
        "mismatched": mismatched,
        "files": sorted(reference),
    }


if __name__ == "__main__":
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    print(json.dumps(main(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]))))
