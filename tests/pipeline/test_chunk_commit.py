"""pipeline.builder.commit.select_chunk: the pure rule of what a built chunk commits."""

from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace
from typing import cast

import pytest

from mars_pairs.errors import BuildError
from mars_pairs.pipeline.builder.commit import select_chunk, write_chunk
from mars_pairs.pipeline.builder.engine import ChunkResult, Outcome
from mars_pairs.pipeline.builder.layout import part_paths
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store.shards import MemberLocation


def _fail(label: str) -> Outcome:
    row = {
        "product_id": Path(label).stem.upper(),
        "path": label,
        "stage": "ground",
        "error_type": "ImageError",
        "message": f"{label}: truncated",
    }
    return Outcome("fail", label, row=row)


def _ok(label: str, key: str, seconds: dict[str, float]) -> Outcome:
    loc = MemberLocation("shards/shard-000001-train.tar", 512, 3, 1)
    return Outcome("ok", label, key, {"key": key, "label_path": label}, {"meta.json": loc}, seconds)


def _chunk(*outcomes: Outcome, staged: bool = True) -> ChunkResult:
    shards = (
        (("shards/shard-000001-train.tar", 2048),) if any(o.kind == "ok" for o in outcomes) else ()
    )
    names = ("parts/.failures-000001.parquet.tmp-1", "parts/.manifest-000001.parquet.tmp-1")
    return ChunkResult(1, outcomes, shards, 0.5, "host:1", names if staged else None)


def test_a_key_an_earlier_chunk_built_becomes_a_duplicate_failure_row() -> None:
    result = _chunk(
        _ok("a.xml", "k_a", {"view": 1.0}),
        _ok("b.xml", "k_b", {"view": 2.0}),
        Outcome("dropped", "c.xml", "k_c"),
    )
    seen = {"k_b": "first_b.xml", "k_c": "first_c.xml"}
    before = copy.deepcopy((result, seen))
    sel = select_chunk(result, seen, strict=False)
    assert (result, seen) == before  # no argument changed
    assert [o.kind for o in sel.outcomes] == ["ok", "duplicate", "duplicate"]
    assert sel.committed == ("k_a",)
    assert [(f["path"], f["stage"], f["error_type"]) for f in sel.failures] == [
        ("b.xml", "record", "DuplicateKeyError"),
        ("c.xml", "record", "DuplicateKeyError"),
    ]
    assert "already built from first_b.xml" in sel.failures[0]["message"]
    assert sel.dropped == ()
    assert sel.built == {"k_a": "a.xml"}
    assert sel.stage_seconds == {"view": 1.0}  # the duplicate's time is not counted
    assert sel.rewrite_shard  # b was written into the shard
    assert not sel.parts_staged  # the worker's parts list b: the driver writes them
    assert sel.stop is None


def test_a_chunk_duplicate_of_an_earlier_key_names_the_earlier_label() -> None:
    inner = Outcome("duplicate", "d2.xml", "k_d", _fail("d2.xml").row)
    sel = select_chunk(_chunk(inner), {"k_d": "d0.xml"}, strict=False)
    assert "already built from d0.xml" in sel.failures[0]["message"]
    assert not sel.rewrite_shard  # nothing of it was in the shard


def test_dropped_samples_own_their_key_and_are_not_committed() -> None:
    result = _chunk(_ok("a.xml", "k_a", {"view": 1.0}), Outcome("dropped", "b.xml", "k_b"))
    sel = select_chunk(result, {}, strict=False)
    assert sel.committed == ("k_a",)
    assert sel.dropped == ("k_b",)
    assert sel.built == {"k_a": "a.xml", "k_b": "b.xml"}
    assert sel.failures == ()
    assert sel.parts_staged and not sel.rewrite_shard


def test_stage_times_sum_over_the_committed_samples() -> None:
    result = _chunk(
        _ok("a.xml", "k_a", {"view": 1.25, "chips": 0.5}),
        _fail("x.xml"),
        _ok("b.xml", "k_b", {"view": 2.0, "record": 0.25}),
    )
    sel = select_chunk(result, {}, strict=False)
    assert sel.stage_seconds == {"view": 3.25, "chips": 0.5, "record": 0.25}
    assert sel.committed == ("k_a", "k_b")


def test_strict_stops_at_the_first_failure_row_in_label_order() -> None:
    result = _chunk(_ok("a.xml", "k_a", {}), _ok("b.xml", "k_b", {}), _fail("c.xml"))
    assert select_chunk(result, {}, strict=False).stop is None
    assert select_chunk(_chunk(_ok("a.xml", "k_a", {})), {}, strict=True).stop is None
    sel = select_chunk(result, {"k_b": "z.xml"}, strict=True)
    assert sel.stop is not None
    assert sel.stop.startswith("b.xml: record: DuplicateKeyError: ")
    assert select_chunk(result, {}, strict=True).stop == (
        "c.xml: ground: ImageError: c.xml: truncated"
    )


def test_a_chunk_without_staged_parts_is_written_by_the_driver() -> None:
    sel = select_chunk(_chunk(_ok("a.xml", "k_a", {}), staged=False), {}, strict=False)
    assert not sel.parts_staged and not sel.rewrite_shard


def test_write_chunk_of_a_strict_stop_removes_the_staged_parts(tmp_path: Path) -> None:
    result = _chunk(_fail("c.xml"))
    for rel in result.staged or ():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"x")
    config = cast(BuildConfig, SimpleNamespace(output=SimpleNamespace(dir=tmp_path)))
    with pytest.raises(BuildError, match=r"c\.xml: ground: ImageError"):
        write_chunk(config, result, select_chunk(result, {}, strict=True))
    assert not any((tmp_path / "parts").iterdir())
    assert not part_paths(tmp_path, 1)[1].exists()
