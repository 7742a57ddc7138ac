"""The names of what a build writes in its output folder: chunk part paths, the stamp's path,
which files a build of so many chunks writes (``written_by``) and the temporary names a killed
build leaves (``is_temporary``).

Chunk k writes one shard per split among its samples (``shards/shard-{k:06d}-{split}.tar``:
a split's samples never share a shard with another split's), and the finished build one
shard list per split (``shards-{split}.txt``, the split's shards relative to the folder, one
a line) and one wids index per split (``shardindex-{split}.json``) beside the whole folder's.

The output folder may be object storage (an fsspec URL: ``store.fs``): the same files under
the same names, listed with one listing.
"""

from __future__ import annotations

import re
from typing import Any

from mars_pairs.store import fs
from mars_pairs.store.atomic import temporary_target
from mars_pairs.store.seal import SUMS
from mars_pairs.store.splits import SPLIT_NAME
from mars_pairs.store.wids_index import WIDS_INDEX

DROPPED_KEY = b"mars_pairs:dropped_in_buffer"


#: The output folder's lock (``pipeline.builder.lock``): every build's, kept, never cleared.
LOCK_FILE = ".mars-pairs.lock"


#: The stamp of a build whose files are being cleared (the old stamp, renamed).
CLEARING = "parts/clearing.json"


#: The driver's index of the sample keys built (``pipeline.builder.key_index``), a local
#: build's scratch file while its chunks are committed.
KEY_INDEX = "parts/keys.sqlite"


#: The folder of the finish's sorted runs (the manifest's rows: ``finish.write_merged``; the
#: leak check's samples: ``store.leakage.streamed_leak_report``), a local build's scratch
#: while the manifest is merged or checked: made on the first run written, removed when the
#: step ends; one a killed build left is cleared or replaced by the next build.
SORT_RUNS = "parts/sort"
SORT_RUN_FILE = re.compile(r"parts/sort/(run|merged)-[0-9]{3,}(-[0-9]{6,})?\.arrow")


def is_sort_run(rel: str) -> bool:
    """Whether ``rel`` (relative to the output folder, with ``/``) is a file of
    ``SORT_RUNS`` as the finish names them."""
    return SORT_RUN_FILE.fullmatch(rel) is not None


#: The files of a build besides its chunks', relative to the output folder.
BUILD_FILES = (
    "parts/build.json",
    CLEARING,
    KEY_INDEX,
    "manifest.parquet",
    "failures.parquet",
    "dataset.json",
    SUMS,  # dataset.json's SHA-256 (``store.seal``)
    WIDS_INDEX,
    "README.md",
    "croissant.json",
    "pairs.parquet",  # output.pairs
    # an append's snapshot of the dataset it appends to (``pipeline.builder.append``)
    "parts/base-manifest.parquet",
    "parts/base-failures.parquet",
    "parts/base-dataset.json",
)


#: A chunk's shard or part. A shard without a split in its name is one of an earlier version's
#: builds (one shard a chunk): still a chunk file, so a rebuild clears it.
CHUNK_FILE = re.compile(
    rf"(shards/shard-([0-9]{{6,}})(?:-{SPLIT_NAME.pattern})?\.tar"
    r"|parts/(?:manifest|failures)-([0-9]{6,})\.parquet)"
)

#: The per-split files of a finished build: shard lists and wids indexes.
SPLIT_FILE = re.compile(rf"shards-{SPLIT_NAME.pattern}\.txt|shardindex-{SPLIT_NAME.pattern}\.json")


def part_paths(out: fs.Location, k: int) -> tuple[str, Any, Any]:
    """Chunk k's shard name stem (relative to ``out``: ``shard_name`` adds the split),
    manifest part and failure part (in ``out``: a Path for a local folder, a URL for object
    storage)."""
    return (
        f"shards/shard-{k:06d}",
        fs.join(out, f"parts/manifest-{k:06d}.parquet"),
        fs.join(out, f"parts/failures-{k:06d}.parquet"),
    )


def shard_name(k: int, split: str) -> str:
    """The shard of chunk ``k``'s samples of ``split``, relative to the output folder."""
    if not SPLIT_NAME.fullmatch(split):
        raise ValueError(f"split name {split!r}: expected {SPLIT_NAME.pattern}")
    return f"shards/shard-{k:06d}-{split}.tar"


def stamp_path(out: fs.Location) -> Any:
    """The build stamp: the fingerprint of the build that wrote the parts."""
    return fs.join(out, "parts/build.json")


def dropped_count(out: fs.Location, n_chunks: int) -> int:
    """Samples dropped in the split buffer, summed over the chunk parts."""
    total = 0
    for k in range(n_chunks):
        meta = fs.parquet_schema(part_paths(out, k)[1]).metadata or {}
        total += int(meta.get(DROPPED_KEY, b"0"))
    return total


def written_by(chunks: int | None, rel: str) -> bool:
    """Whether a build of ``chunks`` chunks (None: no build) writes the file ``rel`` (a path
    relative to the output folder, with ``/``); the folder's lock is every build's."""
    if rel == LOCK_FILE:
        return True
    if chunks is None:
        return False
    if rel in BUILD_FILES or SPLIT_FILE.fullmatch(rel):
        return True
    k = chunk_of(rel)
    return k is not None and k < chunks


def chunk_of(rel: str) -> int | None:
    """The chunk whose file ``rel`` is (a shard or a part, its number written as a build
    writes it: six digits or more, no extra leading zero), else None."""
    m = CHUNK_FILE.fullmatch(rel)
    if m is None:
        return None
    digits = m[2] or m[3]
    return int(digits) if f"{int(digits):06d}" == digits else None


def is_temporary(rel: str) -> bool:
    """Whether ``rel`` is the temporary name (``store.atomic``: ``.NAME.tmp-PID`` beside NAME,
    left by a killed build) of a file some build writes, whatever its chunk count."""
    folder, _, name = rel.rpartition("/")
    target = temporary_target(name)
    if target is None:
        return False
    rel = f"{folder}/{target}" if folder else target
    return rel in BUILD_FILES or SPLIT_FILE.fullmatch(rel) is not None or chunk_of(rel) is not None
