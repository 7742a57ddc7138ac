"""The local pool: results in label order, a bounded window of labels in flight, workers
forked from a server that preloaded the build's modules."""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Iterator
from pathlib import Path

import pytest

from mars_pairs.pipeline.builder.local_pool import LocalPool, pool_processes, worker_context
from support.configs import build_config


@pytest.mark.slow
def test_results_in_order_with_a_bounded_window(small_mission: Path, tmp_path: Path) -> None:
    pulled: list[str] = []

    def labels() -> Iterator[str]:  # 200 labels that fail at once (no such file)
        for i in range(200):
            pulled.append(label := str(tmp_path / f"missing_{i:03d}.xml"))
            yield label

    with LocalPool(build_config(small_mission, tmp_path / "ds"), workers=2, window=6) as pool:
        got = []
        for status, row in pool.results(labels()):
            got.append((status, row["path"]))
            assert len(pulled) - len(got) <= 6  # never more than the window ahead
    assert got == [("fail", p) for p in pulled] and len(got) == 200


def test_workers_come_from_a_fork_server_where_there_is_one() -> None:
    ctx = worker_context()
    if "forkserver" in mp.get_all_start_methods():
        assert ctx.get_start_method() == "forkserver"
    else:
        assert ctx.get_start_method() == "spawn"


def _environ(*names: str) -> dict[str, str | None]:
    import os

    return {name: os.environ.get(name) for name in names}


def test_workers_take_the_builds_settings_not_the_fork_servers_nor_the_rest(
    small_mission: Path, tmp_path: Path, monkeypatch
) -> None:
    """GDAL and AWS options set after a first build (a notebook) reach the next build's
    workers, though the fork server started before; other variables of the driver do not;
    the workers run with the process defaults (OMP_WAIT_POLICY)."""
    names = ("GDAL_HTTP_TIMEOUT", "AWS_PROFILE", "MARS_PAIRS_TEST_OPTION", "OMP_WAIT_POLICY")
    config = build_config(small_mission, tmp_path / "ds")
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with LocalPool(config, workers=1) as pool:  # starts the server if not running
        pool._pool.submit(_environ, *names).result()
    monkeypatch.setenv("GDAL_HTTP_TIMEOUT", "17")
    monkeypatch.setenv("AWS_PROFILE", "set-later")
    monkeypatch.setenv("MARS_PAIRS_TEST_OPTION", "set-later")
    with LocalPool(config, workers=1) as pool:
        seen = pool._pool.submit(_environ, *names).result()
    assert seen == {
        "GDAL_HTTP_TIMEOUT": "17",
        "AWS_PROFILE": "set-later",
        "MARS_PAIRS_TEST_OPTION": None,
        "OMP_WAIT_POLICY": "PASSIVE",
    }


@pytest.mark.slow
def test_pool_processes_are_the_pools_live_workers() -> None:
    """The one standard-library private attribute the pool reads (``pool_processes``): a
    started pool lists its worker processes, alive, with their pids; a Python that renames
    or reshapes it fails here, not silently at a Ctrl-C."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2, mp_context=mp.get_context("spawn")) as pool:
        pids = set(pool.map(_pid, range(4)))
        processes = pool_processes(pool)
        assert processes, "ProcessPoolExecutor no longer keeps its processes in _processes"
        assert {p.pid for p in processes} >= pids
        assert all(p.is_alive() for p in processes)


def _pid(_: int) -> int:
    import os

    return os.getpid()


@pytest.mark.slow
def test_run_pulls_at_most_its_window_of_chunks_ahead(small_mission: Path, tmp_path: Path) -> None:
    from mars_pairs.pipeline.builder.engine import ChunkTask

    config = build_config(small_mission, tmp_path / "ds")
    pulled: list[int] = []

    def chunks() -> Iterator[ChunkTask]:  # 12 chunks of labels that fail at once (no file)
        for k in range(12):
            pulled.append(k)
            yield ChunkTask(k, (str(tmp_path / f"missing_{k:03d}.xml"),))

    with LocalPool(config, workers=2) as pool:
        got, ahead = [], []
        for result in pool.run(config, chunks()):
            got.append(result.index)
            ahead.append(len(pulled) - len(got))
    assert got == list(range(12))
    assert max(ahead) == 2 * pool.workers  # the chunk window ahead, never more
