"""The integrity chain of a dataset folder: every byte a reader trusts is bound to one digest.

- the shards' members are bound to the manifest by its per-member size and CRC-32C
  (:mod:`mars_pairs.store.integrity`);
- dataset.json's ``files`` record (:data:`FILES_KEY`) holds the SHA-256 and size of every
  other file that describes the folder (:data:`SEALED`: the manifest, the failures, the card
  ``README.md``, ``croissant.json``, the shard index ``shardindex.json`` and, with
  ``output.pairs``, ``pairs.parquet``);
- the sidecar ``SHA256SUMS`` (:data:`SUMS`, the coreutils format: ``sha256sum -c SHA256SUMS``
  in the folder checks it) holds the SHA-256 of dataset.json, closing the chain.

A build writes them last, in that order (:func:`seal`): the sealed files, then dataset.json
with their record, then ``SHA256SUMS``. ``mars-pairs verify`` checks the chain first
(:func:`chain_damage`, every file named), ``MarsPairsDataset(verify=True)`` checks dataset.json
and the manifest at open. The chain guards against damage (a flipped bit, a truncated copy, a
hand-edited file), not against someone who rewrites a file and its digests on purpose.

A dataset built before the chain has neither record nor sidecar: :func:`chain_damage` returns
None for it (the caller warns "no integrity record" once). A root may be a local folder or an
fsspec URL (``store.fs``).
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from mars_pairs.store import fs
from mars_pairs.store.wids_index import WIDS_INDEX

#: dataset.json's key holding the record of the sealed files
FILES_KEY = "files"
#: the sidecar holding dataset.json's SHA-256
SUMS = "SHA256SUMS"
#: the files dataset.json's record covers, relative to the dataset folder
SEALED = ("manifest.parquet", "failures.parquet", "README.md", "croissant.json", WIDS_INDEX)
#: the files the record covers when the build wrote them (``output.pairs``)
OPTIONAL_SEALED = ("pairs.parquet",)
#: what a reader says of a dataset without the chain (built before it)
NO_RECORD = (
    "no integrity record (dataset.json has no 'files' and there is no SHA256SUMS: built "
    "before the folder's integrity chain; rebuild to have manifest and dataset.json checked)"
)

_SUMS_LINE = re.compile(r"([0-9a-f]{64}) [ *]dataset\.json")


@dataclass(frozen=True)
class FileDamage:
    """One file of the chain that is not as recorded: ``path`` relative to the dataset
    folder, and what is wrong."""

    path: str
    reason: str


def file_digest(path: fs.Location) -> tuple[str, int]:
    """(hex SHA-256, size in bytes) of a file, read in 1 MiB blocks."""
    h = hashlib.sha256()
    size = 0
    with fs.open_input(path) as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    return h.hexdigest(), size


#: the per-split shard lists and indexes, sealed too (``shards-<split>.txt``,
#: ``shardindex-<split>.json``)
SPLIT_LISTS = re.compile(r"shards-[a-z][a-z0-9_]*\.txt|shardindex-[a-z][a-z0-9_]*\.json")


def sealed_names(root: fs.Location) -> list[str]:
    """The files of ``root`` the record covers: ``SEALED``, those of ``OPTIONAL_SEALED``
    present and the per-split shard lists."""
    names = fs.list_names(root)  # the folder's own files: not its shards' or parts' listing
    lists = sorted(n for n in names if SPLIT_LISTS.fullmatch(n))
    return [*SEALED, *(n for n in OPTIONAL_SEALED if n in names), *lists]


def files_record(
    root: fs.Location, names: Sequence[str] | None = None
) -> dict[str, dict[str, Any]]:
    """The ``files`` record of the sealed files (``names``, default ``sealed_names(root)``)
    present in ``root``: name -> {sha256, size}."""
    record: dict[str, dict[str, Any]] = {}
    for name in sealed_names(root) if names is None else names:
        path = fs.join(root, name)
        if fs.exists(path):
            sha, size = file_digest(path)
            record[name] = {"sha256": sha, "size": size}
    return record


def seal(root: fs.Location, doc: dict[str, Any]) -> bytes:
    """Write dataset.json (``doc`` with the ``files`` record of the sealed files now in
    ``root``), then ``SHA256SUMS`` over it; each atomically. Returns dataset.json's bytes."""
    doc[FILES_KEY] = files_record(root)
    data = json.dumps(doc, indent=2).encode()
    fs.put_bytes(fs.join(root, "dataset.json"), data)
    fs.put_bytes(
        fs.join(root, SUMS), f"{hashlib.sha256(data).hexdigest()}  dataset.json\n".encode()
    )
    return data


def chain_damage(root: fs.Location, only: tuple[str, ...] | None = None) -> list[FileDamage] | None:
    """What is wrong with the chain of the dataset at ``root`` ([] when whole), checked in
    order: ``SHA256SUMS`` against dataset.json, then each file of the record (``only``: just
    these of them) by size and SHA-256. None when the dataset has no chain at all (neither
    record nor sidecar: built before it). A file recorded but missing is damage."""
    sums_path, json_path = fs.join(root, SUMS), fs.join(root, "dataset.json")
    has_sums = fs.exists(sums_path)
    try:
        data = fs.read_bytes(json_path)
    except FileNotFoundError:
        return [FileDamage("dataset.json", "missing")] if has_sums else None
    try:
        doc = json.loads(data)
    except ValueError:
        doc = None
    record = doc.get(FILES_KEY) if isinstance(doc, dict) else None
    if not has_sums and record is None:
        return None
    damage: list[FileDamage] = []
    if not has_sums:
        damage.append(FileDamage(SUMS, "missing (dataset.json records the folder's files)"))
    else:
        problem = _sums_problem(fs.read_bytes(sums_path), data)
        if problem is not None:
            damage.append(FileDamage("dataset.json", problem))
    if not isinstance(record, dict):
        damage.append(FileDamage("dataset.json", f"'{FILES_KEY}': no record of the files"))
        return damage
    recorded = [n for n in record if n not in SEALED and SPLIT_LISTS.fullmatch(str(n))]
    names = [n for n in (*SEALED, *recorded) if only is None or n in only]
    for name in names:
        problem = _file_problem(root, name, record.get(name))
        if problem is not None:
            damage.append(FileDamage(name, problem))
    return damage


def _sums_problem(sums: bytes, data: bytes) -> str | None:
    """What is wrong with dataset.json's bytes ``data`` against the sidecar ``sums``."""
    m = _SUMS_LINE.fullmatch(sums.decode("utf-8", "replace").strip())
    if m is None:
        return f"{SUMS} is not one 'SHA256  dataset.json' line"
    got = hashlib.sha256(data).hexdigest()
    if got != m[1]:
        return f"SHA-256 {got[:16]}... does not match {SUMS} ({m[1][:16]}...): changed"
    return None


def _file_problem(root: fs.Location, name: str, entry: object) -> str | None:
    """What is wrong with the sealed file ``name`` against its record ``entry``."""
    path = fs.join(root, name)
    if entry is None:
        return "not in dataset.json's record" if fs.exists(path) else None
    if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
        return f"dataset.json's record of it is damaged ({entry!r:.80})"
    try:
        sha, size = file_digest(path)
    except FileNotFoundError:
        return "missing (dataset.json records it)"
    except OSError as exc:
        return f"unreadable: {exc}"
    if size != entry.get("size"):
        return f"{size} bytes, dataset.json records {entry.get('size')}: truncated or changed"
    if sha != entry["sha256"]:
        return f"SHA-256 {sha[:16]}... does not match dataset.json's ({entry['sha256'][:16]}...)"
    return None


def require_sealed(root: fs.Location, only: tuple[str, ...] = ("manifest.parquet",)) -> None:
    """Refuse a dataset whose chain is damaged for dataset.json or the files ``only``: a
    DatasetError naming the first damaged file (``MarsPairsDataset(verify=True)`` at open).
    A dataset without the chain warns :data:`NO_RECORD` (one warning per call)."""
    import warnings

    from mars_pairs.errors import DatasetError

    damage = chain_damage(root, only=only)
    if damage is None:
        warnings.warn(f"{root}: {NO_RECORD}", stacklevel=3)
        return
    if damage:
        first = damage[0]
        raise DatasetError(fs.join(root, first.path), None, first.reason)
