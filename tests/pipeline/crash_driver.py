"""Kill a rebuild over an old dataset at every kind of file operation; resume; compare.

Run by tests/pipeline/test_build_crash.py as ``python crash_driver.py NEW.yaml OLD.yaml``
(both configs write the same output folder). This process only imports; every build runs in
a forked child, so no child inherits numba or Arrow threads. Steps:

1. reference: clear the folder, build NEW; keep every file's bytes.
2. count: build OLD, then NEW over it with each file operation under the output folder
   (os.replace/rename/unlink/remove/rmdir/mkdir, open for writing) recorded in order.
3. for every kill point N (every operation up to the first change of the old dataset, then
   the first and the last operation of each kind: the operation with the digits of its path
   masked, so the commits of the shards of every chunk count as one kind): build OLD, then
   NEW with the child SIGKILLing itself just before operation N, then NEW with
   ``resume=True`` in a fresh child; the folder must equal the reference (dataset.json up to
   its build time). A kill before anything changed leaves the old dataset as it was, which
   ``resume`` refuses (its config differs: the documented refusal); those points are listed
   as untouched and rebuilt without ``resume``.

Prints one JSON line: the operations of the rebuild and the kill points that did not match.
"""

from __future__ import annotations

import builtins
import hashlib
import io
import json
import os
import re
import shutil
import signal
import sys
from pathlib import Path
from typing import Any

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config

_OPS = ("replace", "rename", "unlink", "remove", "rmdir", "mkdir")


def _patch(out: Path, kill_at: int | None, log: list[tuple[str, str]]) -> None:
    """Count (and log) file operations under ``out``; SIGKILL this process before the
    ``kill_at``-th one."""
    root = str(out)

    def note(op: str, path: Any) -> None:
        text = os.fsdecode(os.fspath(path)) if isinstance(path, (str, bytes, os.PathLike)) else ""
        if not text.startswith(root):
            return
        log.append((op, os.path.relpath(text, root)))
        if kill_at is not None and len(log) == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)

    for op in _OPS:
        original = getattr(os, op)

        def wrapped(path: Any, *args: Any, _f: Any = original, _op: str = op, **kw: Any) -> Any:
            note(_op, path)
            return _f(path, *args, **kw)

        setattr(os, op, wrapped)
    real_open = builtins.open

    def opened(file: Any, mode: str = "r", *args: Any, **kw: Any) -> Any:
        if any(c in mode for c in "wax+"):
            note(f"open-{mode}", file)
        return real_open(file, mode, *args, **kw)

    builtins.open = opened  # type: ignore[assignment]
    io.open = opened  # type: ignore[assignment]


def kill_points(ops: list[tuple[str, str]], first_change: int) -> list[int]:
    """The 1-based kill points: every operation up to ``first_change``, then the first and the
    last of each kind (the operation and its path with every run of digits masked)."""
    points = set(range(1, first_change + 1))
    first: dict[tuple[str, str], int] = {}
    last: dict[tuple[str, str], int] = {}
    for n, (op, path) in enumerate(ops, start=1):
        kind = (op, re.sub(r"\d+", "#", path))
        first.setdefault(kind, n)
        last[kind] = n
    return sorted(points | set(first.values()) | set(last.values()))


def _in_child(fn: Any) -> int:
    """Run ``fn`` in a forked child; its exit status (negative: killed by that signal)."""
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            fn()
        except BaseException as exc:  # report, never fall back into the parent's loop
            print(f"child failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            code = 3
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def _snapshot(out: Path) -> dict[str, bytes]:
    """Every file's bytes; dataset.json without its build time and its appends' times, and
    SHA256SUMS as whether it holds dataset.json's digest (which holds the build time)."""
    files = {}
    for p in sorted(out.rglob("*")):
        if p.is_file():
            data = p.read_bytes()
            if p.name == "dataset.json":
                doc = json.loads(data)
                doc.pop("build_seconds", None)
                for record in doc.get("appends", []):
                    record.pop("when", None)
                data = json.dumps(doc, sort_keys=True).encode()
            if p.name == "SHA256SUMS" and (p.parent / "dataset.json").is_file():
                sha = hashlib.sha256((p.parent / "dataset.json").read_bytes()).hexdigest()
                data = b"matches dataset.json" if data.startswith(sha.encode()) else data
            files[str(p.relative_to(out))] = data
    return files


def _build(config_path: Path, **kw: Any) -> Any:
    return lambda: run_build(load_config(config_path), progress=False, **kw)


def main(new: Path, old: Path) -> dict[str, Any]:
    out = load_config(new).output.dir
    assert load_config(old).output.dir == out
    shutil.rmtree(out, ignore_errors=True)
    assert _in_child(_build(new)) == 0
    reference = _snapshot(out)
    assert _in_child(_build(old)) == 0
    old_state = out.with_name(out.name + "-old")
    shutil.rmtree(old_state, ignore_errors=True)
    shutil.copytree(out, old_state)

    log_path = out.with_name("ops.json")

    def counted() -> None:
        log: list[tuple[str, str]] = []
        _patch(out, None, log)
        run_build(load_config(new), progress=False)
        log_path.write_text(json.dumps(log))

    assert _in_child(counted) == 0
    ops = json.loads(log_path.read_text())
    old_files = _snapshot(old_state)
    mismatched: list[dict[str, Any]] = []
    statuses: list[int] = []
    untouched: list[int] = []
    first_change = ops.index(["replace", "dataset.json"]) + 1
    points = kill_points([tuple(op) for op in ops], first_change)
    for n in points:
        shutil.rmtree(out)
        shutil.copytree(old_state, out)

        def killed(n: int = n) -> None:
            _patch(out, n, [])
            run_build(load_config(new), progress=False)

        statuses.append(_in_child(killed))
        if _snapshot(out) == old_files:  # killed before changing anything: still the old
            untouched.append(n)  # dataset, which --resume refuses (another config) ...
            if _in_child(_build(new, resume=True)) == 0:
                mismatched.append({"kill_at": n, "op": ops[n - 1], "resume": "not refused"})
            resumed = _in_child(_build(new))  # ... and a plain rerun rebuilds
        else:
            resumed = _in_child(_build(new, resume=True))
        got = _snapshot(out) if resumed == 0 else {}
        if resumed != 0 or got != reference:
            diff = sorted(k for k in set(got) | set(reference) if got.get(k) != reference.get(k))
            mismatched.append({"kill_at": n, "op": ops[n - 1], "resume": resumed, "diff": diff})
    return {
        "ops": ops,
        "points": points,
        "killed": sum(s == -signal.SIGKILL for s in statuses),
        "mismatched": mismatched,
        "untouched": untouched,
        "files": sorted(reference),
    }


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]), Path(sys.argv[2]))))
