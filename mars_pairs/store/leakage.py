"""The leak check of a built manifest: do samples of different splits share ground?

Independent of the split rule (``store/splits.py``): it tests the extents actually written,
every chip (rotated square around the rover) and footprint polygon of one split against those
of every other split, with shapely's STRtree. Samples in the ``buffer`` split take no part.
Map units of the dataset CRS throughout.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa
import shapely

from mars_pairs.store.splits import BUFFER, TRAIN


def chip_polygons(
    x: np.ndarray, y: np.ndarray, size_m: float, rotation_deg: np.ndarray
) -> np.ndarray:
    """Chip squares of side ``size_m`` centred on map points (x, y), turned ``rotation_deg``
    (clockwise, the chip's up direction from grid north), as shapely polygons."""
    t = np.radians(np.asarray(rotation_deg, dtype=np.float64))
    h = size_m / 2.0
    ux, uy = np.sin(t) * h, np.cos(t) * h  # up
    rx, ry = np.cos(t) * h, -np.sin(t) * h  # right
    corners = np.stack(
        [
            np.stack([x + s * rx + u * ux, y + s * ry + u * uy], axis=-1)
            for s, u in ((-1, 1), (1, 1), (1, -1), (-1, -1))
        ],
        axis=1,
    )
    chips = shapely.polygons(corners)
    assert isinstance(chips, np.ndarray)  # (N, 4, 2) corners: N polygons, not one
    return chips


def _pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) with geometry a[i] intersecting b[j] (None entries never match)."""
    tree = shapely.STRtree(b)
    i, j = tree.query(a, predicate="intersects")
    return i, j


def _min_distance(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) == 0 or len(b) == 0:
        return None
    _, dist = shapely.STRtree(b).query_nearest(a, return_distance=True, all_matches=False)
    return float(dist.min())


#: The manifest columns :func:`leak_report` reads.
LEAK_COLUMNS = ("split", "easting", "northing", "chip_rotation_deg", "footprint")


def leak_report(table: pa.Table, size_m: float) -> dict[str, Any]:
    """Intersections between the chips/footprints of samples of different splits, and the
    nearest held-out to train distances (rover to rover, extent to extent), map units."""
    split = np.asarray(table["split"].to_pylist(), dtype=object)
    keep = split != BUFFER
    split = split[keep]
    x = table["easting"].to_numpy()[keep]
    y = table["northing"].to_numpy()[keep]
    rot = table["chip_rotation_deg"].fill_null(0.0).to_numpy()[keep]
    chips = chip_polygons(x, y, size_m, rot)
    wkb = np.asarray(table["footprint"].to_pylist(), dtype=object)[keep]
    feet = np.array([None if w is None else shapely.from_wkb(w) for w in wkb], dtype=object)
    counts = {}
    for name, a, b, ordered in (
        ("chip_chip", chips, chips, False),
        ("footprint_footprint", feet, feet, False),
        ("chip_footprint", chips, feet, True),
    ):
        i, j = _pairs(a, b) if len(split) else (np.zeros(0, int), np.zeros(0, int))
        differ = (split[i] != split[j]) & (i != j if ordered else i < j)
        counts[name] = int(np.count_nonzero(differ))
    held, train = split != TRAIN, split == TRAIN
    extents = np.array(
        [c if f is None else shapely.union(c, f) for c, f in zip(chips, feet, strict=True)],
        dtype=object,
    )
    rover = shapely.points(x, y)
    near = _min_distance(rover[held], rover[train])
    gap = _min_distance(extents[held], extents[train])
    return {
        "intersections_between_splits": counts,
        "min_rover_distance_held_out_to_train_m": None if near is None else round(near, 3),
        "min_extent_gap_held_out_to_train_m": None if gap is None else round(gap, 3),
    }


def rounded(value: float) -> float:
    """A distance for dataset.json: millimetres, rounded up (a bound stays a bound)."""
    return math.ceil(value * 1000.0) / 1000.0
