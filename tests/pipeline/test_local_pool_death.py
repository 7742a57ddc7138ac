"""A build worker that dies mid-build fails the build at once (no hang), naming a label in
flight; a rerun with --resume finishes it with the same bytes as an undisturbed build."""

from __future__ import annotations

import hashlib
import os
import signal
import threading
import time
from pathlib import Path

import pytest
from mission_config import cheap_config

from mars_pairs.pipeline import local_pool
from mars_pairs.pipeline.build import run_build
from mars_pairs.pipeline.local_pool import WorkerDiedError


def _digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name not in ("dataset.json", "shardindex.json")  # hold paths
    }


def test_a_killed_worker_fails_the_build_and_resume_finishes_it(
    small_mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pools: list[local_pool.LocalPool] = []
    init = local_pool.LocalPool.__init__

    def keep(self, *args, **kwargs):  # the test's handle on the pool's processes
        init(self, *args, **kwargs)
        pools.append(self)

    monkeypatch.setattr(local_pool.LocalPool, "__init__", keep)

    def kill_one() -> None:
        while not pools or not pools[0]._pool._processes:
            time.sleep(0.01)
        time.sleep(0.3)
        pid = next(iter(pools[0]._pool._processes))
        os.kill(pid, signal.SIGKILL)

    killer = threading.Thread(target=kill_one)
    killer.start()
    start = time.perf_counter()
    with pytest.raises(WorkerDiedError, match="rerun with --resume"):
        run_build(
            cheap_config(small_mission, tmp_path / "ds", output={"shard_size": 1}),
            workers=2,
            progress=False,
        )
    killer.join()
    assert time.perf_counter() - start < 60  # failed, not hung
    monkeypatch.undo()
    resumed = run_build(
        cheap_config(small_mission, tmp_path / "ds", output={"shard_size": 1}),
        workers=2,
        resume=True,
        progress=False,
    )
    clean = run_build(
        cheap_config(small_mission, tmp_path / "clean", output={"shard_size": 1}),
        workers=1,
        progress=False,
    )
    assert resumed.samples == clean.samples > 0
    assert _digest(tmp_path / "ds") == _digest(tmp_path / "clean")
