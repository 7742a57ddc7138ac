"""``mars-pairs verify DIR``: check every member of a built dataset against its manifest row.

Each member is checked three ways: the tar header just before its data (name
``<key>.<field>...``, size equal to the manifest's), its bytes read in full, and their CRC-32C
against the manifest's ``<member>_crc32c``. Damage is reported per member, naming the shard and
the member; shards are read in file order, one open each.
"""

from __future__ import annotations

import tarfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mars_pairs.store.manifest import MEMBERS, Manifest
from mars_pairs.store.shards import checksum


@dataclass(frozen=True)
class Damage:
    """One damaged member: its shard (relative to the dataset), member name and what is wrong."""

    shard: str
    member: str
    reason: str

    def __str__(self) -> str:
        return f"{self.shard}: {self.member}: {self.reason}"


@dataclass
class VerifyReport:
    """What ``verify_dataset`` checked and found."""

    root: Path
    members: int = 0
    shards: int = 0
    unchecked: int = 0  # members without a checksum (a dataset built before checksums)
    damage: list[Damage] = field(default_factory=list)

    def format(self) -> str:
        """One line per damaged member, then a summary line."""
        lines = [str(d) for d in self.damage]
        state = f"{len(self.damage)} damaged" if self.damage else "all intact"
        extra = f", {self.unchecked} without a checksum" if self.unchecked else ""
        lines.append(
            f"{self.root}: {self.members} members in {self.shards} shards checked: {state}{extra}"
        )
        return "\n".join(lines)


def verify_dataset(root: str | Path) -> VerifyReport:
    """Check every member of the dataset at ``root`` (see the module docstring)."""
    root = Path(root)
    manifest = Manifest.open(root)
    location = [f"{m}_{s}" for m in MEMBERS for s in ("shard", "offset", "size")]
    manifest.require(["key", "ground_member", *location])
    checksums = [f"{m}_crc32c" for m in MEMBERS if f"{m}_crc32c" in manifest.schema.names]
    rows = manifest.to_table(columns=["key", "ground_member", *location, *checksums]).to_pylist()
    by_shard: dict[str, list[_Entry]] = defaultdict(list)
    for row in rows:
        for m in MEMBERS:
            shard = row.get(f"{m}_shard")
            if shard is None:
                continue
            ext = row.get("ground_member") if m == "ground" else None
            by_shard[shard].append(
                _Entry(
                    row[f"{m}_offset"],
                    row[f"{m}_size"],
                    row.get(f"{m}_crc32c"),
                    f"{row['key']}.{ext}" if ext else f"{row['key']}.{m}",
                    exact=ext is not None,
                )
            )
    report = VerifyReport(root, shards=len(by_shard))
    for shard, entries in sorted(by_shard.items()):
        _verify_shard(root, shard, sorted(entries, key=lambda e: e.offset or 0), report)
    return report


@dataclass(frozen=True)
class _Entry:
    offset: int | None
    size: int | None
    crc32c: int | None
    name: str  # the member's full name (exact) or its ``<key>.<field>`` prefix
    exact: bool


def _verify_shard(root: Path, shard: str, entries: list[_Entry], report: VerifyReport) -> None:
    report.members += len(entries)
    report.unchecked += sum(e.crc32c is None for e in entries)
    try:
        fh = open(root / shard, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        report.damage += [Damage(shard, e.name, f"cannot open: {exc}") for e in entries]
        return
    with fh:
        for entry in entries:
            problem = _check_member(fh, entry)
            if problem is not None:
                report.damage.append(Damage(shard, entry.name, problem))


def _check_member(fh: BinaryIO, entry: _Entry) -> str | None:
    """What is wrong with one member, or None."""
    offset, size, crc = entry.offset, entry.size, entry.crc32c
    if offset is None or size is None or size < 0:
        return f"no valid offset/size in the manifest ({offset}, {size})"
    block = tarfile.BLOCKSIZE
    if offset < block or offset % block:
        return f"offset {offset} is not after a tar header"
    fh.seek(offset - block)
    header = fh.read(block)
    try:
        info = tarfile.TarInfo.frombuf(header, "utf-8", "surrogateescape")
    except tarfile.TarError as exc:
        return f"bad tar header at offset {offset - block}: {exc}"
    named = info.name == entry.name if entry.exact else info.name.startswith(f"{entry.name}.")
    if not named:
        return f"tar header names {info.name!r} at offset {offset - block}"
    if info.size != size:
        return f"size {size} in the manifest, {info.size} in the tar header"
    data = fh.read(size)
    if len(data) != size:
        return f"truncated: {len(data)} of {size} bytes"
    if crc is not None and checksum(data) != crc:
        return f"checksum mismatch (crc32c {checksum(data):#010x}, manifest {crc:#010x})"
    return None
