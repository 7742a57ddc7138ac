"""The fetch cache: archive-relative paths mapped under one root, and nothing outside it.

An archive path (from an index row, an inventory or a config) is a POSIX path relative to the
archive root. It may not be absolute, contain ``..``, a backslash, a drive or an empty
component, and no component inside the cache may be a symlink: the file lands exactly at
``root / path`` or the entry is refused with a ``FetchError`` naming it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path, PurePosixPath

from mars_pairs.errors import FetchError
from mars_pairs.store.atomic import atomic_write_bytes

_DRIVE = re.compile(r"^[A-Za-z]:")


def archive_path(entry: str, *, where: str = "index entry") -> PurePosixPath:
    """A validated archive-relative path; refuses absolute paths, '..', '\\' and drives."""
    text = str(entry).strip()
    if not text:
        raise FetchError(where, "empty path")
    if "\\" in text or _DRIVE.match(text) or "\x00" in text:
        raise FetchError(where, f"refused path {text!r} (backslash, drive or NUL)")
    path = PurePosixPath(text)
    if path.is_absolute():
        raise FetchError(where, f"refused absolute path {text!r}")
    parts = [p for p in path.parts if p != "."]
    if not parts or any(p == ".." for p in parts):
        raise FetchError(where, f"refused path {text!r} (escapes the archive root)")
    return PurePosixPath(*parts)


def join_url(root: str, rel: PurePosixPath | str) -> str:
    """The URL of an archive-relative path under an archive root URL."""
    return root.rstrip("/") + "/" + str(rel).lstrip("/")


class Cache:
    """A cache root; ``path(rel)`` is where the archive file ``rel`` is stored."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).expanduser().resolve()

    def path(self, rel: PurePosixPath | str, *, where: str = "index entry") -> Path:
        """``root / rel`` after checking ``rel`` and that no component under root is a symlink."""
        rel = archive_path(str(rel), where=where)
        target = self.root.joinpath(*rel.parts)
        probe = self.root
        for part in rel.parts:
            probe = probe / part
            if probe.is_symlink():
                raise FetchError(where, f"refused {rel}: {probe} is a symlink in the cache")
        if os.path.commonpath([self.root, target]) != str(self.root):  # belt and braces
            raise FetchError(where, f"refused {rel}: outside the cache root {self.root}")
        return target

    def write_bytes(self, rel: PurePosixPath | str, data: bytes) -> Path:
        """Write ``data`` at ``rel`` atomically (temporary name, then rename)."""
        target = self.path(rel)
        atomic_write_bytes(target, data)
        return target
