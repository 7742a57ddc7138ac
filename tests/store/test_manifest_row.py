"""store.manifest: the manifest row's check and its member-location columns."""

from __future__ import annotations

import pytest

from mars_pairs.store.manifest import (
    LOCATION_COLUMNS,
    MANIFEST_SCHEMA,
    check_row,
    manifest_schema,
    rows_to_table,
    with_locations,
)
from mars_pairs.store.members import MEMBERS
from mars_pairs.store.shards import MemberLocation


def test_check_row_names_the_column_that_does_not_fit() -> None:
    check_row({"key": "m2020_a", "sol": 52})  # missing columns are nulls
    with pytest.raises(ValueError, match=r"^sol: 4294967296 does not fit int32"):
        check_row({"key": "m2020_a", "sol": 2**32})
    with pytest.raises(ValueError, match=r"^latitude: 'north' does not fit double"):
        check_row({"key": "m2020_a", "latitude": "north"})


def test_location_columns_of_every_member_are_in_the_schema() -> None:
    names = set(MANIFEST_SCHEMA.names)
    for m in MEMBERS:
        assert {f"{m}_{suffix}" for suffix, _ in LOCATION_COLUMNS} <= names
    extra = set(manifest_schema(["depth"]).names) - names
    assert extra == {f"depth_{suffix}" for suffix, _ in LOCATION_COLUMNS}


def test_with_locations_fills_the_members_columns_and_leaves_the_row() -> None:
    row = {"key": "m2020_a", "sol": 3}
    locs = {
        "ground.jpg": MemberLocation("shards/shard-000000.tar", 512, 10, 7),
        "meta.json": MemberLocation("shards/shard-000000.tar", 1536, 2, None),
    }
    located = with_locations(row, locs)
    assert row == {"key": "m2020_a", "sol": 3}
    assert located["ground_shard"] == "shards/shard-000000.tar"
    assert (located["ground_offset"], located["ground_size"], located["ground_crc32c"]) == (
        512,
        10,
        7,
    )
    assert (located["meta_offset"], located["meta_size"], located["meta_crc32c"]) == (1536, 2, None)
    check_row(located)
    assert rows_to_table([located], MANIFEST_SCHEMA).num_rows == 1
