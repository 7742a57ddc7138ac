"""The driver's record of the sample keys built so far, on disk: memory flat in the archive.

A build refuses a second label with a sample key already built (``commit.select_chunk``
asks ``key in seen`` and ``seen[key]`` for every key of a chunk, then records the chunk's
own). :class:`KeyIndex` answers those from an SQLite table (the standard library's
``sqlite3``; key the primary key, so a lookup is one B-tree search) in a scratch file,
with a page cache of a few MiB: the driver holds no key, whatever the count. The file is
``parts/keys.sqlite`` of a local output folder (``layout.KEY_INDEX``: removed when the
build's commits end; one a killed build left is a build file, cleared with the others or
replaced by the resumed build's), and in the local staging folder of an object storage
output (``store.fs.local_staging``, where its uploads are staged: removed when the build
ends, a killed driver's by ``fs.remove_stale_staging`` at the next build). The index is
scratch: a resumed build or an append fills it again from the committed manifest parts
(:meth:`KeyIndex.add_parts`) or the dataset's manifest, so it needs no journal and no sync.
An append's plan also records there the label paths the dataset holds (``known``), which it
skips.

Measured (``benchmarks/bench_scale.py``, the chunk job stubbed, load ~10): the driver's peak
resident set over the commit pass grew by 3.4 MiB at 10k labels and 11.9 MiB at 100k (the
8 MiB page cache filled), where a dict of the keys grew by 4.5 and 28.4 MiB (~265 bytes a
key), for ~15 % more driver CPU a label (158 against 138 us at 100k).
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import pyarrow.parquet as pq

from mars_pairs.pipeline.builder.layout import KEY_INDEX, part_paths
from mars_pairs.store import fs

#: The SQLite page cache, KiB (``PRAGMA cache_size`` takes a negative count of KiB).
CACHE_KIB = 8192
#: Rows of a manifest read at a time when filling the index from one.
_BATCH = 8192


class KeyIndex(Mapping[str, str]):
    """Sample key -> the label path it was built from, in an SQLite file (a Mapping, and
    :meth:`update` with the keys of a committed chunk). Open it with :func:`open_index`."""

    def __init__(self, path: Path) -> None:
        self._db = sqlite3.connect(path, isolation_level=None)
        for pragma in (
            "journal_mode=OFF",
            "synchronous=OFF",
            "temp_store=MEMORY",
            f"cache_size=-{CACHE_KIB}",
        ):
            self._db.execute(f"PRAGMA {pragma}")
        self._db.execute("CREATE TABLE keys (key TEXT PRIMARY KEY, label TEXT NOT NULL)")
        self._db.execute("CREATE TABLE known (path TEXT PRIMARY KEY) WITHOUT ROWID")
        self._count = 0

    def __getitem__(self, key: str) -> str:
        row = self._db.execute("SELECT label FROM keys WHERE key = ?", (key,)).fetchone()
        if row is None:
            raise KeyError(key)
        return str(row[0])

    def __contains__(self, key: object) -> bool:
        if not isinstance(key, str):
            return False
        found = self._db.execute("SELECT 1 FROM keys WHERE key = ?", (key,)).fetchone()
        return found is not None

    def __iter__(self) -> Iterator[str]:
        return (str(k) for (k,) in self._db.execute("SELECT key FROM keys ORDER BY rowid"))

    def __len__(self) -> int:
        return self._count

    def update(self, built: Mapping[str, str] | Iterable[tuple[str, str]]) -> None:
        """Record ``built`` (key -> label, or pairs); a key already held keeps its first
        label (the build never records one twice: ``select_chunk`` turned it into a
        duplicate)."""
        pairs = built.items() if isinstance(built, Mapping) else built
        before = self._db.total_changes
        self._db.execute("BEGIN")
        self._db.executemany("INSERT OR IGNORE INTO keys VALUES (?, ?)", pairs)
        self._db.execute("COMMIT")
        self._count += self._db.total_changes - before

    def add_table(self, source: fs.Location) -> None:
        """Record the ``key`` and ``label_path`` of every row of the manifest (or manifest
        part) ``source``, read a batch of rows at a time."""
        with fs.open_input(source) as handle:
            parquet = pq.ParquetFile(handle)
            for batch in parquet.iter_batches(_BATCH, columns=["key", "label_path"]):
                keys = batch.column(0).to_pylist()
                labels = batch.column(1).to_pylist()
                self.update(zip(keys, labels, strict=True))

    def add_known(self, paths: Iterable[str]) -> None:
        """Record the label paths ``paths`` (relative to the labels root) as held by the
        dataset an append appends to (:meth:`is_known`)."""
        self._db.execute("BEGIN")
        self._db.executemany("INSERT OR IGNORE INTO known VALUES (?)", ((p,) for p in paths))
        self._db.execute("COMMIT")

    def is_known(self, path: str) -> bool:
        """Whether the label path ``path`` was recorded by :meth:`add_known`."""
        found = self._db.execute("SELECT 1 FROM known WHERE path = ?", (path,)).fetchone()
        return found is not None

    def add_parts(self, out: fs.Location, done: Iterable[int]) -> None:
        """Record the samples of the committed chunks ``done`` of the build in ``out``."""
        for k in done:
            self.add_table(part_paths(out, k)[1])

    def close(self) -> None:
        """Close the SQLite file (the folder holding it is the caller's)."""
        self._db.close()


@contextlib.contextmanager
def scratch_index() -> Iterator[KeyIndex]:
    """An empty :class:`KeyIndex` in a fresh local staging folder (``fs.local_staging``),
    removed when the block ends: an append's, which its plan fills with the dataset's keys
    and label paths before anything is written in the output folder."""
    with fs.local_staging() as folder:
        index = KeyIndex(folder / "keys.sqlite")
        try:
            yield index
        finally:
            index.close()


@contextlib.contextmanager
def open_index(out: fs.Location) -> Iterator[KeyIndex]:
    """An empty :class:`KeyIndex` for the build into ``out``, its file removed when the block
    ends: ``parts/keys.sqlite`` of a local folder (``parts/`` made first; one a killed build
    left is replaced), a file of a fresh local staging folder for object storage."""
    if isinstance(out, Path):
        path = out / KEY_INDEX
        path.parent.mkdir(parents=True, exist_ok=True)
        path.unlink(missing_ok=True)  # a killed build's: scratch, filled again from the parts
        index = KeyIndex(path)
        try:
            yield index
        finally:
            index.close()
            path.unlink(missing_ok=True)
        return
    with scratch_index() as index:
        yield index
