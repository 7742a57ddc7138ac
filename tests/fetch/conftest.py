"""Fixtures: a real loopback HTTP server over a folder (see fetch_server.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from fetch_server import ArchiveServer


@pytest.fixture()
def served(tmp_path: Path):
    """(server, archive root): an empty archive folder served on 127.0.0.1."""
    root = tmp_path / "archive"
    root.mkdir()
    with ArchiveServer(root, slow_s=1.0) as srv:
        yield srv, root
