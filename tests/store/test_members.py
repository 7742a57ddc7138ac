"""One vocabulary of the optional dense members: the store's, which the build writes."""

from __future__ import annotations

from mars_pairs.pipeline import dense
from mars_pairs.store.members import DENSE_CHIP_FIELDS, DENSE_FIELDS, DENSE_GROUND_FIELDS
from mars_pairs.torch.decode import KNOWN_FIELDS, MEMBER_SUFFIXES


def test_the_build_writes_exactly_the_store_fields_in_tar_order() -> None:
    assert dense.DENSE_FIELDS == DENSE_FIELDS
    assert dense.member_fields(dense.DENSE_MEMBERS) == DENSE_FIELDS


def test_every_dense_field_has_one_grid_and_a_reader() -> None:
    assert not set(DENSE_GROUND_FIELDS) & set(DENSE_CHIP_FIELDS)
    assert DENSE_FIELDS == DENSE_GROUND_FIELDS + DENSE_CHIP_FIELDS
    assert set(DENSE_FIELDS) <= set(KNOWN_FIELDS) and set(DENSE_FIELDS) <= set(MEMBER_SUFFIXES)
