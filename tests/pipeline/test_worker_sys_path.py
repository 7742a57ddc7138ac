"""The build's workers never import from the user's folder: a ``concurrent.py`` (a stdlib
name) in the folder ``mars-pairs build`` runs from is neither run nor in the way, in the fork
server, its workers or the resource tracker (``pipeline.builder.local_pool``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from support.writers import lock_config

SHADOW = """\
import pathlib
pathlib.Path(__file__).with_name("IMPORTED").write_text("imported")
raise RuntimeError("the user's concurrent.py was imported")
"""


def test_a_stdlib_shadowing_file_in_the_cwd_is_not_imported(
    small_mission: Path, tmp_path: Path
) -> None:
    cwd = tmp_path / "user"
    cwd.mkdir()
    (cwd / "concurrent.py").write_text(SHADOW)
    config = lock_config(tmp_path, small_mission, tmp_path / "ds")
    exe = [str(Path(sys.executable).with_name("mars-pairs"))]  # the installed console script
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSAFEPATH")}
    run = subprocess.run(
        [*exe, "build", "--config", str(config), "--workers", "2", "--quiet"],
        cwd=cwd, capture_output=True, text=True, timeout=900, env=env,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert not (cwd / "IMPORTED").exists(), run.stderr
    assert "RuntimeError" not in run.stderr
