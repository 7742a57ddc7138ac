"""The shard index WebDataset's indexed reader opens (``wids.ShardListDataset``), and the
shard list of each split.

The format is wids' own (``widsindex create`` writes the same): ``wids_version`` 1 and a
``shardlist`` of {url, nsamples, filesize}, the urls relative to the index's folder. The
counts come from the manifest (every sample's members sit in one shard, in order), so
writing the index reads no shard. A split's samples have shards of their own, so each split
has its index (``shardindex-<split>.json``) and its shard list (``shards-<split>.txt``: the
shards relative to the folder, one a line, the list ``webdataset.WebDataset`` takes).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.store import fs

WIDS_INDEX = "shardindex.json"


def shard_list_name(split: str) -> str:
    """The shard list of ``split``, relative to the dataset folder."""
    return f"shards-{split}.txt"


def split_index_name(split: str) -> str:
    """The wids index of ``split``'s shards, relative to the dataset folder."""
    return f"shardindex-{split}.json"


def shard_counts(manifest: pa.Table) -> dict[str, dict[str, int]]:
    """split -> shard -> samples of the manifest rows ``manifest``."""
    counts: dict[str, dict[str, int]] = {}
    if manifest.num_rows:
        pairs = zip(manifest["split"].to_pylist(), manifest["meta_shard"].to_pylist(), strict=True)
        for (split, shard), n in Counter(pairs).items():
            counts.setdefault(split, {})[shard] = n
    return counts


def wids_index(root: Path | str, manifest: pa.Table, split: str | None = None) -> dict[str, Any]:
    """The index document of a dataset folder's shards (``manifest``: its rows), or of the
    shards of ``split``'s samples."""
    return shards_index(root, shard_counts(manifest), split)


def shards_index(
    root: Path | str, shards: Mapping[str, Mapping[str, int]], split: str | None = None
) -> dict[str, Any]:
    """:func:`wids_index` from the samples a shard of each split (``shards``: split -> shard
    -> samples, as :func:`shard_counts` counts them)."""
    root = fs.dataset_root(root)
    counts: Counter[str] = Counter()
    for name, per_shard in shards.items():
        if split is None or name == split:
            counts.update(per_shard)
    shardlist = [
        {"url": shard, "nsamples": n, "filesize": fs.size(fs.join(root, shard))}
        for shard, n in sorted(counts.items())
    ]
    return {
        "__kind__": "wids-shard-index-v1",
        "wids_version": 1,
        # a split's index is named by its split: the same bytes wherever the folder is
        "name": split
        if split is not None
        else (Path(root).name if isinstance(root, Path) else root.rsplit("/", 1)[-1]),
        "shardlist": shardlist,
    }


def write_wids_index(root: Path | str, shards: Mapping[str, Mapping[str, int]]) -> Path | str:
    """Write ``root/shardindex.json``, and of each split of ``shards`` (split -> shard ->
    samples: :func:`shard_counts`) its index and its shard list, each atomically (temp +
    rename; on object storage one whole upload: ``store.fs``); returns the path of the whole
    folder's index."""
    root = fs.dataset_root(root)
    path = fs.join(root, WIDS_INDEX)
    fs.put_bytes(path, json.dumps(shards_index(root, shards), indent=1).encode())
    for split in sorted(shards):
        doc = shards_index(root, shards, split)
        fs.put_bytes(fs.join(root, split_index_name(split)), json.dumps(doc, indent=1).encode())
        listing = "".join(f"{entry['url']}\n" for entry in doc["shardlist"])
        fs.put_bytes(fs.join(root, shard_list_name(split)), listing.encode())
    return path
