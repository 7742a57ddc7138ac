"""pipeline.builder.key_index: the build's on-disk record of the sample keys built, where the
duplicate-key check looks keys up (across chunks, across an append), and its scratch file."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.pipeline.builder.commit import select_chunk
from mars_pairs.pipeline.builder.engine import ChunkResult, Outcome
from mars_pairs.pipeline.builder.hygiene import clear_outputs, foreign_file
from mars_pairs.pipeline.builder.key_index import KeyIndex, open_index
from mars_pairs.pipeline.builder.layout import KEY_INDEX, part_paths, written_by
from mars_pairs.store.shards import MemberLocation


def _ok(k: int, label: str, key: str) -> Outcome:
    loc = MemberLocation(f"shards/shard-{k:06d}-train.tar", 512, 3, 1)
    return Outcome("ok", label, key, {"key": key, "label_path": label}, {"meta.json": loc}, {})


def _chunk(k: int, *outcomes: Outcome) -> ChunkResult:
    shards = ((f"shards/shard-{k:06d}-train.tar", 2048),)
    return ChunkResult(k, outcomes, shards, 0.5, "host:1", None)


def test_a_key_of_an_earlier_chunk_is_a_duplicate_through_the_index(tmp_path: Path) -> None:
    with open_index(tmp_path / "ds") as seen:
        first = select_chunk(_chunk(0, _ok(0, "a.xml", "k_a"), _ok(0, "b.xml", "k_b")), seen, False)
        seen.update(first.built)
        assert len(seen) == 2 and seen["k_a"] == "a.xml" and "k_c" not in seen
        later = select_chunk(
            _chunk(1, _ok(1, "c.xml", "k_c"), _ok(1, "a2.xml", "k_a")), seen, False
        )
        seen.update(later.built)
        assert sorted(seen) == ["k_a", "k_b", "k_c"]
    assert [o.kind for o in later.outcomes] == ["ok", "duplicate"]
    assert later.committed == ("k_c",)
    assert "already built from a.xml" in later.failures[0]["message"]
    assert later.failures[0]["path"] == "a2.xml"


def test_a_key_of_the_dataset_appended_to_is_a_duplicate_through_the_index(
    tmp_path: Path,
) -> None:
    out = tmp_path / "ds"
    base = tmp_path / "manifest.parquet"  # the dataset's manifest: key and label per sample
    keys = [f"k_{i:05d}" for i in range(70_000)]  # more rows than one read batch
    labels = [f"old/{k}.xml" for k in keys]
    pq.write_table(pa.table({"key": keys, "label_path": labels, "x": range(len(keys))}), base)
    (out / "parts").mkdir(parents=True)
    pq.write_table(pa.table({"key": ["k_new"], "label_path": ["new/a.xml"]}), part_paths(out, 7)[1])
    with open_index(out) as seen:
        seen.add_table(base)
        seen.add_parts(out, [7])  # a committed chunk of the interrupted append
        sel = select_chunk(
            _chunk(8, _ok(8, "new/b.xml", "k_b"), _ok(8, "new/x.xml", "k_69999")), seen, False
        )
        again = select_chunk(_chunk(9, _ok(9, "new/c.xml", "k_new")), seen, False)
        assert len(seen) == 70_001
    assert [o.kind for o in sel.outcomes] == ["ok", "duplicate"]
    assert "already built from old/k_69999.xml" in sel.failures[0]["message"]
    assert "already built from new/a.xml" in again.failures[0]["message"]


def test_a_local_builds_index_is_a_build_file_in_parts_removed_when_done(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    (out / "parts").mkdir(parents=True)
    stale = out / KEY_INDEX  # a killed build's, with a key the new build must not see
    with sqlite3.connect(stale) as db:
        db.execute("CREATE TABLE keys (key TEXT PRIMARY KEY, label TEXT NOT NULL)")
        db.execute("INSERT INTO keys VALUES ('k_old', 'old.xml')")
    db.close()
    assert written_by(1, KEY_INDEX) and not written_by(None, KEY_INDEX)
    with open_index(out) as seen:
        assert (out / KEY_INDEX).is_file()  # in the output folder, not the system's temp
        assert "k_old" not in seen and len(seen) == 0
        seen.update({"k": "a.xml"})
    assert not (out / KEY_INDEX).exists()
    assert sorted(p.name for p in (out / "parts").iterdir()) == []


def test_a_killed_builds_index_is_cleared_with_its_build(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    (out / "parts").mkdir(parents=True)
    (out / "parts/build.json").write_text('{"count": 1, "config": {"output": {"shard_size": 1}}}')
    KeyIndex(out / KEY_INDEX).close()
    assert foreign_file(out) is None  # a build file: the folder may be resumed or cleared
    clear_outputs(out)
    assert not (out / KEY_INDEX).exists()


def test_an_object_storage_builds_index_is_in_the_local_staging_folder() -> None:
    with open_index("memory://bucket/ds") as seen:
        seen.update([("k", "a.xml")])
        assert seen["k"] == "a.xml"
        with pytest.raises(KeyError):
            seen["other"]
