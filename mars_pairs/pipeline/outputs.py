"""What a build keeps in its output folder: chunk part paths, the build stamp, clearing.

The stamp (``parts/build.json``) holds the fingerprint of the build that wrote the parts; a
resumed build must match it. It also lists what that build writes: its label count and
``output.shard_size`` give its chunks, and ``written_by`` names their files. A build clears
only those (and its own temporary files): a folder holding anything else is refused, untouched
(``foreign_file``). Clearing is ordered so that a kill at any point resumes.

A finished build removes ``parts/`` (``remove_parts``, unless ``output.keep_parts``): its stamp
lives on as ``build_stamp`` in dataset.json (``finished_stamp``: the label count, shard size and
the SHA-256 of the fingerprint, no paths), written before the parts go.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store.wids_index import WIDS_INDEX

DROPPED_KEY = b"mars_pairs:dropped_in_buffer"
#: The stamp of a build whose files are being cleared (the old stamp, renamed).
CLEARING = "parts/clearing.json"
#: The files of a build besides its chunks', relative to the output folder.
BUILD_FILES = (
    "parts/build.json",
    CLEARING,
    "manifest.parquet",
    "failures.parquet",
    "dataset.json",
    WIDS_INDEX,
    "README.md",
    "croissant.json",
)
#: dataset.json's key holding the stamp of the finished build (``stamp_digest``).
FINISHED_KEY = "build_stamp"
_CHUNK_FILE = re.compile(
    r"(shards/shard-([0-9]{6,})\.tar|parts/(?:manifest|failures)-([0-9]{6,})\.parquet)"
)
_TEMPORARY = re.compile(r"((?:shards/|parts/)?)\.([^/]+)\.tmp-[0-9]+")  # store's atomic writes


def part_paths(out: Path, k: int) -> tuple[str, Path, Path]:
    return (
        f"shards/shard-{k:06d}.tar",
        out / "parts" / f"manifest-{k:06d}.parquet",
        out / "parts" / f"failures-{k:06d}.parquet",
    )


def stamp_path(out: Path) -> Path:
    """The build stamp: the fingerprint of the build that wrote the parts."""
    return out / "parts" / "build.json"


def dropped_count(out: Path, n_chunks: int) -> int:
    """Samples dropped in the split buffer, summed over the chunk parts."""
    total = 0
    for k in range(n_chunks):
        meta = pq.read_schema(part_paths(out, k)[1]).metadata or {}
        total += int(meta.get(DROPPED_KEY, b"0"))
    return total


class LabelDigest:
    """The sha256 of the label names joined by newlines, and their count, fed one name at a
    time: the digest of ``"\n".join(names).encode()`` without holding the names."""

    def __init__(self) -> None:
        self._sha = hashlib.sha256()
        self.count = 0

    def add(self, name: str) -> None:
        if self.count:
            self._sha.update(b"\n")
        self._sha.update(name.encode())
        self.count += 1

    def tally(self, names: Iterable[str]) -> Iterator[str]:
        """``names`` unchanged, each added to the digest as it passes."""
        for name in names:
            self.add(name)
            yield name

    def hexdigest(self) -> str:
        return self._sha.hexdigest()


def fingerprint(config: BuildConfig, labels: Iterable[str | Path]) -> dict[str, Any]:
    """What a resumed build must share with the interrupted one: the config (without its
    source and output folder) and the label list's digest and count, in one streaming pass."""
    digest = LabelDigest()
    for label in labels:
        digest.add(str(label))
    return stamp_of(config, digest)


def stamp_of(config: BuildConfig, digest: LabelDigest) -> dict[str, Any]:
    """The fingerprint of ``config`` with the label list that ``digest`` summed."""
    doc = config.to_dict()
    doc.pop("source", None)
    doc["output"].pop("dir", None)
    return {"config": doc, "labels": digest.hexdigest(), "count": digest.count}


def read_stamp(stamp: Path) -> dict[str, Any] | None:
    """The fingerprint of the build that wrote the parts; None when absent or damaged."""
    try:
        doc = json.loads(stamp.read_bytes())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def stamp_digest(stamp: dict[str, Any]) -> dict[str, Any]:
    """What dataset.json keeps of a build's fingerprint: its label count, shard size and the
    SHA-256 of the fingerprint (canonical JSON), so that no input path is written there."""
    text = json.dumps(stamp, sort_keys=True, separators=(",", ":")).encode()
    return {
        "count": stamp["count"],
        "shard_size": stamp["config"]["output"]["shard_size"],
        "sha256": hashlib.sha256(text).hexdigest(),
    }


def finished_stamp(out: Path) -> dict[str, Any] | None:
    """The ``stamp_digest`` of the finished build in ``out`` (dataset.json's ``build_stamp``);
    None when there is none."""
    doc = read_stamp(out / "dataset.json")
    digest = doc.get(FINISHED_KEY) if doc is not None else None
    return digest if isinstance(digest, dict) else None


def stamp_chunks(stamp: Any) -> int | None:
    """The chunk count of the build a stamp describes (its label count over its
    ``output.shard_size``); None when ``stamp`` is not a build's fingerprint. A finished
    build's dataset.json (its ``build_stamp``) describes that build."""
    try:
        if isinstance(stamp, dict) and isinstance(stamp.get(FINISHED_KEY), dict):
            count, size = stamp[FINISHED_KEY]["count"], stamp[FINISHED_KEY]["shard_size"]
        else:
            count, size = stamp["count"], stamp["config"]["output"]["shard_size"]
    except (KeyError, TypeError):
        return None
    ints = all(isinstance(v, int) and not isinstance(v, bool) for v in (count, size))
    if not ints or count < 0 or size < 1:
        return None
    return -(-count // size)


def written_by(chunks: int | None, rel: str) -> bool:
    """Whether a build of ``chunks`` chunks (None: no build) writes the file ``rel`` (a path
    relative to the output folder, with ``/``)."""
    if chunks is None:
        return False
    if rel in BUILD_FILES:
        return True
    m = _CHUNK_FILE.fullmatch(rel)
    if m is None:
        return False
    digits = m[2] or m[3]
    return int(digits) < chunks and f"{int(digits):06d}" == digits


def is_temporary(rel: str) -> bool:
    """Whether ``rel`` is the temporary name of a file a build writes (``.NAME.tmp-PID``
    beside NAME, left by a killed build), whatever the build."""
    m = _TEMPORARY.fullmatch(rel)
    return m is not None and written_by(2**62, m[1] + m[2])


def stamped_chunks(out: Path) -> int | None:
    """The chunks of the build(s) whose stamp the folder holds (the build's, and a clearing's
    left by a killed clearing); None when it holds no valid stamp."""
    stamps = ("parts/build.json", CLEARING, "dataset.json")
    counts = [stamp_chunks(read_stamp(out / rel)) for rel in stamps]
    valid = [n for n in counts if n is not None]
    return max(valid) if valid else None


def foreign_file(out: Path) -> str | None:
    """The first entry of ``out`` (sorted, relative, with ``/``) that the build that stamped
    it did not write: a file it does not list, a symbolic link, a folder other than
    ``shards`` and ``parts``; None when a build may clear the folder."""
    if not out.is_dir():
        return None
    chunks = stamped_chunks(out)
    for folder, dirs, files in os.walk(out):
        dirs.sort()
        rel_dir = os.path.relpath(folder, out).replace(os.sep, "/")
        prefix = "" if rel_dir == "." else rel_dir + "/"
        for name in sorted(files):
            rel = prefix + name
            path = os.path.join(folder, name)
            if os.path.islink(path) or not os.path.isfile(path):
                return rel
            if not (written_by(chunks, rel) or is_temporary(rel)):
                return rel
        for name in dirs:
            if (
                prefix
                or name not in ("shards", "parts")
                or os.path.islink(os.path.join(folder, name))
            ):
                return prefix + name + "/"
    return None


def remove_temporaries(out: Path) -> None:
    """Remove the temporary files a killed build left (``is_temporary`` names only, in the
    output folder, ``shards/`` and ``parts/``)."""
    for sub in ("", "shards/", "parts/"):
        folder = out / sub
        if not folder.is_dir():
            continue
        for name in sorted(os.listdir(folder)):
            path = folder / name
            if is_temporary(sub + name) and path.is_file() and not path.is_symlink():
                path.unlink()


def remove_parts(out: Path, chunks: int) -> None:
    """Remove ``parts/`` of a finished build (its dataset.json holds the stamp): the chunk
    commit markers first, then the failure parts, the stamp, the folder. A kill at any point
    resumes: a chunk without its manifest part is rebuilt, byte for byte."""
    for k in range(chunks):
        part_paths(out, k)[1].unlink(missing_ok=True)
    for k in range(chunks):
        part_paths(out, k)[2].unlink(missing_ok=True)
    stamp_path(out).unlink(missing_ok=True)
    remove_empty_parts(out)


def remove_empty_parts(out: Path) -> None:
    """Remove ``parts/`` when it is an empty folder."""
    parts = out / "parts"
    if parts.is_dir() and not parts.is_symlink() and not any(parts.iterdir()):
        parts.rmdir()


def built_keys(out: Path, done: Iterable[int]) -> dict[str, str]:
    """Sample key -> label path of the chunks a resumed build keeps (for duplicate ids)."""
    seen: dict[str, str] = {}
    for k in done:
        part = pq.read_table(part_paths(out, k)[1], columns=["key", "label_path"])
        seen.update(zip(part["key"].to_pylist(), part["label_path"].to_pylist(), strict=True))
    return seen


def clear_outputs(out: Path) -> None:
    """Remove what the earlier build(s) stamped in ``out`` wrote (``written_by``; the caller
    has checked that the folder holds nothing else: ``foreign_file``), crash-safely. The
    stamp is renamed first (``parts/clearing.json``): a build killed at any point of the
    clearing leaves no build stamp, so its rerun (resumed or not) clears again, and the
    renamed stamp still lists what is left (a finished build's stamp is its dataset.json,
    renamed the same way). Then the dataset's own commit marker (manifest.parquet) goes, so
    no reader sees a manifest whose shards are going; then the chunk commit markers (manifest
    parts) before the failure parts and shards they vouch for; the renamed stamp goes last."""
    chunks = stamped_chunks(out)
    stamp = stamp_path(out)
    finished = out / "dataset.json"
    if stamp.is_file():
        os.replace(stamp, out / CLEARING)
    elif finished_stamp(out) is not None and not (out / CLEARING).is_file():
        (out / "parts").mkdir(exist_ok=True)
        os.replace(finished, out / CLEARING)
    for pattern in (
        "manifest.parquet",
        "dataset.json",
        "README.md",
        "croissant.json",
        WIDS_INDEX,
        "failures.parquet",
        "parts/manifest-*.parquet",
        "parts/*.parquet",
        "shards/*.tar",
    ):
        for stale in sorted(out.glob(pattern)):
            rel = stale.relative_to(out).as_posix()
            if written_by(chunks, rel) and stale.is_file() and not stale.is_symlink():
                stale.unlink()
    clearing = out / CLEARING
    if clearing.is_file():
        clearing.unlink()
