"""Fixtures shared by the fetch tests: the fixture archive and a loopback server over it."""

from __future__ import annotations

import pytest

from support import fetch_archive
from support.fetch_server import ArchiveServer


@pytest.fixture()
def archive(tmp_path_factory) -> fetch_archive.Archive:
    """Both synthetic missions laid out as the real archives (built once per run)."""
    return fetch_archive.shared_archive(tmp_path_factory.getbasetemp())


@pytest.fixture()
def server(archive):
    """The fixture archive on 127.0.0.1 (faults queued per request; slow_s = 1 s)."""
    with ArchiveServer(archive.root, slow_s=1.0) as srv:
        yield srv
