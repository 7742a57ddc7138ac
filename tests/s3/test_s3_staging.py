"""No leftovers: the local staging folders of a build to object storage
(``mars-pairs-upload-<pid>-*`` in TMPDIR) that a killed build left are removed by the next
build or ``--resume`` to object storage; a running process's stay."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.store import fs
from support.builds import small_doc


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_killed_builds_staging_is_removed_by_the_next_build(
    small_mission: Path, tmp_path: Path, s3_prefix: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mars_pairs.pipeline.config import parse_config

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    dead = tmp / f"{fs.STAGING_PREFIX}{_dead_pid()}-abc"
    (dead / "parts").mkdir(parents=True)
    (dead / "parts" / "shard.tar").write_bytes(b"x" * 1000)
    alive = tmp / f"{fs.STAGING_PREFIX}{os.getpid()}-def"
    alive.mkdir()
    stranger = tmp / "mars-pairs-uploads-not-ours"
    stranger.mkdir()
    doc = small_doc(small_mission, Path("/unused"))
    doc["output"]["dir"] = s3_prefix
    summary = run_build(parse_config(doc, base=small_mission), progress=False, resume=True)
    assert summary.failures == 0
    assert not dead.exists()
    assert alive.is_dir() and stranger.is_dir()
    assert sorted(p.name for p in tmp.iterdir()) == sorted([alive.name, stranger.name])
