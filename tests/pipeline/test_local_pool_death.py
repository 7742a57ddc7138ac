"""A build worker that dies fails the build at once with WorkerDiedError (no hang, no raw
BrokenProcessPool), naming a label in flight; a rerun with --resume finishes it with the same
bytes as an undisturbed build. The worker is killed after the pool starts and before its
work is handed out, so the test never races the 4-image build."""

from __future__ import annotations

import hashlib
import os
import signal
import time
from pathlib import Path

import pytest

from mars_pairs.errors import WorkerDiedError
from mars_pairs.pipeline.builder import local_pool
from mars_pairs.pipeline.builder.run import run_build
from support.configs import build_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
        and p.name not in ("dataset.json", "SHA256SUMS", "shardindex.json")  # hold paths
    }


def test_a_killed_worker_fails_the_build_and_resume_finishes_it(
    small_mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = local_pool.LocalPool.run

    def kill_a_worker_first(self, config, chunks):  # the processes are up, no work begun
        pid = next(iter(self._pool._processes))
        os.kill(pid, signal.SIGKILL)
        while True:  # until it is gone (the fork server reaps it)
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.01)
        yield from run(self, config, chunks)

    monkeypatch.setattr(local_pool.LocalPool, "run", kill_a_worker_first)
    start = time.perf_counter()
    with pytest.raises(WorkerDiedError, match="rerun with --resume"):
        run_build(
            build_config(small_mission, tmp_path / "ds", output={"shard_size": 1}),
            workers=2,
            progress=False,
        )
    assert time.perf_counter() - start < 60  # failed, not hung
    monkeypatch.undo()
    resumed = run_build(
        build_config(small_mission, tmp_path / "ds", output={"shard_size": 1}),
        workers=2,
        resume=True,
        progress=False,
    )
    clean = run_build(
        build_config(small_mission, tmp_path / "clean", output={"shard_size": 1}),
        workers=1,
        progress=False,
    )
    assert resumed.samples == clean.samples > 0
    assert _digest(tmp_path / "ds") == _digest(tmp_path / "clean")
