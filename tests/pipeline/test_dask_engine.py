"""The build on Dask: a LocalCluster of 2 processes gives the local engine's bytes, a killed
worker costs a retry, --resume crosses engines, the CLI runs it."""

from __future__ import annotations

import hashlib
import os
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml

from mars_pairs.cli.main import main
from mars_pairs.errors import WorkerStartError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from support.configs import config_file
from support.missions import MissionCache

distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")

from mars_pairs.pipeline.builder.dask_engine import DaskEngine  # noqa: E402

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mission(missions: MissionCache) -> Path:
    return missions(seed=3, stops=3, images_per_stop=2)


@pytest.fixture(scope="module")
def cluster():
    """2 worker processes, 1 thread each (one per core of CI)."""
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
            host="127.0.0.1",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        yield cluster, client


def config(tmp: Path, mission: Path, out: str, shard_size: int = 2) -> Path:
    output = {"shard_size": shard_size, "keep_parts": True}
    return config_file(tmp / f"{out}.yaml", mission, tmp / out, fine=True, output=output)


def digests(out: Path) -> dict[str, str]:
    """sha256 of every output file but dataset.json (which holds the timing) and SHA256SUMS
    (its digest)."""
    return {
        p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(out.rglob("*"))
        if p.is_file() and p.name not in ("dataset.json", "SHA256SUMS")  # (its digest)
    }


@pytest.fixture(scope="module")
def local_build(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("local")
    run_build(load_config(config(tmp, mission, "ds")), workers=1, progress=False)
    return digests(tmp / "ds")


def test_local_cluster_gives_the_local_engines_bytes(
    mission: Path, tmp_path: Path, local_build: dict[str, str], cluster
) -> None:
    engine = DaskEngine(scheduler=cluster[0].scheduler_address, announce=False)
    summary = run_build(load_config(config(tmp_path, mission, "ds")), engine=engine, progress=False)
    assert summary.samples == 6 and summary.failures == 0
    got = digests(tmp_path / "ds")
    assert {"manifest.parquet", "failures.parquet"} <= set(got)
    assert any(name.startswith("shards/shard-000000-") for name in got)
    assert got == local_build


def test_a_killed_worker_costs_a_retry_not_the_build(
    mission: Path, tmp_path: Path, local_build: dict[str, str], cluster
) -> None:
    cl, client = cluster
    client.wait_for_workers(2)
    pids = client.run(os.getpid)
    killed: list[tuple[str, int]] = []

    def kill_a_busy_worker() -> None:  # SIGKILL the first worker seen running a chunk
        deadline = time.monotonic() + 60
        while not killed and time.monotonic() < deadline:
            busy = [w for w, tasks in client.processing().items()
                    if any(str(t).startswith("chunk-") for t in tasks)]  # fmt: skip
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append((busy[0], pids[busy[0]]))
            time.sleep(0.005)

    watcher = threading.Thread(target=kill_a_busy_worker)
    watcher.start()
    # three chunks of two labels, all in flight when the kill lands
    engine = DaskEngine(scheduler=cl.scheduler_address, announce=False, window=6)
    cfg = load_config(config(tmp_path, mission, "ds", shard_size=2))
    summary = run_build(cfg, engine=engine, progress=False)
    watcher.join()
    assert killed, "no worker was seen running a chunk"
    assert summary.samples == 6 and summary.failures == 0
    assert digests(tmp_path / "ds") == local_build
    client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed one
    assert killed[0][1] not in client.run(os.getpid).values()


def test_resume_crosses_engines_and_the_cli_runs_dask(
    mission: Path, tmp_path: Path, local_build: dict[str, str], cluster, capsys
) -> None:
    cfg_path = config(tmp_path, mission, "ds")
    run_build(load_config(cfg_path), workers=1, limit=None, progress=False)
    out = tmp_path / "ds"
    for k in (1, 2):  # as if the build were killed after its first chunk
        (out / "parts" / f"manifest-{k:06d}.parquet").unlink()
    scheduler = cluster[0].scheduler_address
    argv = ["build", "--config", str(cfg_path), "--engine", "dask", "--scheduler", scheduler]
    assert main([*argv, "--resume", "--quiet"]) == 0
    printed = capsys.readouterr()
    assert "chunks: 2 built, 1 resumed" in printed.out
    assert "dask dashboard: http://" in printed.err
    assert digests(out) == local_build


def test_scheduler_needs_the_dask_engine(mission: Path, tmp_path: Path, capsys) -> None:
    argv = ["build", "--config", str(config(tmp_path, mission, "ds")), "--scheduler", "tcp://x:1"]
    assert main(argv) == 2
    assert "--scheduler needs --engine dask" in capsys.readouterr().err


def test_a_worker_that_cannot_start_fails_the_build_once(
    mission: Path, tmp_path: Path, cluster
) -> None:
    lines = (mission / "places" / "best_interp.csv").read_text().splitlines()
    col = lines[0].split(",").index("drive")
    drop = [",".join(c for i, c in enumerate(line.split(",")) if i != col) for line in lines]
    places = tmp_path / "p.csv"
    places.write_text("\n".join(drop) + "\n")
    cfg_path = config(tmp_path, mission, "ds")
    doc = yaml.safe_load(cfg_path.read_text())
    doc["inputs"]["places"] = str(places)
    cfg_path.write_text(yaml.safe_dump(doc))
    engine = DaskEngine(scheduler=cluster[0].scheduler_address, announce=False)
    with pytest.raises(WorkerStartError, match="missing column"):
        run_build(load_config(cfg_path), engine=engine, progress=False)
