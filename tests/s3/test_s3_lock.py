"""One writer per output folder on the S3 test server (``pipeline.builder.lock``: a
conditional-put lock object): a second build, append or resume exits 2 in one line naming the
holder, the first's output is a lone run's; the stale rule."""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from mars_pairs.errors import FolderLockedError
from mars_pairs.pipeline.builder.lock import LOCK, STALE_S, folder_lock
from mars_pairs.store import fs
from support.writers import S3_CASES, two_writers


@pytest.mark.parametrize("case", S3_CASES)
def test_a_second_writer_is_refused_on_s3(
    small_mission: Path, tmp_path: Path, s3_prefix_factory: Callable[[], str], case: str
) -> None:
    two_writers(tmp_path, small_mission, s3_prefix_factory(), s3_prefix_factory(), case)


def test_stale_rule_on_s3(s3_prefix_factory: Callable[[], str]) -> None:
    """Fresh lock of another host: refused; not renewed for STALE_S, or of a dead pid on
    this host: taken over; the lock object is gone after the run."""
    now = time.time()
    cases = [
        ({"pid": 1, "host": "elsewhere", "started": "x", "renewed": now}, True),
        ({"pid": 1, "host": "elsewhere", "started": "x", "renewed": now - STALE_S - 1}, False),
        ({"pid": 2**22 + 7, "host": socket.gethostname(), "started": "x", "renewed": now}, False),
    ]
    for holder, refused in cases:
        url = s3_prefix_factory()
        fs.put_bytes(fs.join(url, LOCK), json.dumps({**holder, "token": "t"}).encode())
        if refused:
            with (
                pytest.raises(FolderLockedError, match="pid 1 on elsewhere"),
                folder_lock(url),
            ):
                pass
            continue
        with folder_lock(url):
            mine = json.loads(fs.read_bytes(fs.join(url, LOCK)))
            assert mine["pid"] == os.getpid()
        assert not fs.exists(fs.join(url, LOCK))
