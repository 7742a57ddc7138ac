"""A Dask build (labels read on worker threads, where no SIGALRM timer runs) with one
pathological label among good ones costs about what the good ones cost: the bad label is a
failure row, the rest are built."""

from __future__ import annotations

import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from support.configs import config_file
from support.label_shapes import SHAPES
from support.missions import MissionCache

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")


BAD_SHAPE = "10k duplicate pointers"  # pdr alone: 59 s on a thread (quadratic)
EXTRA_BUDGET_S = 20.0  # what the bad label may add to the build of the good ones


def _config(tmp: Path, mission: Path, out: str) -> Path:
    return config_file(tmp / f"{out}.yaml", mission, tmp / out, fine=True, output={"shard_size": 2})


def test_a_dask_build_with_a_pathological_label_fails_that_label_only(
    missions: MissionCache, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = missions.copy(tmp_path / "mission", seed=5, stops=2, images_per_stop=1)
    good = sorted((mission / "labels").glob("*.xml"))
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
            host="127.0.0.1",
        ) as cluster,
        distributed.Client(cluster),
    ):  # fmt: skip
        seconds = []
        for out in ("good", "mixed"):
            if out == "mixed":  # PDS3 text named .xml: the reader sniffs the content
                (mission / "labels" / "BAD_0000.xml").write_text(SHAPES[BAD_SHAPE]())
            argv = ["build", "--config", str(_config(tmp_path, mission, out)), "--quiet"]
            start = time.perf_counter()
            code = main([*argv, "--engine", "dask", "--scheduler", cluster.scheduler_address])
            seconds.append(time.perf_counter() - start)
            assert code == 0
    capsys.readouterr()
    assert seconds[1] < seconds[0] + EXTRA_BUDGET_S, seconds  # the first one warms numba
    failures = pq.read_table(tmp_path / "mixed" / "failures.parquet").to_pylist()
    assert [(Path(f["path"]).name, f["stage"], f["error_type"]) for f in failures] == [
        ("BAD_0000.xml", "label", "LabelError")
    ]
    assert "^A: repeated more than 64 times" in failures[0]["message"]
    assert pq.read_table(tmp_path / "mixed" / "manifest.parquet").num_rows == len(good) == 2
