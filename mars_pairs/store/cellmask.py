"""A raster mask's set cells as a compact record on its own grid (``pack_cells``), and which
records hold a map point's cell (``cells_at``).

A record is a dict of ``CELLS_TYPE``: ``x0``, ``y0`` the top-left corner of the mask's
bounding box of set cells (map units), ``dx``, ``dy`` the grid's cell size (map units, signed
as the grid's transform: ``dy`` < 0 for a north-up grid), ``rows``, ``cols`` the box's size
and ``bits`` its cells row-major, one bit each, most significant bit first
(``numpy.packbits``). A map point (x, y) lies in the cell (floor((y - y0) / dy),
floor((x - x0) / dx)) of the box, the cell rasterio's ``~transform * (x, y)`` floored names
on the grid: the record answers exactly what the mask says for the cell holding the point.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
from affine import Affine

#: the record's Arrow type (a struct column)
CELLS_TYPE = pa.struct(
    [
        ("x0", pa.float64()),
        ("y0", pa.float64()),
        ("dx", pa.float64()),
        ("dy", pa.float64()),
        ("rows", pa.int32()),
        ("cols", pa.int32()),
        ("bits", pa.binary()),
    ]
)


def set_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(row0, row1, col0, col1), the half-open bounding box of the set cells of ``mask``
    (rows, cols; nonzero = set); None when no cell is set."""
    rows = np.flatnonzero(mask.any(axis=1))
    if not rows.size:
        return None
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    cols = np.flatnonzero(mask[r0:r1].any(axis=0))
    return r0, r1, int(cols[0]), int(cols[-1]) + 1


def pack_cells(mask: np.ndarray, transform: Affine) -> dict[str, Any] | None:
    """The set cells of ``mask`` (rows, cols; nonzero = set) on the axis-aligned grid of
    ``transform`` (pixel corners -> map x, y) as a ``CELLS_TYPE`` record; None when no cell
    is set."""
    data = np.asarray(mask) != 0
    found = set_box(data)
    if found is None:
        return None
    r0, r1, c0, c1 = found
    box = data[r0:r1, c0:c1]
    x0, y0 = transform * (c0, r0)
    return {
        "x0": float(x0), "y0": float(y0),
        "dx": float(transform.a), "dy": float(transform.e),
        "rows": r1 - r0, "cols": c1 - c0,
        "bits": np.packbits(box.ravel()).tobytes(),
    }  # fmt: skip


def cells_at(cells: pa.Array | pa.ChunkedArray, x: float, y: float) -> np.ndarray:
    """Indices (ascending) of the ``CELLS_TYPE`` records of ``cells`` whose cell holding map
    point (x, y) (map units) is set; a null record holds no cell."""
    if isinstance(cells, pa.ChunkedArray):
        cells = cells.combine_chunks()
    if len(cells) == 0:
        return np.zeros(0, dtype=np.int64)
    field = {name: cells.field(name) for name in ("x0", "y0", "dx", "dy", "rows", "cols")}
    num = {k: v.to_numpy(zero_copy_only=False) for k, v in field.items()}
    valid = ~np.asarray(cells.is_null().to_numpy(zero_copy_only=False), dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        col = np.floor((x - num["x0"]) / num["dx"])
        row = np.floor((y - num["y0"]) / num["dy"])
    inside = valid & (col >= 0) & (row >= 0) & (col < num["cols"]) & (row < num["rows"])
    hits = []
    bits = cells.field("bits")
    for i in np.flatnonzero(inside):
        index = int(row[i]) * int(num["cols"][i]) + int(col[i])
        byte = bits[i].as_py()[index >> 3]
        if (byte >> (7 - (index & 7))) & 1:
            hits.append(int(i))
    return np.array(hits, dtype=np.int64)
