"""The checks that bind a manifest row's members to the tar shards, shared by ``mars-pairs
verify`` and ``MarsPairsDataset(verify=True)``.

A member sits in its shard as a tar member named ``<key>.<field>.<ext>`` (the ground image's
full name is ``<key>.<ground_member>``): a 512-byte ustar header, then the member's bytes at
the manifest's ``<field>_offset``. A member is intact when

- its shard path is relative, without ``..``, resolves inside the dataset folder and is a
  regular file (:func:`shard_path`);
- its offset is a whole number of tar blocks after a header and ``offset + size`` lies inside
  the shard file (:func:`location_problem`; no read is ever larger than the shard);
- the header before the offset names the member of this sample and records the manifest's
  size (:func:`header_problem`: two samples' locations swapped, or a renamed key, fail here);
- its bytes have the manifest's CRC-32C where the manifest has one (:func:`data_problem`).

:func:`check_member` runs them in that order with two reads: the header, then the bytes.
"""

from __future__ import annotations

import os
import stat
import tarfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import crc32c as _crc32c
import pyarrow as pa
import pyarrow.compute as pc

from mars_pairs.errors import DatasetError
from mars_pairs.store.fs import Location, is_url, join

#: a tar block: every member's data starts this many bytes after its header's start
BLOCK = tarfile.BLOCKSIZE


def checksum(data: bytes | bytearray | memoryview) -> int:
    """CRC-32C (Castagnoli) of ``data`` as an unsigned 32-bit int (fits the int64 column)."""
    return int(_crc32c.crc32c(data))


def shard_path(root: Path, shard: str, member: str | None = None) -> Path:
    """The file of the manifest's shard path ``shard``, confined to the dataset folder.

    ``shard`` must be relative (no leading ``/``, drive or ``\\``), hold no ``..``, resolve
    (symlinks followed) inside ``root`` and name a regular file; otherwise DatasetError naming
    the shard and ``member``. A file that does not exist is an OSError (FileNotFoundError),
    as from ``open``.
    """
    problem = _path_problem(shard)
    if problem is not None:
        raise DatasetError(shard, member, problem)
    path = Path(root) / shard
    resolved = path.resolve()
    if not resolved.is_relative_to(Path(root).resolve()):
        reason = f"shard path resolves outside the dataset folder, to {resolved}"
        raise DatasetError(path, member, reason)
    mode = os.stat(resolved).st_mode
    if not stat.S_ISREG(mode):
        raise DatasetError(path, member, "shard path is not a regular file")
    return resolved


def shard_location(root: Location, shard: str, member: str | None = None) -> Location:
    """The file of the manifest's shard path ``shard`` in the dataset root ``root``: for a
    local folder :func:`shard_path`; for a URL (object storage: no links, no folders) the
    object under ``root``, ``shard`` checked as relative and without ``..`` (DatasetError
    naming the shard and ``member``)."""
    if isinstance(root, Path) or not is_url(root):
        return shard_path(Path(root), shard, member)
    problem = _path_problem(shard)
    if problem is not None:
        raise DatasetError(shard, member, problem)
    return join(root, shard)


def _path_problem(shard: object) -> str | None:
    if not isinstance(shard, str) or not shard:
        return f"bad shard path {shard!r}"
    if "\x00" in shard:
        return "shard path holds a NUL byte"
    posix, windows = PurePosixPath(shard), PureWindowsPath(shard)
    if posix.is_absolute() or windows.is_absolute() or windows.drive or shard[0] in "/\\":
        return "shard path is absolute (must be relative to the dataset folder)"
    if ".." in posix.parts or ".." in windows.parts:
        return "shard path leaves the dataset folder ('..')"
    return None


@dataclass(frozen=True)
class MemberSpec:
    """What a manifest row says of one member: the sample ``key``, the ``field`` (one of
    :data:`mars_pairs.store.manifest.MEMBERS`), ``offset`` and ``size`` in bytes within the
    shard, the CRC-32C (None or negative: unknown, a dataset built before checksums) and,
    for the ground image, the member's full suffix ``ground_member`` (``ground.jpg``)."""

    key: str
    field: str
    offset: int | None
    size: int | None
    crc32c: int | None = None
    ground_member: str | None = None

    @property
    def exact(self) -> str | None:
        """The member's full tar name where the manifest records it (the ground image)."""
        if self.field == "ground" and self.ground_member:
            return f"{self.key}.{self.ground_member}"
        return None

    @property
    def name(self) -> str:
        """The member's full tar name, else ``<key>.<field>``."""
        return self.exact or f"{self.key}.{self.field}"

    def names(self, tar_name: str) -> bool:
        """Whether a tar header's ``tar_name`` is this member's."""
        exact = self.exact
        if exact is not None:
            return tar_name == exact
        return tar_name.startswith(f"{self.key}.{self.field}.")


def location_problem(spec: MemberSpec, shard_size: int) -> str | None:
    """What is wrong with the member's place in a shard of ``shard_size`` bytes, or None."""
    offset, size = spec.offset, spec.size
    if offset is None or size is None or offset < 0 or size < 0:
        return f"no valid offset/size in the manifest ({offset}, {size})"
    if offset < BLOCK or offset % BLOCK:
        return f"offset {offset} is not after a tar header"
    return bounds_problem(offset, size, shard_size)


def bounds_problem(offset: int, size: int, shard_size: int) -> str | None:
    """Whether ``size`` bytes at ``offset`` lie inside a file of ``shard_size`` bytes."""
    if offset < 0 or size < 0:
        return f"cannot read: no valid offset/size in the manifest ({offset}, {size})"
    if offset + size > shard_size:
        return (
            f"cannot read {size} bytes at offset {offset}: past the end of the shard "
            f"({shard_size} bytes)"
        )
    return None


def header_problem(spec: MemberSpec, header: bytes | bytearray) -> str | None:
    """What is wrong with the tar header just before the member's offset, or None."""
    at = (spec.offset or 0) - BLOCK
    if len(header) != BLOCK:
        return f"truncated tar header at offset {at}"
    try:
        info = tarfile.TarInfo.frombuf(bytes(header), "utf-8", "surrogateescape")
    except tarfile.TarError as exc:
        return f"bad tar header at offset {at}: {exc}"
    if not spec.names(info.name):
        return f"tar header names {info.name!r} at offset {at}"
    if info.size != spec.size:
        return f"size {spec.size} in the manifest, {info.size} in the tar header"
    return None


def data_problem(spec: MemberSpec, data: bytes | bytearray) -> str | None:
    """What is wrong with the member's bytes (length, CRC-32C), or None."""
    return bytes_problem(data, spec.size, spec.crc32c)


def bytes_problem(data: bytes | bytearray, size: int | None, crc32c: int | None) -> str | None:
    """What is wrong with a member's bytes read: not ``size`` bytes long, or not of CRC-32C
    ``crc32c`` (None or negative: not checked); None when intact."""
    if len(data) != size:
        return f"truncated: {len(data)} of {size} bytes"
    if crc32c is not None and crc32c >= 0:
        got = checksum(data)
        if got != crc32c:
            return f"checksum mismatch (crc32c {got:#010x}, manifest {crc32c:#010x})"
    return None


def repeated_keys(keys: pa.Array | pa.ChunkedArray) -> list[tuple[str | None, int]]:
    """Every sample key that more than one manifest row holds (``keys``: the manifest's key
    column), with its row count, sorted by key (a manifest names each sample once)."""
    counts = pc.value_counts(keys)
    repeated = pc.filter(counts, pc.greater(counts.field("counts"), 1)).to_pylist()
    return sorted(((r["values"], r["counts"]) for r in repeated), key=lambda kn: str(kn[0]))


def check_member(
    spec: MemberSpec, read: Callable[[int, int], bytes | bytearray], shard_size: int
) -> tuple[bytes | bytearray | None, str | None]:
    """Check one member in a shard of ``shard_size`` bytes; ``read(offset, size)`` reads the
    shard (it may return fewer bytes at the end of the file, or raise OSError).

    Returns (the member's bytes, None) when intact, else (None, what is wrong).
    """
    problem = location_problem(spec, shard_size)
    if problem is not None:
        return None, problem
    assert spec.offset is not None and spec.size is not None  # location_problem checked
    offset, size = int(spec.offset), int(spec.size)
    problem = header_problem(spec, read(offset - BLOCK, BLOCK))
    if problem is not None:
        return None, problem
    data = read(offset, size)
    problem = data_problem(spec, data)
    return (None, problem) if problem is not None else (data, None)
