"""Splits reach every loader: a split's samples have shards of their own, each split a shard
list and a wids index; the card's front matter makes ``datasets.load_dataset(folder)`` give
one split per split with its counts; the card's loading snippet runs as pasted."""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from support.builds import build


@pytest.fixture(scope="module")
def split_build(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small build with a held-out ``test`` box around the last stop: the first stop's
    samples are ``train`` (or ``buffer``), the last stop's ``test``; one sample a chunk."""
    truth = pq.read_table(small_mission / "truth.parquet").to_pylist()
    last = max(truth, key=lambda r: r["stop"])
    x, y = last["easting"], last["northing"]
    splits = {
        "style": "cross-area",
        "guard": "chip",
        "buffer_m": 0.0,
        "areas": {"test": [[x - 5, y - 5, x + 5, y + 5]]},
    }
    out = tmp_path_factory.mktemp("splits") / "ds"
    return build(
        small_mission, out, chips={"size_m": 8, "size_px": 32}, output={"shard_size": 3},
        whole={"splits": splits},
    )  # fmt: skip


def _rows(root: Path) -> list[dict]:
    return pq.read_table(
        root / "manifest.parquet", columns=["key", "split", "meta_shard"]
    ).to_pylist()


def test_a_splits_samples_never_share_a_shard_with_another_splits(split_build: Path) -> None:
    rows = _rows(split_build)
    by_split = Counter(r["split"] for r in rows)
    assert len(by_split) >= 2, by_split  # the test means something
    splits_of: dict[str, set[str]] = {}
    for r in rows:
        splits_of.setdefault(r["meta_shard"], set()).add(r["split"])
        assert r["meta_shard"].endswith(f"-{r['split']}.tar")
    assert all(len(s) == 1 for s in splits_of.values()), splits_of
    # a chunk of 3 samples of two splits wrote two shards
    assert len(splits_of) > -(-len(rows) // 3)
    for split, n in by_split.items():
        listed = (split_build / f"shards-{split}.txt").read_text().split()
        assert listed == sorted(s for s, sp in splits_of.items() if sp == {split})
        index = json.loads((split_build / f"shardindex-{split}.json").read_text())
        assert sum(e["nsamples"] for e in index["shardlist"]) == n
    whole = json.loads((split_build / "shardindex.json").read_text())
    assert sum(e["nsamples"] for e in whole["shardlist"]) == len(rows)


def test_webdataset_over_a_split_shard_list_yields_that_split_only(split_build: Path) -> None:
    import webdataset as wds

    rows = _rows(split_build)
    for split in {r["split"] for r in rows}:
        shards = [
            str(split_build / s) for s in (split_build / f"shards-{split}.txt").read_text().split()
        ]
        keys = [s["__key__"] for s in wds.WebDataset(shards, shardshuffle=False)]
        assert sorted(keys) == sorted(r["key"] for r in rows if r["split"] == split)
        metas = [json.loads(s["meta.json"]) for s in wds.WebDataset(shards, shardshuffle=False)]
        assert {m["split"] for m in metas} == {split}


def test_wids_reads_one_split_by_its_index(split_build: Path) -> None:
    import wids

    rows = _rows(split_build)
    for split in {r["split"] for r in rows}:
        ds = wids.ShardListDataset(str(split_build / f"shardindex-{split}.json"))
        assert len(ds) == sum(r["split"] == split for r in rows)
        got = {ds[i]["__key__"] for i in range(len(ds))}
        assert got == {r["key"] for r in rows if r["split"] == split}
        metas = [ds[i][".meta.json"] for i in range(len(ds))]  # wids decodes .json members
        assert {m["split"] for m in metas} == {split}


def _hf_offline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("HF_DATASETS_CACHE", str(tmp_path / "hf" / "datasets"))


def test_load_dataset_of_the_folder_gives_each_split_with_its_count(
    split_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _hf_offline(tmp_path, monkeypatch)
    from datasets import load_dataset

    card = (split_build / "README.md").read_text()
    front = card.split("---\n")[1]
    assert "configs:" in front and "data_files:" in front
    got = load_dataset(str(split_build), cache_dir=str(tmp_path / "cache"))
    want = Counter(r["split"] for r in _rows(split_build))
    assert {name: got[name].num_rows for name in got} == dict(want)
    for name in got:
        assert {json.loads(json.dumps(m))["split"] for m in got[name]["meta.json"]} == {name}


def test_the_cards_loading_snippet_runs_as_pasted(
    split_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _hf_offline(tmp_path, monkeypatch)
    card = (split_build / "README.md").read_text()
    (snippet,) = re.findall(r"```python\n(.*?)```", card, flags=re.S)
    monkeypatch.chdir(split_build)
    scope: dict = {}
    exec(compile(snippet, "README.md", "exec"), scope)  # the card's own code, in its folder
    rows = _rows(split_build)
    train = sorted(r["key"] for r in rows if r["split"] == "train")
    assert len(scope["ds"]) == len(train)
    assert sorted(s["__key__"] for s in scope["samples"]) == train
    assert len(scope["train"]) == len(train)
    assert scope["pairs"]["train"].num_rows == len(train)
    assert scope["rows"].num_rows == len(scope["gdf"]) == len(rows)
