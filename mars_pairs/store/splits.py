"""Leak-free spatial splits and a space-filling-curve order for map positions.

Positions are map coordinates (x easting, y northing, map units) of the dataset CRS.

The plane is cut into *regions*, each with a split. ``same-area``: square blocks of ``block_m``
map units, each block's split drawn by a seeded hash (held-out blocks interleaved over the
area). ``cross-area``: held-out areas (map boxes) named by split, as VIGOR holds out whole
cities; everything outside them is ``train``. A sample's *home* split is that of the region
holding its rover. Every split but ``train`` is *held out*.

The buffer: every sample's extent (its chip, and with ``guard: footprint`` its footprint) lies
within ``reach`` map units of its rover. A sample becomes ``buffer`` when the disk of radius
``reach + buffer_m`` around its rover meets a held-out region whose split is not its own.

Why no extents of two kept samples of different splits intersect: one of them (p, home
region H) is held out and the other (q) is not of H's split, so q was tested against H: the
disk of radius reach + buffer_m around q misses H, which holds p, so |p - q| > reach +
buffer_m, and the extents, each within reach of its rover, are more than buffer_m - reach
apart: disjoint whenever buffer_m >= reach (``guaranteed`` in dataset.json).

A sample's split depends only on its rover position and the config (not on the other
samples), so builds are the same whatever the worker count or resume.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mars_pairs.errors import ConfigError

BUFFER = "buffer"  # the split of samples in the buffer (when kept)
TRAIN = "train"  # the one split that is not held out
#: What a split may be named: it names the split's shards (``shard-000000-<split>.tar``), shard
#: list and Hugging Face split.
SPLIT_NAME = re.compile(r"[a-z][a-z0-9_]*", re.ASCII)
MAX_BLOCKS = 250_000  # blocks a same-area sample may test (block_m >= zone / ~250)
MAST_REACH_M = 3.0  # camera centre to rover origin: footprints include the camera centre


@dataclass(frozen=True)
class SplitRule:
    """Regions, their splits and the buffer (map units). See the module docstring."""

    style: str = "same-area"  # same-area | cross-area
    block_m: float = 1000.0
    ratios: dict[str, float] = field(
        default_factory=lambda: {"train": 0.8, "val": 0.1, "test": 0.1}
    )
    seed: int = 0
    areas: dict[str, tuple[tuple[float, float, float, float], ...]] = field(default_factory=dict)
    reach: float = 0.0  # every sample's extent lies within this distance of its rover
    buffer_m: float = 0.0

    @property
    def guaranteed(self) -> bool:
        """Whether the rule guarantees disjoint extents across splits (buffer_m >= reach)."""
        return self.buffer_m >= self.reach

    def home(self, x: float, y: float) -> str:
        """The split of the region holding map point (x, y)."""
        if self.style == "same-area":
            bx, by = math.floor(x / self.block_m), math.floor(y / self.block_m)
            return self._block_split(bx, by)
        for name, boxes in self.areas.items():
            if any(x0 <= x <= x1 and y0 <= y <= y1 for x0, y0, x1, y1 in boxes):
                return name
        return TRAIN

    def assign(self, x: float, y: float) -> str:
        """The split of a sample whose rover stands at map point (x, y): home or ``buffer``."""
        own = self.home(x, y)
        zone = self.reach + self.buffer_m
        for name, box in self._held_out_near(x, y, zone):
            if name != own and _box_distance(x, y, box) <= zone:
                return BUFFER
        return own

    def _held_out_near(
        self, x: float, y: float, zone: float
    ) -> list[tuple[str, tuple[float, float, float, float]]]:
        """Held-out regions (split, box) that may lie within ``zone`` of (x, y)."""
        if self.style == "cross-area":
            return [(n, b) for n, boxes in self.areas.items() if n != TRAIN for b in boxes]
        b = self.block_m
        x0, x1 = math.floor((x - zone) / b), math.floor((x + zone) / b)
        y0, y1 = math.floor((y - zone) / b), math.floor((y + zone) / b)
        out = []
        for bx in range(x0, x1 + 1):
            for by in range(y0, y1 + 1):
                name = self._block_split(bx, by)
                if name != TRAIN:
                    out.append((name, (bx * b, by * b, (bx + 1) * b, (by + 1) * b)))
        return out

    def _block_split(self, bx: int, by: int) -> str:
        return _block_split(bx, by, tuple(self.ratios.items()), self.seed)


class EmptySplitWarning(UserWarning):
    """A build left a split it configures empty (no train sample, or a held-out split with
    none): the dataset is usable but not what the config asks for."""


def empty_split_warnings(
    style: str,
    ratios: dict[str, float],
    areas: dict[str, Any],
    block_m: float,
    counts: dict[str, int],
) -> list[str]:
    """One sentence per configured split that holds no sample (``counts``: samples per split
    name), train first; one for them all when every sample is in the buffer; none when the
    dataset has no sample at all.

    Configured: ``train`` and, same-area, the ``ratios`` names with a positive ratio, or,
    cross-area, the ``areas`` names. Each sentence says where the samples went and what to
    change (``splits.block_m``, ``splits.areas``, ``splits.ratios``).
    """
    total = sum(counts.values())
    if total == 0:
        return []
    named = [n for n, r in ratios.items() if r > 0] if style == "same-area" else list(areas)
    wanted = sorted({*named, TRAIN}, key=lambda n: (n != TRAIN, n))
    held = ", ".join(f"{n} {c}" for n, c in sorted(counts.items()) if c)
    blocks = f"splits.block_m = {block_m:g} map units"
    empty = [n for n in wanted if not counts.get(n, 0)]
    if empty and counts.get(BUFFER, 0) == total:
        where = (
            f"use regions several times wider than the zone (reach_m + buffer_m in "
            f"dataset.json; {blocks})"
            if style == "same-area"
            else "move splits.areas or lower splits.buffer_m"
        )
        names = ", ".join(repr(n) for n in empty)
        return [
            f"split {names} {'is' if len(empty) == 1 else 'are'} empty ({total} samples: "
            f"{held}); every sample is in the buffer zone around held-out regions: {where}"
        ]
    out = []
    for name in empty:
        if style == "same-area" and name == TRAIN:
            fix = (
                f"every rover position fell in held-out blocks or their buffer ({blocks}, "
                "blocks drawn by splits.ratios): use smaller blocks (several per traverse), "
                "another splits.seed, or style cross-area"
            )
        elif style == "same-area":
            fix = (
                f"no rover position fell in a {name} block ({blocks}, blocks drawn by "
                "splits.ratios): use smaller blocks or another splits.seed"
            )
        elif name == TRAIN:
            fix = "every rover position is in a held-out area or its buffer: shrink splits.areas"
        else:
            fix = f"no rover position lies inside splits.areas.{name}"
        out.append(f"split {name!r} is empty ({total} samples: {held}); {fix}")
    return out


def _box_distance(x: float, y: float, box: tuple[float, float, float, float]) -> float:
    """Euclidean distance (map units) from a point to an axis-aligned box (0 inside)."""
    x0, y0, x1, y1 = box
    return math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))


def block_ids(x: ArrayLike, y: ArrayLike, block_m: float) -> NDArray[np.int64]:
    """Block index pairs (N, 2): floor(x / block_m), floor(y / block_m)."""
    xs = np.floor(np.asarray(x, dtype=np.float64) / block_m).astype(np.int64)
    ys = np.floor(np.asarray(y, dtype=np.float64) / block_m).astype(np.int64)
    return np.stack([xs, ys], axis=-1)


def _unit_hash(bx: int, by: int, seed: int) -> float:
    digest = hashlib.blake2b(f"{seed}:{bx}:{by}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") / 2.0**64


@lru_cache(maxsize=65536)
def _block_split(bx: int, by: int, ratios: tuple[tuple[str, float], ...], seed: int) -> str:
    names = [n for n, _ in ratios]
    edges = np.cumsum([r for _, r in ratios])
    u = _unit_hash(bx, by, seed)
    return names[min(int(np.searchsorted(edges, u, side="right")), len(names) - 1)]


def assign_splits(
    x: ArrayLike, y: ArrayLike, block_m: float, ratios: dict[str, float], seed: int = 0
) -> list[str]:
    """The block split of each position (no buffer): every block goes whole into one split.

    Deterministic and independent of the other positions, so adding data never moves a
    block from one split to another.
    """
    rule = SplitRule(block_m=block_m, ratios=dict(ratios), seed=seed)
    xs, ys = np.atleast_1d(x), np.atleast_1d(y)
    return [rule.home(float(a), float(b)) for a, b in zip(xs, ys, strict=True)]


def make_rule(
    splits: Any, chip_size_m: float, radius_m: float, map_scale: float, cell_diagonal: float
) -> SplitRule:
    """The rule of a ``SplitsConfig`` for chips of ``chip_size_m`` and views of ``radius_m``.

    ``map_scale``: ``map_scale_bound`` of the DEM; ``cell_diagonal``: the DEM cell's (map
    units). The default buffer is the guard's reach, at least the chip size.
    """
    reach = chip_reach(chip_size_m)
    if splits.guard == "footprint":
        reach = max(reach, footprint_reach(radius_m, map_scale, cell_diagonal))
    buffer_m = splits.buffer_m
    if buffer_m is None:
        buffer_m = max(chip_size_m, math.ceil(reach))
    zone = reach + buffer_m
    if splits.style == "same-area" and (2 * zone / splits.block_m + 2) ** 2 > MAX_BLOCKS:
        raise ConfigError(
            f"splits.block_m: blocks of {splits.block_m:g} m are far smaller than the buffer "
            f"zone (reach {reach:.0f} + buffer_m {buffer_m:g}): every train sample would be "
            "in the buffer; use blocks of several times the zone, or style cross-area"
        )
    return SplitRule(
        style=splits.style,
        block_m=splits.block_m,
        ratios=dict(splits.ratios),
        seed=splits.seed,
        areas=dict(splits.areas),
        reach=reach,
        buffer_m=float(buffer_m),
    )


# -- reach: how far a sample's extent goes from its rover ---------------------------------------


def chip_reach(size_m: float) -> float:
    """Farthest point of a chip from its centre at any rotation: the circumscribed circle."""
    return size_m / math.sqrt(2.0)


def footprint_reach(radius_m: float, map_scale: float, cell_diagonal: float) -> float:
    """Farthest point of a footprint from its rover (map units).

    The footprint is the hull of the visible cells' corners (within ``radius_m`` of the camera
    centre, true metres) and the camera centre: ``radius_m`` times the largest map scale (map
    units per metre, at least 1, so a degree-unit CRS only widens it), a cell diagonal for the
    corners and ``MAST_REACH_M`` for the camera centre's offset from the rover origin.
    """
    return radius_m * max(map_scale, 1.0) + cell_diagonal + MAST_REACH_M


@lru_cache(maxsize=16)
def map_scale_bound(crs_wkt: str, bounds: tuple[float, float, float, float]) -> float:
    """The largest linear scale (map units per true metre, any direction) over ``bounds``.

    pyproj's Tissot semi-major axis on a 9 x 9 grid of the (W, S, E, N) box, plus 0.1 %;
    1.0 for a CRS that is not projected (the reach is then clamped, see ``footprint_reach``).
    """
    from pyproj import CRS, Proj, Transformer

    crs = CRS.from_user_input(crs_wkt)
    if not crs.is_projected:
        return 1.0
    w, s, e, n = bounds
    gx, gy = np.meshgrid(np.linspace(w, e, 9), np.linspace(s, n, 9))
    to_geo = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    lon, lat = to_geo.transform(gx.ravel(), gy.ravel())
    factors = Proj(crs).get_factors(lon, lat)
    return float(np.nanmax(factors.tissot_semimajor)) * 1.001


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
    # the bits in Python ints, point by point: the callers index one position at a time,
    # where numpy's per-call cost over 16 levels made one point 0.5 ms (Python ints: 10 us)
    pairs = zip(xi.ravel().tolist(), yi.ravel().tolist(), strict=True)
    return np.array([_hilbert_d(a, b, n) for a, b in pairs], dtype=np.int64).reshape(xi.shape)


def _hilbert_d(xi: int, yi: int, n: int) -> int:
    """Hilbert index of grid cell (xi, yi) on an n x n grid (n a power of 2)."""
    d = 0
    s = n >> 1
    while s > 0:
        rx = 1 if xi & s else 0
        ry = 1 if yi & s else 0
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:  # rotate the quadrant
            if rx == 1:
                xi, yi = s - 1 - xi, s - 1 - yi
            xi, yi = yi, xi
        s >>= 1
    return d
