"""What kind of file a config's path names: a FIFO, a socket or a device is refused by name."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from mars_pairs.errors import ConfigError

_KINDS = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISDIR, "a folder"),
)


def file_kind(mode: int) -> str | None:
    """What a file of ``st_mode`` ``mode`` is, when it is not a regular file (None)."""
    for test, kind in _KINDS:
        if test(mode):
            return kind
    return None if stat.S_ISREG(mode) else "not a regular file"


def regular_problem(path: Path | str, *, folder: bool = False) -> str | None:
    """What is wrong when ``path`` exists and is not a regular file (with ``folder``: not a
    folder), else None: a FIFO, a socket or a device would block or never end when read. An
    absent path, a URL and a GDAL ``/vsi`` path pass (what opens them says why they do not).
    Checked by ``stat``, without opening the path."""
    text = str(path)
    if text.startswith("/vsi") or "://" in text:
        return None
    try:
        mode = os.stat(text).st_mode
    except (OSError, ValueError):
        return None
    if folder and stat.S_ISDIR(mode):
        return None
    kind = file_kind(mode)
    if kind is None:
        return None
    return f"{path} is {kind}, expected {'a folder' if folder else 'a regular file'}"


def check_regular(path: Path | str, key: str, *, folder: bool = False) -> None:
    """ConfigError naming ``key`` and ``path`` when ``regular_problem`` finds one."""
    problem = regular_problem(path, folder=folder)
    if problem is not None:
        raise ConfigError(f"{key}: {problem}")
