"""The shard index WebDataset's indexed reader opens (``wids.ShardListDataset``).

The format is wids' own (``widsindex create`` writes the same): ``wids_version`` 1 and a
``shardlist`` of {url, nsamples, filesize}, the urls relative to the index's folder. The
counts come from the manifest (every sample's members sit in one shard, in order), so
writing the index reads no shard.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.store.atomic import atomic_write_bytes

WIDS_INDEX = "shardindex.json"


def wids_index(root: Path, manifest: pa.Table) -> dict[str, Any]:
    """The index document of a dataset folder's shards (``manifest``: its rows)."""
    counts = Counter(manifest.column("meta_shard").to_pylist()) if manifest.num_rows else {}
    shardlist = [
        {"url": shard, "nsamples": n, "filesize": (Path(root) / shard).stat().st_size}
        for shard, n in sorted(counts.items())
    ]
    return {
        "__kind__": "wids-shard-index-v1",
        "wids_version": 1,
        "name": Path(root).name,
        "shardlist": shardlist,
    }


def write_wids_index(root: Path, manifest: pa.Table) -> Path:
    """Write ``root/shardindex.json`` atomically (temp + rename); returns its path."""
    path = Path(root) / WIDS_INDEX
    atomic_write_bytes(path, json.dumps(wids_index(root, manifest), indent=1).encode())
    return path
