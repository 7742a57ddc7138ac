"""What the pictures of a sample take from its ``meta.json`` member: the camera centre."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import pyarrow.dataset as ds

from mars_pairs.store.query import Manifest
from mars_pairs.store.shards import MemberLocation, read_member

_LOCATION = ["meta_shard", "meta_offset", "meta_size"]


def camera_centres(root: Path, keys: Iterable[str]) -> dict[str, list[float] | None]:
    """``camera_center_map`` (map x, y, z of the dataset CRS, map units) of each sample of
    ``keys`` from its meta.json member in the dataset folder ``root``, the manifest read
    once; None for a key whose meta.json the manifest does not locate (no such column, no
    such key, a key twice, a null location) or whose member lacks the centre."""
    wanted = list(dict.fromkeys(keys))
    centres: dict[str, list[float] | None] = dict.fromkeys(wanted)
    manifest = Manifest.open(root)
    if not wanted or not set(_LOCATION) <= set(manifest.column_names):
        return centres
    table = manifest.to_table(columns=["key", *_LOCATION]).filter(ds.field("key").isin(wanted))
    rows = table.to_pylist()
    seen = Counter(r["key"] for r in rows)
    for row in rows:
        key = row["key"]
        if seen[key] != 1 or row["meta_shard"] is None:
            continue
        location = MemberLocation(row["meta_shard"], int(row["meta_offset"]), int(row["meta_size"]))
        meta = json.loads(read_member(root, location, name=f"{key}.meta.json"))
        centre = meta.get("camera_center_map") if isinstance(meta, dict) else None
        if isinstance(centre, list) and len(centre) >= 2:
            centres[key] = [float(v) for v in centre]
    return centres
