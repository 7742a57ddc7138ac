"""The member vocabulary: every dense field lies on one grid and the torch side reads it."""

from __future__ import annotations

from mars_pairs.store.members import (
    CHIP_GRID_FIELDS,
    DENSE_CHIP_FIELDS,
    DENSE_FIELDS,
    DENSE_GROUND_FIELDS,
    DENSE_MEMBERS,
    OPTIONAL_FIELDS,
    TERRAIN_FIELDS,
    member_fields,
)
from mars_pairs.torch.decode import KNOWN_FIELDS, MEMBER_SUFFIXES


def test_every_dense_field_has_one_grid_and_a_reader() -> None:
    assert member_fields(DENSE_MEMBERS) == DENSE_FIELDS
    assert not set(DENSE_GROUND_FIELDS) & set(DENSE_CHIP_FIELDS)
    assert DENSE_FIELDS == DENSE_GROUND_FIELDS + DENSE_CHIP_FIELDS
    assert set(DENSE_FIELDS) <= set(KNOWN_FIELDS) and set(DENSE_FIELDS) <= set(MEMBER_SUFFIXES)


def test_terrain_fields_are_optional_fields_with_a_reader() -> None:
    assert OPTIONAL_FIELDS == DENSE_FIELDS + TERRAIN_FIELDS
    assert not set(TERRAIN_FIELDS) & set(DENSE_FIELDS)
    assert set(CHIP_GRID_FIELDS) - set(DENSE_CHIP_FIELDS) == {"terrain_on_map"}
    assert set(TERRAIN_FIELDS) <= set(KNOWN_FIELDS) and set(TERRAIN_FIELDS) <= set(MEMBER_SUFFIXES)
