"""Spatial-block splits and a space-filling-curve order for map positions.

Positions are map coordinates (x easting, y northing, map units ~ metres) of one CRS.
"""

from __future__ import annotations

import hashlib

import numpy as np
from numpy.typing import ArrayLike, NDArray


def block_ids(x: ArrayLike, y: ArrayLike, block_m: float) -> NDArray[np.int64]:
    """Block index pairs (N, 2): floor(x / block_m), floor(y / block_m)."""
    xs = np.floor(np.asarray(x, dtype=np.float64) / block_m).astype(np.int64)
    ys = np.floor(np.asarray(y, dtype=np.float64) / block_m).astype(np.int64)
    return np.stack([xs, ys], axis=-1)


def _unit_hash(bx: int, by: int, seed: int) -> float:
    digest = hashlib.blake2b(f"{seed}:{bx}:{by}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") / 2.0**64


def assign_splits(
    x: ArrayLike, y: ArrayLike, block_m: float, ratios: dict[str, float], seed: int = 0
) -> list[str]:
    """The split of each position: every block goes whole into one split, by a seeded hash.

    Deterministic and independent of the other positions, so adding data never moves a
    block from one split to another.
    """
    names = list(ratios)
    edges = np.cumsum([ratios[n] for n in names])
    out = []
    for bx, by in block_ids(x, y, block_m):
        u = _unit_hash(int(bx), int(by), seed)
        out.append(names[min(int(np.searchsorted(edges, u, side="right")), len(names) - 1)])
    return out


def hilbert_index(
    x: ArrayLike, y: ArrayLike, bounds: tuple[float, float, float, float], order: int = 16
) -> NDArray[np.int64]:
    """Hilbert-curve index of positions on a 2^order grid spanning ``bounds`` (W, S, E, N).

    Sorting rows by it keeps nearby positions in the same Parquet row groups.
    """
    west, south, east, north = bounds
    n = 1 << order
    span_x, span_y = max(east - west, 1e-9), max(north - south, 1e-9)
    xi = np.clip(((np.asarray(x) - west) / span_x * (n - 1)).astype(np.int64), 0, n - 1)
    yi = np.clip(((np.asarray(y) - south) / span_y * (n - 1)).astype(np.int64), 0, n - 1)
    d = np.zeros_like(xi)
    s = n >> 1
    while s > 0:
        rx = ((xi & s) > 0).astype(np.int64)
        ry = ((yi & s) > 0).astype(np.int64)
        d += s * s * ((3 * rx) ^ ry)
        # rotate the quadrant
        flip = ry == 0
        swap_x = np.where(flip & (rx == 1), s - 1 - xi, xi)
        swap_y = np.where(flip & (rx == 1), s - 1 - yi, yi)
        xi = np.where(flip, swap_y, xi)
        yi = np.where(flip, swap_x, yi)
        s >>= 1
    return d
