"""Run ``mars-pairs ARGS...`` holding the output folder's lock until told to go on.

Run by tests/pipeline/test_folder_lock.py as ``python lock_driver.py GATE ARGS...``: once this
process holds the lock (``pipeline.builder.lock.folder_lock``), it creates ``GATE.locked`` and
waits for ``GATE.go`` before its build goes on; then it exits with the CLI's code. The CLI
itself is unchanged: only the moment between taking the lock and working is held open.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import mars_pairs.pipeline.builder.run as run
from mars_pairs.cli.main import main

gate = Path(sys.argv[1])
real_lock = run.folder_lock


@contextlib.contextmanager
def held(out: Any) -> Iterator[None]:
    with real_lock(out):
        gate.with_suffix(".locked").touch()
        while not gate.with_suffix(".go").exists():
            time.sleep(0.05)
        yield


run.folder_lock = held  # type: ignore[assignment]
sys.exit(main(sys.argv[2:]))
