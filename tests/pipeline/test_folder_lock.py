"""One writer per output folder (``pipeline.builder.lock``): while a build, ``--resume`` or
``--append`` holds a folder, a second one exits 2 in one line naming the holder, and the
first's output is a lone run's; a dead holder does not block the next run. Locally
(``fcntl.flock``) and on the S3 test server (a conditional-put lock object)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import FolderLockedError
from mars_pairs.pipeline.builder.lock import LOCK, folder_lock
from support.writers import CASES, DRIVER, cli, lock_config, two_writers


@pytest.mark.parametrize("case", [c for c in CASES if c != "build+resume"])
def test_a_second_writer_is_refused_locally(small_mission: Path, tmp_path: Path, case: str) -> None:
    two_writers(tmp_path, small_mission, tmp_path / "ds", tmp_path / "lone", case)


def test_a_killed_holder_does_not_block(small_mission: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    config = lock_config(tmp_path, small_mission, out)
    gate = tmp_path / "gate"
    holder = subprocess.Popen(
        [sys.executable, str(DRIVER), str(gate), "build", "--config", str(config), "--quiet"]
    )
    while not gate.with_suffix(".locked").exists():
        assert holder.poll() is None
        time.sleep(0.05)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert cli("build", "--config", str(config), "--quiet").returncode == 0
    assert cli("verify", str(out)).returncode == 0


def test_the_lock_is_known_to_the_folder_hygiene(small_mission: Path, tmp_path: Path) -> None:
    """A rebuild over a folder holding the lock file (and nothing else, or a dataset) does not
    call it foreign; a run that leaves nothing leaves no folder."""
    out = tmp_path / "ds"
    config = lock_config(tmp_path, small_mission, out)
    for _ in range(2):
        assert cli("build", "--config", str(config), "--quiet").returncode == 0
        assert (out / LOCK).is_file()
    assert main(["build", "--config", str(config), "--resume", "--quiet"]) == 0
    empty = tmp_path / "empty"
    with folder_lock(empty):
        assert (empty / LOCK).is_file()
    assert not empty.exists()


def test_the_same_process_cannot_take_a_held_lock_twice(tmp_path: Path) -> None:
    with (
        folder_lock(tmp_path / "ds"),
        pytest.raises(FolderLockedError, match=f"pid {os.getpid()}"),
        folder_lock(tmp_path / "ds"),
    ):
        pass
