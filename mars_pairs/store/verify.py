"""``mars-pairs verify DIR``: check a built dataset against its manifest.

The folder's integrity chain is checked first (:func:`~mars_pairs.store.seal.chain_damage`:
``SHA256SUMS`` against dataset.json, then the size and SHA-256 dataset.json records of the
manifest, the failures, the card, croissant.json and the shard index), each damaged file
named; a dataset built before the chain is reported as having "no integrity record" (once).
The dataset must have its ``dataset.json`` (:func:`~mars_pairs.store.dataset_info.
read_dataset_info`: the ray stride, CRS and chip size every reader needs) and no key on two
manifest rows. Each member is checked by :func:`~mars_pairs.store.integrity.check_member`,
the code ``MarsPairsDataset(verify=True)`` runs on every sample it reads: its shard path
confined to the dataset folder, its bytes inside the shard, the tar header just before them
(name ``<key>.<field>...``, size equal to the manifest's), its bytes read in full and their
CRC-32C against the manifest's ``<member>_crc32c``. Damage is reported per member, naming the
shard and the member (per key for the manifest, per field for dataset.json); shards are
read in file order, one open each. ``DIR`` may be an fsspec URL (``s3://bucket/prefix``:
``store.fs``): a shard is then read in order through one file object (range requests).
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs
from mars_pairs.store.dataset_info import DATASET_JSON, read_dataset_info
from mars_pairs.store.integrity import MemberSpec, check_member, repeated_keys, shard_location
from mars_pairs.store.members import MEMBERS, OPTIONAL_FIELDS
from mars_pairs.store.query import Manifest
from mars_pairs.store.seal import NO_RECORD, chain_damage


@dataclass(frozen=True)
class Damage:
    """One damaged file or member: ``path`` the file (a shard, the manifest, dataset.json;
    relative to the dataset), ``member`` what in it (a shard's member name, the manifest's
    key, dataset.json's key at fault; None: the whole file) and what is wrong."""

    path: str
    member: str | None
    reason: str

    def __str__(self) -> str:
        where = f"{self.path}: {self.member}" if self.member else self.path
        return f"{where}: {self.reason}"


@dataclass
class VerifyReport:
    """What ``verify_dataset`` checked and found."""

    root: Path | str
    members: int = 0
    shards: int = 0
    unchecked: int = 0  # members without a checksum (a dataset built before checksums)
    damage: list[Damage] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # warnings (no integrity record)

    def format(self) -> str:
        """One line per note and per damaged file or member, then a summary line."""
        lines = [f"warning: {n}" for n in self.notes] + [str(d) for d in self.damage]
        state = f"{len(self.damage)} damaged" if self.damage else "all intact"
        extra = f", {self.unchecked} without a checksum" if self.unchecked else ""
        lines.append(
            f"{self.root}: {self.members} members in {self.shards} shards checked: {state}{extra}"
        )
        return "\n".join(lines)


def verify_dataset(root: str | Path) -> VerifyReport:
    """Check the dataset at ``root`` (see the module docstring). A manifest that cannot be
    read or lacks a location column raises DatasetError naming it and the column (with what
    the chain found)."""
    root = fs.dataset_root(root)
    chain = chain_damage(root)
    notes = [NO_RECORD] if chain is None else []
    damage = [Damage(d.path, None, d.reason) for d in chain or []]
    try:
        report = _verify_members(root)
    except DatasetError as exc:
        if not damage:
            raise
        # the manifest (or dataset.json) unreadable: one error, with what the chain found
        found = "; ".join(str(d) for d in damage)
        reason = " ".join(str(exc.reason).split())
        raise DatasetError(exc.path, exc.member, f"{reason} ({found})") from None
    report.damage[:0] = damage
    report.notes = notes
    return report


def _verify_members(root: fs.Location) -> VerifyReport:
    """verify_dataset's checks after the chain: dataset.json's fields, repeated keys, every
    member."""
    manifest = Manifest.open(root)
    names = set(manifest.schema.names)
    # the optional dense members (output.members) that this manifest locates
    members = (*MEMBERS, *(m for m in OPTIONAL_FIELDS if f"{m}_offset" in names))
    location = [f"{m}_{s}" for m in members for s in ("shard", "offset", "size")]
    manifest.require(["key", "ground_member", *location])
    checksums = [f"{m}_crc32c" for m in members if f"{m}_crc32c" in names]
    table = manifest.to_table(columns=["key", "ground_member", *location, *checksums])
    rows = table.to_pylist()
    damage = _dataset_json_damage(root)
    damage += [
        Damage("manifest.parquet", key, f"{n} rows hold this key")
        for key, n in repeated_keys(table["key"])
    ]
    by_shard: dict[str, list[MemberSpec]] = defaultdict(list)
    for row in rows:
        for m in members:
            shard = row.get(f"{m}_shard")
            if shard is None:
                continue
            by_shard[shard].append(
                MemberSpec(
                    row["key"],
                    m,
                    row[f"{m}_offset"],
                    row[f"{m}_size"],
                    row.get(f"{m}_crc32c"),
                    row.get("ground_member"),
                )
            )
    report = VerifyReport(root, shards=len(by_shard), damage=damage)
    for shard, specs in sorted(by_shard.items()):
        _verify_shard(root, shard, sorted(specs, key=lambda e: e.offset or 0), report)
    return report


def _dataset_json_damage(root: fs.Location) -> list[Damage]:
    try:
        read_dataset_info(root)
    except DatasetError as exc:
        return [Damage(DATASET_JSON, exc.member, exc.reason)]
    return []


def _verify_shard(
    root: fs.Location, shard: str, specs: list[MemberSpec], report: VerifyReport
) -> None:
    report.members += len(specs)
    report.unchecked += sum(s.crc32c is None for s in specs)
    try:
        fh = fs.open_input(shard_location(root, shard))
    except DatasetError as exc:  # a shard path outside the dataset folder
        report.damage += [Damage(shard, s.name, exc.reason) for s in specs]
        return
    except OSError as exc:
        report.damage += [Damage(shard, s.name, f"cannot open: {exc}") for s in specs]
        return
    with fh:
        size = os.fstat(fh.fileno()).st_size if isinstance(root, Path) else fh.size
        for spec in specs:
            try:
                _, problem = check_member(spec, lambda o, n: _read(fh, o, n), size)
            except OSError as exc:
                problem = f"cannot read: {exc}"
            if problem is not None:
                report.damage.append(Damage(shard, spec.name, problem))


def _read(fh: BinaryIO, offset: int, size: int) -> bytes:
    fh.seek(offset)
    return fh.read(size)
