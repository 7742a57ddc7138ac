"""WebDataset-style tar shards, written atomically, with each member's byte offset, size and
CRC-32C checksum (the ``crc32c`` package: hardware CRC where the CPU has it)."""

from __future__ import annotations

import contextlib
import os
import tarfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from mars_pairs.errors import ArgumentError, DatasetError
from mars_pairs.store.atomic import naming, rename_into_place, temporary_path
from mars_pairs.store.integrity import bounds_problem, bytes_problem, checksum, shard_path


@dataclass(frozen=True)
class MemberLocation:
    """Where one member's bytes sit: shard file (relative to the dataset), offset, size, and
    the CRC-32C of the bytes (None when unknown: a dataset built before checksums)."""

    shard: str
    offset: int
    size: int
    crc32c: int | None = None


_NUL = b"\0"
# a regular file's ustar header after its size field, for mtime 0, mode 0o644, uid and gid 0,
# no user or group names and blank device fields, checksum blank ("        "): as tarfile
# writes them (``TarInfo.create_ustar_header``)
_HEAD_MODE = b"0000644\0" + b"0000000\0" * 2
_HEAD_REST = (
    b"00000000000\0"  # mtime
    + b"        "  # checksum, filled in below
    + tarfile.REGTYPE
    + _NUL * 100  # linkname
    + tarfile.POSIX_MAGIC
    + _NUL * (32 + 32 + 8 + 8 + 155)  # uname, gname, devmajor, devminor, prefix
)


def ustar_header(name: str, size: int) -> bytes:
    """The 512-byte ustar header block tarfile writes for a regular member ``name`` of
    ``size`` bytes with the shards' fixed fields (mtime 0, mode 0o644, uid and gid 0, no
    user or group names), built directly for an ASCII name of at most 100 bytes and a size
    below 8 GiB; any other through ``tarfile.TarInfo.tobuf`` itself. Written by hand because
    it is on every member's path: 2.6 us a header against ``TarInfo.tobuf``'s 13.8 us
    (CPU, one process), the bytes equal (tests/store/test_shards.py)."""
    raw = name.encode("ascii", "replace")
    if len(raw) > tarfile.LENGTH_NAME or not name.isascii() or size >= 8 << 30:
        info = tarfile.TarInfo(name)
        info.size, info.mtime, info.mode = size, 0, 0o644
        info.uname = info.gname = ""
        return info.tobuf(tarfile.USTAR_FORMAT, tarfile.ENCODING, "surrogateescape")
    head = raw.ljust(100, _NUL) + _HEAD_MODE + b"%011o\0" % size + _HEAD_REST
    block = head.ljust(tarfile.BLOCKSIZE, _NUL)
    chksum = sum(block)  # the unsigned sum, the checksum field counted as spaces
    return block[:148] + b"%06o\0" % chksum + block[155:]


class ShardWriter:
    """Writes one tar shard of samples: ``<key>.<field>`` members, deterministic headers.

    The tar is written under a temporary name and renamed on a clean close, so a killed build
    leaves no half-written shard. ``add`` returns each member's location for the manifest.
    The bytes are those of ``tarfile`` in ustar format (``ustar_header``; the end: two zero
    blocks, then zeros to a whole 10240-byte record).

    >>> with ShardWriter(root, "shards/shard-000000.tar") as shard:
    ...     locs = shard.add("key", {"ground.jpg": b"...", "meta.json": b"{}"})
    """

    def __init__(self, root: Path, relpath: str) -> None:
        self.root, self.relpath = Path(root), relpath
        self.path = self.root / relpath
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temporary_path(self.path)
        self._fh = open(self._tmp, "wb")  # noqa: SIM115 - closed in close()
        self._offset = 0
        self._ended = False
        self.count = 0

    def add(self, key: str, members: dict[str, bytes]) -> dict[str, MemberLocation]:
        """Append one sample's members (field -> bytes) in the given order."""
        if "." in key or "/" in key:
            raise ArgumentError(f"sample key must not contain '.' or '/': {key!r}")
        out = {}
        for fld, data in members.items():
            size = len(data)
            # the data follows its header, padded to whole 512-byte blocks
            pad = -size % tarfile.BLOCKSIZE
            with naming(self.path):
                self._fh.write(ustar_header(f"{key}.{fld}", size))
                self._fh.write(data)
                if pad:
                    self._fh.write(_NUL * pad)
            start = self._offset + tarfile.BLOCKSIZE
            self._offset = start + size + pad
            out[fld] = MemberLocation(self.relpath, start, size, checksum(data))
        self.count += 1
        return out

    def _end(self) -> None:
        """The end of the archive as tarfile writes it: two zero blocks, then zeros to a
        whole record (``tarfile.RECORDSIZE``)."""
        if self._ended:
            return
        self._ended = True
        self._offset += 2 * tarfile.BLOCKSIZE
        self._fh.write(_NUL * (2 * tarfile.BLOCKSIZE) + _NUL * (-self._offset % tarfile.RECORDSIZE))

    def close(self, commit: bool = True) -> None:
        """Finish the tar and rename it into place if ``commit``, else delete it."""
        try:
            if commit:
                with naming(self.path):
                    self._end()
                    self._fh.flush()
                    os.fsync(self._fh.fileno())
        except OSError:
            commit = False
            raise
        finally:
            if not commit:
                with contextlib.suppress(OSError):  # a full disk cannot take the buffer either
                    self._fh.close()
                self._tmp.unlink(missing_ok=True)
        if commit:
            self._fh.close()
            rename_into_place(self._tmp, self.path)

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close(commit=exc_type is None)


def read_member(
    root: Path, location: MemberLocation, *, name: str | None = None, verify: bool = False
) -> bytes:
    """One member's bytes by its manifest location: one seek, one read.

    ``name`` (``<key>.<field>``) is named in errors; ``verify`` checks the bytes against the
    location's CRC-32C. A shard path outside ``root`` (:func:`~mars_pairs.store.integrity.
    shard_path`), a location past the shard's end, a short read, a missing shard or a
    checksum mismatch raise DatasetError naming the shard and the member.
    """
    with _ShardHandles(Path(root)) as shards:
        return shards.read(location, name, verify)


def read_members(
    root: Path,
    locations: Mapping[str, MemberLocation],
    *,
    key: str | None = None,
    verify: bool = False,
) -> dict[str, bytes]:
    """The bytes of several members (``locations``: member suffix -> location, e.g. a
    sample's), each shard confined, opened and sized once. Errors as :func:`read_member`'s,
    naming ``<key>.<suffix>`` when ``key`` is given."""
    with _ShardHandles(Path(root)) as shards:
        return {
            member: shards.read(loc, None if key is None else f"{key}.{member}", verify)
            for member, loc in locations.items()
        }


class _ShardHandles:
    """Shard files of the dataset folder ``root``, each confined and opened on first use,
    closed together."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._open: dict[str, tuple[BinaryIO, int]] = {}

    def __enter__(self) -> _ShardHandles:
        return self

    def __exit__(self, *exc: object) -> None:
        for fh, _ in self._open.values():
            fh.close()
        self._open.clear()

    def read(self, location: MemberLocation, name: str | None, verify: bool) -> bytes:
        try:
            entry = self._open.get(location.shard)
            if entry is None:
                opened = open(shard_path(self.root, location.shard, name), "rb")  # noqa: SIM115
                entry = self._open[location.shard] = (opened, os.fstat(opened.fileno()).st_size)
            fh, shard_size = entry
            problem = bounds_problem(location.offset, location.size, shard_size)
            if problem is not None:  # checked before reading: a huge size allocates nothing
                raise DatasetError(location.shard, name, f"short read: {problem}")
            fh.seek(location.offset)
            data = fh.read(location.size)
        except DatasetError as exc:
            raise DatasetError(location.shard, name, exc.reason) from None
        except OSError as exc:
            raise DatasetError(location.shard, name, f"cannot read: {exc}") from None
        problem = bytes_problem(data, location.size, location.crc32c if verify else None)
        if problem is not None:
            raise DatasetError(location.shard, name, problem)
        return data
