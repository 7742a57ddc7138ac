"""Atomic writes: every file mars-pairs writes goes through a temporary name and a rename.

The temporary name of ``folder/NAME`` is ``folder/.NAME.tmp-<pid>`` (:func:`temporary_path`;
a writer that needs the file's extension appends it: ``.NAME.tmp-<pid>.gpkg``), recognised by
:func:`temporary_target`, so a killed writer's leftovers can be found and removed. The data is
synced (``fsync``) before the rename: after a crash, ``NAME`` is either the old file or the
whole new one. The folder itself is not synced.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

_TEMPORARY = re.compile(r"\.(?P<name>[^/]+)\.tmp-[0-9]+")


def temporary_path(path: Path, suffix: str = "") -> Path:
    """The temporary name this process writes ``path`` under: ``.NAME.tmp-<pid>`` beside it,
    then ``suffix`` (for a writer that picks its format by extension)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}{suffix}")


def temporary_target(name: str) -> str | None:
    """``NAME`` when the file name ``name`` is a temporary name ``.NAME.tmp-<pid>`` (no
    suffix), else None."""
    m = _TEMPORARY.fullmatch(name)
    return None if m is None else m["name"]


@contextmanager
def naming(path: Path) -> Iterator[None]:
    """Re-raise an OSError that names no file (a full disk: ``[Errno 28] No space left on
    device``) as one naming ``path``."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None:
            raise
        if exc.errno is None:
            raise OSError(f"{path}: {exc}") from exc
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


def sync_file(path: Path) -> None:
    """Flush ``path``'s data to the disk (``fsync``)."""
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def rename_into_place(tmp: Path, path: Path) -> None:
    """Rename the synced temporary ``tmp`` to ``path`` (atomic on one file system)."""
    os.replace(tmp, path)


@contextmanager
def staged_path(path: Path, suffix: str = "") -> Iterator[Path]:
    """The temporary name of ``path`` (:func:`temporary_path`) for the caller to write; synced
    when the block ends cleanly, removed when it raises. Not renamed: the caller commits it
    (:func:`rename_into_place`)."""
    tmp = temporary_path(path, suffix)
    try:
        with naming(path):
            yield tmp
            sync_file(tmp)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_path(path: Path, suffix: str = "") -> Iterator[Path]:
    """Write ``path`` all or nothing: the caller writes the yielded temporary name, which is
    synced and renamed to ``path`` when the block ends cleanly, removed when it raises."""
    with staged_path(path, suffix) as tmp:
        yield tmp
    rename_into_place(tmp, path)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary name and a rename (all or nothing); the
    folder is created when missing."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        with naming(path), open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    rename_into_place(tmp, path)


def write_parquet_staged(table: pa.Table, path: Path, row_group_size: int = 4096) -> Path:
    """Write the Parquet file of ``path`` (zstd, statistics) under its temporary name, synced,
    and return that name: renaming it to ``path`` is the caller's (:func:`rename_into_place`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with staged_path(path) as tmp:
        pq.write_table(
            table, tmp, row_group_size=row_group_size, compression="zstd", write_statistics=True
        )
    return tmp


def write_parquet_atomic(table: pa.Table, path: Path, row_group_size: int = 4096) -> None:
    """Write a Parquet file through a temporary name and a rename."""
    rename_into_place(write_parquet_staged(table, path, row_group_size), path)
