"""Two writers on one output folder, for the lock tests (``pipeline.builder.lock``): the
first holds the lock (``tests/pipeline/lock_driver.py``) while the second runs."""

from __future__ import annotations

import hashlib
import socket
import subprocess
import sys
import time
from pathlib import Path

import yaml

from mars_pairs.pipeline.builder.lock import LOCK
from mars_pairs.store import fs
from support.builds import small_doc

DRIVER = Path(__file__).parents[1] / "pipeline" / "lock_driver.py"
CLI = [sys.executable, "-m", "mars_pairs.cli"]
#: files that name their build (its time, its pid, its config file and folder) or the chain
#: over them: compared by name only
OWN = {"dataset.json", "SHA256SUMS", LOCK, "README.md", "shardindex.json"}
#: the pairs on object storage (where an append is not supported: a build then a resume)
S3_CASES = ("build+build", "build+append", "build+resume")


def lock_config(tmp: Path, mission: Path, out: str | Path) -> Path:
    doc = small_doc(mission, Path("/unused"))
    doc["output"]["dir"] = str(out)
    path = tmp / f"c-{hashlib.sha1(str(out).encode()).hexdigest()[:8]}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def folder_files(root: str | Path) -> dict[str, str]:
    root = fs.dataset_root(root)
    return {
        rel: "" if rel in OWN else hashlib.sha256(fs.read_bytes(fs.join(root, rel))).hexdigest()
        for rel in fs.list_files(root)
    }


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=600)


def pair(tmp: Path, config: Path, first: list[str], second: list[str]) -> tuple[int, str]:
    """Run ``first`` holding the lock (lock_driver), then ``second`` while it holds it; the
    second's exit code and stderr; the first is let go and must succeed."""
    gate = tmp / "gate"
    for suffix in (".locked", ".go"):
        gate.with_suffix(suffix).unlink(missing_ok=True)
    holder = subprocess.Popen(
        [sys.executable, str(DRIVER), str(gate), *first, "--config", str(config), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        while not gate.with_suffix(".locked").exists():
            assert holder.poll() is None, holder.communicate()
            time.sleep(0.05)
        other = cli(*second, "--config", str(config), "--quiet")
    finally:
        gate.with_suffix(".go").touch()
        _, err = holder.communicate(timeout=600)
    assert holder.returncode == 0, err
    err_lines = other.stderr.strip().splitlines()
    assert len(err_lines) == 1, other.stderr
    assert f"pid {holder.pid} on {socket.gethostname()}" in err_lines[0]
    return other.returncode, err_lines[0]


CASES = {
    "build+build": (["build"], ["build"], False),
    "build+append": (["build"], ["build", "--append"], True),
    "append+resume": (["build", "--append"], ["build", "--resume"], True),
    "build+resume": (["build"], ["build", "--resume"], False),
}


def two_writers(tmp: Path, mission: Path, out: str | Path, lone: str | Path, case: str) -> None:
    first, second, base = CASES[case]
    lone_config = lock_config(tmp, mission, lone)
    assert cli("build", "--config", str(lone_config), "--quiet").returncode == 0
    config = lock_config(tmp, mission, out)
    if base:  # the second (or the first, an append) needs a finished dataset
        assert cli("build", "--config", str(config), "--quiet").returncode == 0
    code, line = pair(tmp, config, first, second)
    assert code == 2 and "the output folder is locked by another build" in line, line
    assert folder_files(out) == folder_files(lone)
    assert cli("verify", str(out)).returncode == 0
