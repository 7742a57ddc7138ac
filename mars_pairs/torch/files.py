"""Shard files opened lazily per process, with positioned reads confined to the dataset
folder and to each file's size; on object storage (a URL root), one range request a read."""

from __future__ import annotations

import contextlib
import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs
from mars_pairs.store.integrity import bounds_problem, shard_location, shard_path

#: the most bytes between two members :meth:`ShardFiles.read_adjacent` reads past (a tar
#: header and the previous member's padding take 512 to 1023)
MAX_GAP = 4096


class ShardFiles:
    """Shard file descriptors, opened lazily and per process (safe under fork and spawn).

    At most ``max_open`` stay open (least recently used closed first), so datasets with many
    shards do not run out of descriptors. Reads are positioned (``preadv``): no seek state.
    A shard path that is not confined to ``root`` (:func:`~mars_pairs.store.integrity.
    shard_path`) and a read past a shard's end raise DatasetError naming the shard (no
    member: the caller adds it) before anything is read or allocated; I/O errors are OSError.
    A dataset on object storage (``root`` a URL: ``store.fs``) holds no descriptors: each
    read is one range request (fsspec), each shard's size is asked once.
    """

    def __init__(self, root: fs.Location, max_open: int = 64) -> None:
        self.root = root
        self._remote = not isinstance(root, Path)
        self.max_open = max_open
        self._pid = -1
        self._files: OrderedDict[str, tuple[int, int]] = OrderedDict()

    def _fd(self, shard: str) -> tuple[int, int]:
        """(descriptor, size in bytes) of ``shard``, opened if need be."""
        if self._pid != os.getpid():  # inherited through fork: the parent's, leave them be
            self._files, self._pid = OrderedDict(), os.getpid()
        entry = self._files.get(shard)
        if entry is None and self._remote:
            size = fs.size(shard_location(self.root, shard))
            entry = self._files[shard] = (-1, size)
        elif entry is None:
            while len(self._files) >= self.max_open:
                os.close(self._files.popitem(last=False)[1][0])
            fd = os.open(shard_path(Path(self.root), shard), os.O_RDONLY)
            entry = self._files[shard] = (fd, os.fstat(fd).st_size)
        else:
            self._files.move_to_end(shard)
        return entry

    def size(self, shard: str) -> int:
        """The size in bytes of ``shard`` (as when this process opened it)."""
        return self._fd(shard)[1]

    def read(self, shard: str, offset: int, size: int) -> bytearray:
        """``size`` bytes at ``offset``, into a fresh writable buffer."""
        fd, shard_size = self._fd(shard)
        problem = bounds_problem(offset, size, shard_size)
        if problem is not None:
            raise DatasetError(fs.join(self.root, shard), None, problem)
        if self._remote:
            data = fs.read_range(shard_location(self.root, shard), offset, size)
            if len(data) != size:
                where = fs.join(self.root, shard)
                raise OSError(f"{where}: short read at offset {offset}")
            return bytearray(data)
        buf = bytearray(size)
        view, done = memoryview(buf), 0
        while done < size:
            if hasattr(os, "preadv"):
                n = os.preadv(fd, [view[done:]], offset + done)
            else:  # no positioned reads (Windows)
                os.lseek(fd, offset + done, os.SEEK_SET)
                chunk = os.read(fd, size - done)
                view[done : done + len(chunk)] = chunk
                n = len(chunk)
            if n <= 0:
                raise OSError(f"{fs.join(self.root, shard)}: short read at offset {offset}")
            done += n
        return buf

    def read_adjacent(
        self, shard: str, spans: Sequence[tuple[int, int]], max_gap: int = MAX_GAP
    ) -> list[bytearray] | None:
        """``read`` of each ``(offset, size)`` of ``spans`` (one shard's members, in file
        order) in one positioned scatter read (``preadv``: each member into its own buffer,
        the tar headers between them into a scratch one); None, having read nothing, where
        that cannot be done: a remote or Windows shard, spans out of order, a gap over
        ``max_gap`` bytes, a span outside the shard (``read`` then names the fault)."""
        if self._remote or not hasattr(os, "preadv") or not spans:
            return None
        fd, shard_size = self._fd(shard)
        end = spans[0][0]
        gaps = []
        for offset, size in spans:
            gap = offset - end
            if gap < 0 or gap > max_gap or bounds_problem(offset, size, shard_size) is not None:
                return None
            gaps.append(gap)
            end = offset + size
        scratch = memoryview(bytearray(max(gaps)))
        out = [bytearray(size) for _, size in spans]
        buffers: list[memoryview | bytearray] = []
        for gap, buf in zip(gaps, out, strict=True):
            if gap:
                buffers.append(scratch[:gap])
            buffers.append(buf)
        start, total = spans[0][0], end - spans[0][0]
        if os.preadv(fd, buffers, start) != total:  # short (a shard cut meanwhile): one by one
            return None
        return out

    @property
    def remote(self) -> bool:
        """Whether the shards are on object storage (``root`` a URL)."""
        return self._remote

    def read_many(self, requests: list[tuple[str, int, int]]) -> list[bytearray]:
        """``read`` of each ``(shard, offset, size)`` of ``requests``, in order; on object
        storage one concurrent batch of range requests (``store.fs.read_ranges``)."""
        if not self._remote:
            return [self.read(shard, offset, size) for shard, offset, size in requests]
        urls = []
        for shard, offset, size in requests:
            problem = bounds_problem(offset, size, self._fd(shard)[1])
            if problem is not None:
                raise DatasetError(fs.join(self.root, shard), None, problem)
            urls.append((str(shard_location(self.root, shard)), offset, size))
        out = [bytearray(data) for data in fs.read_ranges(urls)]
        for (shard, offset, size), data in zip(requests, out, strict=True):
            if len(data) != size:
                raise OSError(f"{fs.join(self.root, shard)}: short read at offset {offset}")
        return out

    def close(self) -> None:
        """Close this process's descriptors."""
        if self._pid == os.getpid():
            for fd, _ in self._files.values():
                if fd >= 0:
                    os.close(fd)
        self._files = OrderedDict()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def __getstate__(self) -> dict[str, Any]:
        return {
            "root": self.root,
            "max_open": self.max_open,
            "_remote": self._remote,
            "_pid": -1,
            "_files": {},
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state, _files=OrderedDict())
