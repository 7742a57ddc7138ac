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

from mars_pairs.store import fs

WIDS_INDEX = "shardindex.json"


def wids_index(root: Path | str, manifest: pa.Table) -> dict[str, Any]:
    """The index document of a dataset folder's shards (``manifest``: its rows)."""
    root = fs.dataset_root(root)
    counts = Counter(manifest.column("meta_shard").to_pylist()) if manifest.num_rows else {}
    shardlist = [
        {"url": shard, "nsamples": n, "filesize": fs.size(fs.join(root, shard))}
        for shard, n in sorted(counts.items())
    ]
    return {
        "__kind__": "wids-shard-index-v1",
        "wids_version": 1,
        "name": Path(root).name if isinstance(root, Path) else root.rsplit("/", 1)[-1],
        "shardlist": shardlist,
    }


def write_wids_index(root: Path | str, manifest: pa.Table) -> Path | str:
    """Write ``root/shardindex.json`` atomically (temp + rename; on object storage one
    whole upload: ``store.fs``); returns its path."""
    root = fs.dataset_root(root)
    path = fs.join(root, WIDS_INDEX)
    fs.put_bytes(path, json.dumps(wids_index(root, manifest), indent=1).encode())
    return path
