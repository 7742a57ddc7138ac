"""The streamed leak check against the in-memory one, on generated traverses with known leaks.

The layout: several random-walk traverses (``test_splits.traverse_case``) split by a rule
without a buffer (chips and footprints of different splits meet), some samples in the
buffer split, some without a footprint or a chip rotation, written in Hilbert-like order to
a Parquet manifest; the streamed check reads it in small batches (many sorted runs, more
than a merge's fan-in, and a window that is emptied and refilled).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import shapely

from mars_pairs.store.leakage import leak_report, streamed_leak_report
from mars_pairs.store.splits import BUFFER, TRAIN, SplitRule
from tests.store.test_splits import S, rule_for, traverse_case


def leaky_manifest(seeds: range, buffer_every: int = 0) -> pa.Table:
    """The rows of traverses ``seeds``, split with no buffer (leaks between splits), every
    ``buffer_every``-th sample in ``buffer`` (0: none), every 7th without a footprint and
    every 5th without a rotation."""
    rule = rule_for("chip", "same-area", buffer_m=0.0, block_m=700.0, seed=2)
    rule = SplitRule(**{**rule.__dict__, "reach": 0.0})
    parts = [traverse_case(seed, rule, True) for seed in seeds]
    split = np.concatenate([p["split"] for p in parts])
    x = np.concatenate([p["x"] for p in parts])
    y = np.concatenate([p["y"] for p in parts])
    rot = np.concatenate([p["rot"] for p in parts])
    feet = np.concatenate([p["feet"] for p in parts])
    n = len(x)
    if buffer_every:
        split[::buffer_every] = BUFFER
    wkb = [None if i % 7 == 3 else shapely.to_wkb(f) for i, f in enumerate(feet)]
    rotation = pa.array([None if i % 5 == 1 else float(r) for i, r in enumerate(rot)])
    order = np.lexsort((np.arange(n), np.round(y / 300.0), np.round(x / 300.0)))
    table = pa.table(
        {
            "split": pa.array(split.tolist(), pa.string()),
            "easting": x,
            "northing": y,
            "chip_rotation_deg": rotation,
            "footprint": pa.array(wkb, pa.binary()),
        }
    )
    return table.take(pa.array(order))


def both(table: pa.Table, tmp_path: Path, batch_rows: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The streamed report of ``table`` written as a manifest file, and the in-memory one."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "manifest.parquet"
    pq.write_table(table, path, row_group_size=97)
    streamed = streamed_leak_report(path, S, tmp_path / "sort", batch_rows=batch_rows)
    return streamed, leak_report(table, S)


@pytest.mark.parametrize("batch_rows", [16, 64, 5000])
def test_streamed_leak_check_is_the_in_memory_one(tmp_path: Path, batch_rows: int) -> None:
    table = leaky_manifest(range(4), buffer_every=11)
    streamed, expected = both(table, tmp_path, batch_rows)
    counts = expected["intersections_between_splits"]
    assert min(counts.values()) > 0  # the layout leaks: every count is tested
    assert expected["min_extent_gap_held_out_to_train_m"] == 0.0
    assert expected["min_rover_distance_held_out_to_train_m"] > 0.0
    assert streamed == expected
    if batch_rows == 16:
        assert len(list((tmp_path / "sort").iterdir())) > 0  # runs on disk: sorted and merged


def test_streamed_leak_check_far_splits_and_one_split(tmp_path: Path) -> None:
    """Held-out samples far from the train ones (the window spans the gap), and a manifest
    of one split (no distances), and of no sample."""
    table = leaky_manifest(range(3))
    split = np.asarray(table["split"].to_pylist(), dtype=object)
    x = table["easting"].to_numpy().copy()
    held = split != TRAIN
    x[held] += 50_000.0  # every held-out sample 50 km east
    far = table.set_column(1, "easting", pa.array(x))
    streamed, expected = both(far, tmp_path / "far", 32)
    assert expected["min_rover_distance_held_out_to_train_m"] > 40_000.0
    assert streamed == expected
    one = table.set_column(0, "split", pa.array([TRAIN] * table.num_rows))
    streamed, expected = both(one, tmp_path / "one", 32)
    assert expected["min_rover_distance_held_out_to_train_m"] is None
    assert streamed == expected
    streamed, expected = both(table.slice(0, 0), tmp_path / "none", 32)
    assert streamed == expected


@pytest.mark.parametrize("train_east", [False, True])
def test_streamed_leak_check_nearest_pair_far_apart_in_the_sweep(
    tmp_path: Path, train_east: bool
) -> None:
    """The nearest held-out-to-train pair 5 km apart along the easting with 500 samples
    between them in the sweep (1,000 km north: none nearer), so the window must keep the
    western one of the pair across them (the train sample, or the held-out one)."""
    fill = np.linspace(0.0, 5000.0, 500)
    x = np.concatenate([[5000.0, 0.0] if train_east else [0.0, 5000.0], fill])
    y = np.concatenate([[0.0, 0.0], np.full(500, 1e6)])
    split = [TRAIN, "val", *(["test"] * 500)]
    table = pa.table(
        {
            "split": split,
            "easting": x,
            "northing": y,
            "chip_rotation_deg": np.zeros(len(x)),
            "footprint": pa.array([None] * len(x), pa.binary()),
        }
    )
    streamed, expected = both(table, tmp_path, 16)
    assert expected["min_rover_distance_held_out_to_train_m"] == 5000.0
    assert streamed == expected
