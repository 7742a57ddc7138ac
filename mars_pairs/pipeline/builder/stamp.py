"""The build stamp (``parts/build.json``): the fingerprint of the build that wrote the parts (its
config, its label list, and its other inputs: the PLACES table, the DEM and the ortho, with a
VRT's source tiles); a resumed build must match it (``stamp_difference``). It also lists what
that build writes: its label count and ``output.shard_size`` give its chunks.

A finished build's stamp lives on as ``build_stamp`` in dataset.json (``finished_stamp``: the
label count, shard size and the SHA-256 of the fingerprint, no paths).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from mars_pairs.pipeline.builder.fingerprints import (
    INPUT_KEYS,
    LabelDigest,
    input_change,
    inputs_fingerprint,
)
from mars_pairs.pipeline.builder.layout import CLEARING
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store import fs

#: dataset.json's key holding the stamp of the finished build (``stamp_digest``).
FINISHED_KEY = "build_stamp"


def stamp_difference(previous: dict[str, Any], stamp: dict[str, Any]) -> str | None:
    """Why a build of fingerprint ``stamp`` cannot resume one of ``previous`` (one phrase:
    the config or label list, or the input and what changed); None when they match."""
    for key in ("config", "labels", "count"):
        if previous.get(key) != stamp.get(key):
            return "the config or the label list changed since the interrupted build"
    old, new = previous.get("inputs"), stamp.get("inputs", {})
    if not isinstance(old, dict):
        return "the interrupted build's stamp records no fingerprint of its inputs"
    for key in INPUT_KEYS:
        if old.get(key) != new.get(key):
            return (
                f"inputs.{key} changed since the interrupted build: {new[key].get('path')}: "
                f"{input_change(old.get(key), new[key])}"
            )
    return None if previous == stamp else "the build stamp differs"


def fingerprint(config: BuildConfig, labels: Iterable[str | Path]) -> dict[str, Any]:
    """What a resumed build must share with the interrupted one: the config (without its
    source and output folder), the label list's digest and count (in one streaming pass),
    and the fingerprint of the other inputs (``inputs_fingerprint``)."""
    digest = LabelDigest()
    for label in labels:
        digest.add(str(label))
    return stamp_of(config, digest)


def stamp_of(config: BuildConfig, digest: LabelDigest) -> dict[str, Any]:
    """The fingerprint of ``config`` with the label list that ``digest`` summed."""
    doc = config.to_dict()
    doc.pop("source", None)
    doc["output"].pop("dir", None)
    return {
        "config": doc,
        "labels": digest.hexdigest(),
        "count": digest.count,
        "inputs": inputs_fingerprint(config),
    }


def read_stamp(stamp: fs.Location) -> dict[str, Any] | None:
    """The fingerprint of the build that wrote the parts; None when absent or damaged."""
    try:
        doc = json.loads(fs.read_bytes(stamp))
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


def finished_stamp(out: fs.Location) -> dict[str, Any] | None:
    """The ``stamp_digest`` of the finished build in ``out`` (dataset.json's ``build_stamp``);
    None when there is none."""
    doc = read_stamp(fs.join(out, "dataset.json"))
    digest = doc.get(FINISHED_KEY) if doc is not None else None
    return digest if isinstance(digest, dict) else None


def stamp_chunks(stamp: Any) -> int | None:
    """The chunk count of the build a stamp describes (its label count over its
    ``output.shard_size``, or its ``chunks`` when larger: an append's stamp and an appended
    dataset's ``build_stamp`` count the chunks before it too); None when ``stamp`` is not a
    build's fingerprint. A finished build's dataset.json (its ``build_stamp``) describes that
    build."""
    try:
        if isinstance(stamp, dict) and isinstance(stamp.get(FINISHED_KEY), dict):
            count, size = stamp[FINISHED_KEY]["count"], stamp[FINISHED_KEY]["shard_size"]
            chunks = stamp[FINISHED_KEY].get("chunks")
        else:
            count, size = stamp["count"], stamp["config"]["output"]["shard_size"]
            chunks = stamp.get("chunks")
    except (KeyError, TypeError, AttributeError):
        return None
    ints = all(isinstance(v, int) and not isinstance(v, bool) for v in (count, size))
    if not ints or count < 0 or size < 1:
        return None
    n: int = -(-count // size)
    if isinstance(chunks, int) and not isinstance(chunks, bool) and chunks > n:
        return chunks  # an appended dataset's (or an append's): chunks beyond its count's
    return n


def stamped_chunks(out: fs.Location) -> int | None:
    """The chunks of the build(s) whose stamp the folder holds (the build's, and a clearing's
    left by a killed clearing); None when it holds no valid stamp."""
    stamps = ("parts/build.json", CLEARING, "dataset.json")
    counts = [stamp_chunks(read_stamp(fs.join(out, rel))) for rel in stamps]
    valid = [n for n in counts if n is not None]
    return max(valid) if valid else None


def appended_to(stamp: Any) -> int:
    """The chunks of the finished dataset an append's stamp appends to (its first chunk: a
    finished build vouched for them); 0 for any other stamp."""
    append = stamp.get("append") if isinstance(stamp, dict) else None
    first = append.get("first_chunk") if isinstance(append, dict) else None
    return first if isinstance(first, int) and not isinstance(first, bool) else 0
