"""Folder hygiene: what a build may clear or resume in its output folder.

A build clears only the files the stamped build writes (``layout.written_by``) and its own
temporary files, and a resumed build keeps only those: a folder holding anything else is
refused, untouched (``foreign_file``). A shard or failure part of an unfinished chunk must read
as one a build writes (a tar of ``<key>.<field>`` members, a parquet file of the failure
columns). Clearing is ordered so that a kill at any point resumes. A finished build removes
``parts/`` (``remove_parts``, unless ``output.keep_parts``), after its stamp is written into
dataset.json. On object storage a rename is a server-side copy and a delete (``fs.replace``),
and there are no folders (nor links) to find.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import tarfile
from pathlib import Path

from mars_pairs.pipeline.builder.layout import (
    CHUNK_FILE,
    CLEARING,
    KEY_INDEX,
    SORT_RUNS,
    is_sort_run,
    is_temporary,
    part_paths,
    stamp_path,
    written_by,
)
from mars_pairs.pipeline.builder.stamp import (
    appended_to,
    finished_stamp,
    read_stamp,
    stamped_chunks,
)
from mars_pairs.store import fs
from mars_pairs.store.manifest import FAILURE_SCHEMA
from mars_pairs.store.seal import SUMS
from mars_pairs.store.wids_index import WIDS_INDEX


def foreign_file(out: fs.Location) -> str | None:
    """The first entry of ``out`` (sorted, relative, with ``/``) that the build that stamped
    it did not write: a file it does not list, a shard or failure part of an unfinished
    chunk that does not read as one (``_as_built``; a finished build's chunks are all
    finished, vouched for by its dataset.json, and so are those of the dataset an
    interrupted append appends to: ``appended_to``), a symbolic link, a folder other than
    ``shards`` and ``parts``; None when a build may clear or resume the folder. On object
    storage, every object under the prefix (one listing)."""
    if not isinstance(out, Path):
        return _foreign_object(out)
    if not out.is_dir():
        return None
    chunks = stamped_chunks(out)
    finished = finished_stamp(out) is not None and not stamp_path(out).exists()
    vouched = 2**62 if finished else appended_to(read_stamp(stamp_path(out)))
    for folder, dirs, files in os.walk(out):
        dirs.sort()
        rel_dir = os.path.relpath(folder, out).replace(os.sep, "/")
        prefix = "" if rel_dir == "." else rel_dir + "/"
        for name in sorted(files):
            rel = prefix + name
            path = os.path.join(folder, name)
            if os.path.islink(path) or not os.path.isfile(path):
                return rel
            if is_sort_run(rel):  # a killed finish's scratch: cleared by the next build
                continue
            if not (written_by(chunks, rel) or is_temporary(rel)):
                return rel
            if not _as_built(out, rel, vouched):
                return rel
        for name in dirs:
            allowed = name in ("shards", "parts") if not prefix else prefix + name == SORT_RUNS
            if not allowed or os.path.islink(os.path.join(folder, name)):
                return prefix + name + "/"
    return None


def _foreign_object(out: str) -> str | None:
    """``foreign_file`` of the object storage prefix ``out``."""
    files = fs.list_files(out)
    if not files:
        return None
    chunks = stamped_chunks(out)
    finished = finished_stamp(out) is not None and "parts/build.json" not in files
    vouched = 2**62 if finished else appended_to(read_stamp(stamp_path(out)))
    for rel in files:
        if not (written_by(chunks, rel) or is_temporary(rel)):
            return rel
        if not _as_built(out, rel, vouched):
            return rel
    return None


_MEMBER = re.compile(r"[^./]+\.[^/]+")  # <key>.<field> (``ShardWriter``)


def _as_built(out: fs.Location, rel: str, vouched: int = 0) -> bool:
    """Whether the chunk file ``rel`` reads as one a build writes, when its chunk is not
    finished (no manifest part, and not one of the first ``vouched`` chunks, which a finished
    build vouches for: the dataset an append appends to): a shard is a tar of regular
    ``<key>.<field>`` members, a failure part a parquet file of the failure columns. Other
    files: True. Reads tar headers and the parquet footer only."""
    m = CHUNK_FILE.fullmatch(rel)
    if m is None or rel.startswith("parts/manifest-"):
        return True
    k = int(m[2] or m[3])
    if k < vouched or fs.exists(part_paths(out, k)[1]):
        return True
    path = fs.join(out, rel)
    if m[2] is not None:
        try:
            with fs.open_input(path) as fh, tarfile.open(fileobj=fh, mode="r:") as tar:
                return all(t.isreg() and _MEMBER.fullmatch(t.name) for t in tar)
        except (OSError, tarfile.TarError):
            return False
    try:
        return bool(fs.parquet_schema(path).names == FAILURE_SCHEMA.names)
    except (OSError, ValueError):
        return False


def remove_temporaries(out: fs.Location) -> None:
    """Remove the temporary files a killed build left (``is_temporary`` names only, in the
    output folder, ``shards/`` and ``parts/``)."""
    if not isinstance(out, Path):
        for rel in fs.list_files(out):
            if is_temporary(rel):
                fs.remove(fs.join(out, rel))
        return
    for sub in ("", "shards/", "parts/"):
        folder = out / sub
        if not folder.is_dir():
            continue
        with os.scandir(folder) as entries:  # streamed: not a list of every shard and part
            stale = [e.name for e in entries if is_temporary(sub + e.name)]
        for name in sorted(stale):
            path = folder / name
            if path.is_file() and not path.is_symlink():
                path.unlink()


def remove_parts(out: fs.Location, chunks: int) -> None:
    """Remove ``parts/`` of a finished build (its dataset.json holds the stamp): the chunk
    commit markers first, then the failure parts, the stamp, the folder. A kill at any point
    resumes: a chunk without its manifest part is rebuilt, byte for byte."""
    for k in range(chunks):
        fs.remove(part_paths(out, k)[1])
    for k in range(chunks):
        fs.remove(part_paths(out, k)[2])
    fs.remove(stamp_path(out))
    remove_empty_parts(out)


def remove_sort_runs(out: Path) -> None:
    """Remove the finish's sorted runs (``SORT_RUNS``: its run files, then the folder) from
    the local output folder ``out``, if there."""
    folder = out / SORT_RUNS
    if folder.is_symlink() or not folder.is_dir():
        return
    for name in sorted(os.listdir(folder)):
        if is_sort_run(f"{SORT_RUNS}/{name}") and not (folder / name).is_symlink():
            (folder / name).unlink()
    with contextlib.suppress(OSError):  # not empty: a file no build writes, left for the user
        folder.rmdir()


def remove_empty_parts(out: fs.Location) -> None:
    """Remove ``parts/`` when it is an empty folder (object storage has no folders)."""
    if not isinstance(out, Path):
        return
    parts = out / "parts"
    if parts.is_dir() and not parts.is_symlink() and not any(parts.iterdir()):
        parts.rmdir()


#: What ``clear_outputs`` removes, in order (patterns relative to the output folder).
_CLEARED = (
    SUMS,  # the chain's sidecar first: no reader checks a half-cleared folder against it
    "manifest.parquet",
    "dataset.json",
    "README.md",
    "croissant.json",
    "pairs.parquet",
    WIDS_INDEX,
    "shardindex-*.json",
    "shards-*.txt",
    "failures.parquet",
    "parts/manifest-*.parquet",
    "parts/*.parquet",
    "parts/base-dataset.json",
    KEY_INDEX,
    "shards/*.tar",
)


def clear_outputs(out: fs.Location) -> None:
    """Remove what the earlier build(s) stamped in ``out`` wrote (``written_by``; the caller
    has checked that the folder holds nothing else: ``foreign_file``), crash-safely. The
    stamp is renamed first (``parts/clearing.json``): a build killed at any point of the
    clearing leaves no build stamp, so its rerun (resumed or not) clears again, and the
    renamed stamp still lists what is left (a finished build's stamp is its dataset.json,
    renamed the same way). Then the dataset's own commit marker (manifest.parquet) goes, so
    no reader sees a manifest whose shards are going; then the chunk commit markers (manifest
    parts) before the failure parts and shards they vouch for; the renamed stamp goes last.
    On object storage the same, in the same order (a rename is a copy and a delete)."""
    if not isinstance(out, Path):
        _clear_objects(out)
        return
    chunks = stamped_chunks(out)
    stamp = stamp_path(out)
    finished = out / "dataset.json"
    if stamp.is_file():
        os.replace(stamp, out / CLEARING)
    elif finished_stamp(out) is not None and not (out / CLEARING).is_file():
        (out / "parts").mkdir(exist_ok=True)
        os.replace(finished, out / CLEARING)
    remove_sort_runs(out)
    for pattern in _CLEARED:
        for stale in sorted(out.glob(pattern)):
            rel = stale.relative_to(out).as_posix()
            if written_by(chunks, rel) and stale.is_file() and not stale.is_symlink():
                stale.unlink()
    clearing = out / CLEARING
    if clearing.is_file():
        clearing.unlink()


def _clear_objects(out: str) -> None:
    """``clear_outputs`` of the object storage prefix ``out``."""
    chunks = stamped_chunks(out)
    stamp, clearing = stamp_path(out), fs.join(out, CLEARING)
    if fs.is_file(stamp):
        fs.replace(stamp, clearing)
    elif finished_stamp(out) is not None and not fs.is_file(clearing):
        fs.replace(fs.join(out, "dataset.json"), clearing)
    files = fs.list_files(out)
    done: set[str] = set()
    for pattern in _CLEARED:
        for rel in files:
            if rel not in done and fnmatch.fnmatchcase(rel, pattern) and written_by(chunks, rel):
                if "/" in pattern and rel.count("/") != pattern.count("/"):
                    continue
                fs.remove(fs.join(out, rel))
                done.add(rel)
    fs.remove(clearing)
