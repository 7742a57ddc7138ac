"""A rebuild over an old dataset killed (SIGKILL) at every kind of its file operations (the
first and the last of each), each time resumed with ``resume=True``, ends byte-identical to a
clean build."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from support.configs import config_file

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

DRIVER = Path(__file__).with_name("crash_driver.py")


def _config(path: Path, mission: Path, out: Path, labels: str, shard_size: int) -> Path:
    return config_file(
        path, mission, out, labels=mission / "labels" / labels,
        geometry={"radius": 200, "ray_stride": 64}, chips={"size_m": 32, "size_px": 16},
        output={"shard_size": shard_size},
    )  # fmt: skip


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="the driver forks its builds")
def test_a_rebuild_killed_at_every_file_operation_resumes_byte_identical(
    small_mission: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    # the old dataset: all 4 images in 4 chunks; the rebuild: the 2 left-camera images in 2,
    # so the clearing removes shards and parts the new build will not write again
    old = _config(tmp_path / "old.yaml", small_mission, out, "*.xml", shard_size=1)
    new = _config(tmp_path / "new.yaml", small_mission, out, "ZLF*.xml", shard_size=1)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(
        [sys.executable, str(DRIVER), str(new), str(old)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    ops = [tuple(op) for op in report["ops"]]
    assert report["mismatched"] == [], report["mismatched"]
    points = report["points"]
    # every kind of operation (its path's digits masked) is a kill point at its first and last
    # occurrence, and every operation before the old dataset changes
    kinds = {(op, re.sub(r"\d+", "#", path)) for op, path in ops}
    assert {(ops[n - 1][0], re.sub(r"\d+", "#", ops[n - 1][1])) for n in points} == kinds
    assert report["killed"] == len(points)  # every kill point was reached and killed the build
    # only kills before the first change leave the old dataset (which resume refuses, its
    # config being another): the ops before its stamp goes (a finished build's stamp is its
    # dataset.json, renamed to parts/clearing.json)
    first_change = ops.index(("replace", "dataset.json")) + 1
    assert report["untouched"] == list(range(1, first_change + 1))
    assert set(range(1, first_change + 1)) <= set(points)
    # the kill points cover the clearing of every old output and every commit of the new one
    unlinked = {path for op, path in ops if op == "unlink"}
    old = ("parts/clearing.json", "manifest.parquet", "failures.parquet", "README.md")
    for stale in (*old, "croissant.json"):
        assert stale in unlinked
    assert {
        k for k in range(4) if any(p.startswith(f"shards/shard-00000{k}-") for p in unlinked)
    } == {
        0,
        1,
        2,
        3,
    }
    # the finished old build left no parts; the new one removes its own as it finishes
    assert {f"parts/manifest-00000{k}.parquet" for k in range(2)} <= unlinked
    assert "parts/build.json" in unlinked and ops[-1] == ("rmdir", "parts")
    assert not [f for f in report["files"] if f.startswith("parts/")]
    replaced = [path for op, path in ops if op == "replace"]
    assert {p.startswith("shards/.shard-000000-") and ".tar.tmp-" in p for p in replaced} != {False}
    assert sum(p.startswith("parts/.manifest-") for p in replaced) == 2
    assert not [f for f in report["files"] if f.startswith("shards/shard-000002")]  # the old third
