"""What a build keeps in its output folder: chunk part paths, the build stamp, clearing.

The stamp (``parts/build.json``) holds the fingerprint of the build that wrote the parts; a
resumed build must match it. Clearing is ordered so that a kill at any point resumes.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store.wids_index import WIDS_INDEX

DROPPED_KEY = b"mars_pairs:dropped_in_buffer"


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


def built_keys(out: Path, done: Iterable[int]) -> dict[str, str]:
    """Sample key -> label path of the chunks a resumed build keeps (for duplicate ids)."""
    seen: dict[str, str] = {}
    for k in done:
        part = pq.read_table(part_paths(out, k)[1], columns=["key", "label_path"])
        seen.update(zip(part["key"].to_pylist(), part["label_path"].to_pylist(), strict=True))
    return seen


def clear_outputs(out: Path) -> None:
    """Remove what an earlier build left, crash-safely: the stamp goes first, so a build
    killed at any point of the clearing leaves no stamp and its rerun (resumed or not)
    clears again; then the dataset's own commit marker (manifest.parquet), so no reader
    sees a manifest whose shards are going; then the chunk commit markers (manifest parts)
    before the failure parts and shards they vouch for."""
    for pattern in (
        "parts/build.json",
        "manifest.parquet",
        "dataset.json",
        WIDS_INDEX,
        "failures.parquet",
        "parts/manifest-*.parquet",
        "parts/*.parquet",
        "shards/*.tar",
    ):
        for stale in sorted(out.glob(pattern)):
            if stale.is_file():
                stale.unlink()
