"""Cell bitmask records against rasterio's own cell lookup (``rasterio.transform.rowcol``)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from affine import Affine
from rasterio.transform import rowcol

from mars_pairs.store.cellmask import CELLS_TYPE, cells_at, pack_cells


@pytest.mark.parametrize(
    "transform",
    [
        Affine(1.0, 0.0, 4352000.0, 0.0, -1.0, 1093000.0),  # north-up, map offsets in millions
        Affine(0.5, 0.0, -120.25, 0.0, 0.5, 300.0),  # south-up
    ],
)
def test_cells_at_is_the_masks_cell_under_the_point(transform: Affine) -> None:
    rng = np.random.default_rng(3)
    masks = [np.zeros((40, 50), dtype=np.uint8) for _ in range(3)]
    masks[0][5:30, 7:41] = rng.random((25, 34)) < 0.6
    masks[1][20, 33] = 1
    records = [pack_cells(m, transform) for m in masks]
    assert records[2] is None
    cells = pa.array(records, type=CELLS_TYPE)
    for _ in range(400):
        col, row = rng.uniform(-2, 52), rng.uniform(-2, 42)
        x, y = transform * (col, row)
        r, c = rowcol(transform, x, y)
        want = [
            i for i, m in enumerate(masks)
            if 0 <= r < m.shape[0] and 0 <= c < m.shape[1] and m[r, c]
        ]  # fmt: skip
        assert cells_at(cells, x, y).tolist() == want


def test_a_record_is_the_set_cells_bounding_box() -> None:
    mask = np.zeros((6, 9), dtype=bool)
    mask[2, 3] = mask[4, 7] = True
    record = pack_cells(mask, Affine(2.0, 0.0, 10.0, 0.0, -2.0, 50.0))
    assert record is not None
    assert (record["x0"], record["y0"], record["rows"], record["cols"]) == (16.0, 46.0, 3, 5)
    bits = np.unpackbits(np.frombuffer(record["bits"], dtype=np.uint8))[:15].reshape(3, 5)
    assert bits.tolist() == mask[2:5, 3:8].astype(int).tolist()
