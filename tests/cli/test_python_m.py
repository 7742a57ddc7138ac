"""``python -m mars_pairs`` runs the command line: the same parser, the same exit codes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mars_pairs", *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )


def test_python_m_mars_pairs_prints_the_version() -> None:
    done = _run("--version")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("mars-pairs ")


def test_python_m_mars_pairs_help_lists_the_commands() -> None:
    done = _run("--help")
    assert done.returncode == 0, done.stderr
    assert "usage: mars-pairs" in done.stdout
    for command in ("build", "inspect", "verify", "query", "fetch", "export-qgis"):
        assert command in done.stdout


def test_python_m_mars_pairs_bad_input_exits_2_with_one_line(tmp_path: Path) -> None:
    done = _run("inspect", str(tmp_path / "missing"))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mars-pairs inspect: "), done.stderr
