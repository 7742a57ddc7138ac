"""A build whose output folder is on the S3 test server equals the same build on local disk,
byte for byte; it survives a worker killed mid-upload (``--resume``); the readers read it."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from built_dataset import build_config

from mars_pairs.pipeline.build.run import run_build
from mars_pairs.pipeline.config import BuildConfig, parse_config
from mars_pairs.store import fs

#: The files whose bytes a build makes the same wherever it writes them (besides the shards;
#: shardindex.json names the folder).
SAME_BYTES = ("manifest.parquet", "failures.parquet")


def config_for(mission: Path, out: str | Path, **sections: Any) -> BuildConfig:
    """The cheap build of ``mission`` (2 samples a shard) into ``out`` (a folder or URL)."""
    doc = build_config(mission, Path("/unused"), **sections)
    doc["output"]["dir"] = str(out)
    return parse_config(doc, base=mission)


def digests(root: str | Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (a folder or a URL) but the build's own card."""
    root = fs.dataset_root(root)
    return {
        rel: hashlib.sha256(fs.read_bytes(fs.join(root, rel))).hexdigest()
        for rel in fs.list_files(root)
        if rel.startswith("shards/") or rel in SAME_BYTES
    }


@pytest.fixture(scope="module")
def local_build(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("s3_local") / "ds"
    summary = run_build(config_for(small_mission, out), progress=False)
    assert summary.samples == 4 and summary.failures == 0
    return out


def test_a_build_to_s3_equals_the_local_build(
    small_mission: Path, local_build: Path, s3_prefix: str
) -> None:
    """Two workers upload their shards; the manifest, failures, shards and shard index on
    the server have the bytes of the local build; parts/ is gone; every dataset file is
    there."""
    summary = run_build(config_for(small_mission, s3_prefix), workers=2, progress=False)
    assert (summary.samples, summary.chunks_built) == (4, 2)
    assert digests(s3_prefix) == digests(local_build)
    files = fs.list_files(s3_prefix)
    assert not [f for f in files if f.startswith("parts/")]
    for name in ("dataset.json", "README.md", "croissant.json", "shardindex.json"):
        assert name in files
    # a resume over the finished build does nothing
    again = run_build(config_for(small_mission, s3_prefix), resume=True, progress=False)
    assert (again.chunks_built, again.samples) == (0, 4)


@pytest.mark.parametrize(
    "target", ["shards/shard-000001.tar", "parts/.manifest-000001.parquet.tmp-"], ids=str
)
def test_a_worker_killed_mid_upload_resumes_to_the_same_bytes(
    small_mission: Path, local_build: Path, s3_prefix: str, target: str
) -> None:
    """The worker (the one process of a build: ``kill_upload_driver.py``) dies while
    uploading chunk 1's shard or its staged manifest part: nothing appears under that name,
    chunk 0 stays committed, and ``resume`` gives the local build's bytes."""
    config = config_for(small_mission, s3_prefix)
    here = Path(__file__).resolve().parent
    path = os.pathsep.join(
        [str(here.parents[1]), str(here.parent), os.environ.get("PYTHONPATH", "")]
    )
    run = subprocess.run(
        [
            sys.executable,
            str(here / "kill_upload_driver.py"),
            str(small_mission),
            s3_prefix,
            target,
        ],
        env={**os.environ, "PYTHONPATH": path},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == -signal.SIGKILL, run.stderr[-2000:]
    files = fs.list_files(s3_prefix)
    assert "parts/manifest-000000.parquet" in files  # chunk 0 committed
    assert "parts/manifest-000001.parquet" not in files and "manifest.parquet" not in files
    assert not [f for f in files if target in f]  # never completed, never there
    summary = run_build(config, resume=True, progress=False)
    assert (summary.chunks_built, summary.chunks_resumed) == (1, 1)
    assert digests(s3_prefix) == digests(local_build)
    assert not [f for f in fs.list_files(s3_prefix) if ".tmp-" in f]
