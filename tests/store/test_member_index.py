"""MemberIndex: member locations and meta values in columns."""

from __future__ import annotations

import gc
import pickle

import numpy as np
import pyarrow as pa
import pytest

from mars_pairs.store.member_index import MemberIndex


def table(n: int, seed: int = 0) -> pa.Table:
    """``n`` rows over 3 shards in shuffled order; row 1 has no ortho member."""
    rng = np.random.default_rng(seed)
    shard = rng.integers(0, 3, n)
    offset = rng.permutation(n).astype(np.int64) * 1024
    ortho_offset = pa.array([None if i == 1 else int(o) for i, o in enumerate(offset)], pa.int64())
    return pa.table(
        {
            "key": [f"s{i:06d}" for i in range(n)],
            "sol": np.arange(n, dtype=np.int32),
            "latitude": rng.uniform(18, 19, n),
            "ground_shard": [f"shards/{k}.tar" for k in shard],
            "ground_offset": offset,
            "ground_size": np.full(n, 512, np.int64),
            "ortho_shard": [f"shards/{k}.tar" for k in shard],
            "ortho_offset": ortho_offset,
            "ortho_size": np.full(n, 256, np.int64),
        }
    )


def test_locations_and_meta() -> None:
    t = table(50)
    index = MemberIndex(t, ("ground", "ortho"), ("key", "sol", "latitude"))
    rows = t.to_pylist()
    assert len(index) == 50
    for i in (0, 7, 49):
        row = rows[i]
        assert index.location(i, "ground") == (row["ground_shard"], row["ground_offset"], 512)
        assert index.meta(i) == {"key": row["key"], "sol": i, "latitude": row["latitude"]}
        assert type(index.meta(i)["sol"]) is int
    assert index.metas([3, 0]) == [index.meta(3), index.meta(0)]
    with pytest.raises(KeyError, match=r"s000001\.ortho: no such member"):
        index.location(1, "ortho")


def test_shard_order_is_file_order_and_covers_every_row() -> None:
    t = table(200, seed=4)
    index = MemberIndex(t, ("ground",), ("key",))
    order = index.shard_order("ground")
    assert sorted(order) == sorted(set(t["ground_shard"].to_pylist()))
    seen = np.concatenate(list(order.values()))
    assert sorted(seen.tolist()) == list(range(200))
    for shard, indices in order.items():
        offsets = [index.location(int(i), "ground")[1] for i in indices]
        assert offsets == sorted(offsets)
        assert all(index.location(int(i), "ground")[0] == shard for i in indices)


def test_holds_columns_not_row_objects() -> None:
    n = 100_000
    t = table(n)
    gc.collect()
    before = len(gc.get_objects())
    index = MemberIndex(t, ("ground", "ortho"), ("key", "sol", "latitude"))
    gc.collect()
    assert len(gc.get_objects()) - before < 1000  # a list of row dicts adds n of them
    data = pickle.dumps(index)
    assert len(data) < 80 * n  # the columns' bytes (~63 a row), nothing per row on top
    back = pickle.loads(data)
    assert back.meta(n - 1) == index.meta(n - 1)
    assert back.location(12345, "ortho") == index.location(12345, "ortho")
