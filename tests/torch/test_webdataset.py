"""WebDataset compatibility: the shards read with webdataset, the shard index with wids."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from mars_pairs.store.wids_index import WIDS_INDEX
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset, decode_member
from support.members import SUFFIX, manifest_keys


def test_shards_read_with_webdataset(dataset_dir: Path, members: dict[str, bytes]) -> None:
    wds = pytest.importorskip("webdataset")
    urls = [str(p) for p in sorted((dataset_dir / "shards").glob("*.tar"))]
    samples = list(wds.WebDataset(urls, shardshuffle=False))
    assert sorted(s["__key__"] for s in samples) == sorted(manifest_keys(dataset_dir))
    expected = {name.split(".", 1)[0]: name for name in members}
    assert len(expected) == len(samples)
    for s in samples:
        fields = {k: v for k, v in s.items() if not k.startswith("__")}
        assert set(fields) == {"ground.jpg", *SUFFIX.values()}
        for ext, data in fields.items():
            assert data == members[f"{s['__key__']}.{ext}"], (s["__key__"], ext)


def test_the_shard_index_opens_with_wids(
    dataset_dir: Path, members: dict[str, bytes], tmp_path: Path
) -> None:
    wids = pytest.importorskip("wids")
    index = dataset_dir / WIDS_INDEX
    doc = json.loads(index.read_text())
    assert doc["wids_version"] == 1 and len(doc["shardlist"]) == 3
    assert not list(dataset_dir.glob(f".{WIDS_INDEX}.tmp-*"))  # written through a rename
    ds = wids.ShardListDataset(str(index), cache_dir=str(tmp_path / "cache"), transformations=[])
    try:
        assert len(ds) == len(manifest_keys(dataset_dir)) == 9
        seen = []
        with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as ours:
            for i in range(len(ds)):
                sample = ds[i]
                key = sample["__key__"]
                seen.append(key)
                fields = {k: v for k, v in sample.items() if not k.startswith("__")}
                assert set(fields) == {".ground.jpg", *(f".{v}" for v in SUFFIX.values())}
                for ext, stream in fields.items():
                    assert stream.read() == members[f"{key}{ext}"], (key, ext)
                mine = ours[ours.index_of(key)]
                for name in ALL_FIELDS:  # wids' bytes decode to the dataset's tensors
                    ext = ".ground.jpg" if name == "ground" else f".{SUFFIX[name]}"
                    fields[ext].seek(0)
                    tensor = decode_member(name, fields[ext].read())
                    assert torch.equal(tensor.nan_to_num(-1), mine[name].nan_to_num(-1)), name
        assert sorted(seen) == sorted(manifest_keys(dataset_dir))
    finally:
        ds.close()
