"""WebDataset-style tar shards, written atomically, with each member's byte offset and size."""

from __future__ import annotations

import io
import os
import tarfile
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType


@dataclass(frozen=True)
class MemberLocation:
    """Where one member's bytes sit: shard file (relative to the dataset), offset, size."""

    shard: str
    offset: int
    size: int


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary name and a rename (all or nothing)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class ShardWriter:
    """Writes one tar shard of samples: ``<key>.<field>`` members, deterministic headers.

    The tar is written under a temporary name and renamed on a clean close, so a killed build
    leaves no half-written shard. ``add`` returns each member's location for the manifest.

    >>> with ShardWriter(root, "shards/shard-000000.tar") as shard:
    ...     locs = shard.add("key", {"ground.jpg": b"...", "meta.json": b"{}"})
    """

    def __init__(self, root: Path, relpath: str) -> None:
        self.root, self.relpath = Path(root), relpath
        self.path = self.root / relpath
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        self._fh = open(self._tmp, "wb")  # noqa: SIM115 - closed in close()
        self._tar = tarfile.open(  # noqa: SIM115 - closed in close()
            fileobj=self._fh, mode="w", format=tarfile.USTAR_FORMAT
        )
        self.count = 0

    def add(self, key: str, members: dict[str, bytes]) -> dict[str, MemberLocation]:
        """Append one sample's members (field -> bytes) in the given order."""
        if "." in key or "/" in key:
            raise ValueError(f"sample key must not contain '.' or '/': {key!r}")
        out = {}
        for fld, data in members.items():
            info = tarfile.TarInfo(f"{key}.{fld}")
            info.size, info.mtime, info.mode = len(data), 0, 0o644
            info.uname = info.gname = ""
            self._tar.addfile(info, io.BytesIO(data))
            # the data ends the member, padded to whole 512-byte blocks
            padded = -(-len(data) // tarfile.BLOCKSIZE) * tarfile.BLOCKSIZE
            out[fld] = MemberLocation(self.relpath, self._tar.offset - padded, len(data))
        self.count += 1
        return out

    def close(self, commit: bool = True) -> None:
        """Finish the tar; rename it into place if ``commit``, else delete it."""
        self._tar.close()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        if commit:
            os.replace(self._tmp, self.path)
        else:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close(commit=exc_type is None)


def read_member(root: Path, location: MemberLocation) -> bytes:
    """One member's bytes by its manifest location: one seek, one read."""
    with open(Path(root) / location.shard, "rb") as fh:
        fh.seek(location.offset)
        data = fh.read(location.size)
    if len(data) != location.size:
        raise OSError(f"{location.shard}: short read at offset {location.offset}")
    return data
