"""Batches of spatially close samples whose views do not overlap: hard negatives.

For contrastive training (a ground image against its ortho chip, the other chips of the
batch the negatives) random batches mix far-apart places that are easy to tell apart.
:class:`SpatialBatchSampler` fills each batch with the nearest samples (by rover position,
map metres) to a random seed sample whose viewshed footprints (the manifest's ``footprint``
polygons, map coordinates) do not intersect any footprint already in the batch, so no two
samples of a batch show the same ground. Footprint intersections are found once with
shapely's STRtree; the nearest samples with scipy's cKDTree (the ``lightning`` extra).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import shapely
from torch.utils.data import Sampler

from mars_pairs.errors import ArgumentError
from mars_pairs.store.query import Manifest


def footprints_of(dataset: Any) -> tuple[np.ndarray, np.ndarray]:
    """(rover positions float64 [N, 2] map x, y; footprints, shapely polygons [N]) of a
    :class:`~mars_pairs.torch.MarsPairsDataset`'s samples, in its index order (read from the
    manifest with the dataset's filters; an absent footprint is an empty polygon)."""
    manifest = Manifest.open(dataset.root).filter(**dataset.filters)
    manifest.require(["key", "easting", "northing", "footprint"])
    table = manifest.to_table(columns=["key", "easting", "northing", "footprint"])
    row_of = {k: i for i, k in enumerate(table["key"].to_pylist())}
    order = np.array([row_of[k] for k in dataset._index.column("key").to_pylist()], np.int64)
    xy = np.column_stack(
        [table[c].fill_null(np.nan).to_numpy().astype(np.float64) for c in ("easting", "northing")]
    )[order]
    wkb = table["footprint"].to_pylist()
    shapes = np.array(
        [shapely.from_wkb(wkb[i]) if wkb[i] else shapely.Polygon() for i in order], dtype=object
    )
    return xy.reshape(len(order), 2), shapes


class SpatialBatchSampler(Sampler[list[int]]):
    """A batch sampler (``DataLoader(ds, batch_sampler=...)``) of spatially close samples
    whose footprints do not intersect.

    Each epoch visits the samples in a random order (``seed`` + epoch, see
    :meth:`set_epoch`); every sample not yet used opens a batch, filled with the nearest
    unused samples (rover distance, map metres; within ``max_distance_m`` if given) whose
    footprint intersects no footprint of the batch. Every sample is in exactly one batch
    per epoch; a batch is smaller than ``batch_size`` when too few such samples remain
    (``drop_last`` drops those). ``dataset``: a :class:`~mars_pairs.torch.MarsPairsDataset`
    (or anything with ``root``, ``filters`` and the same index); ``positions`` and
    ``footprints`` (map coordinates) may be given instead.
    """

    def __init__(
        self,
        dataset: Any = None,
        batch_size: int = 8,
        *,
        max_distance_m: float | None = None,
        seed: int = 0,
        drop_last: bool = False,
        positions: np.ndarray | None = None,
        footprints: Any = None,
    ) -> None:
        if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
            raise ArgumentError(f"batch_size: expected a positive int, got {batch_size!r}")
        if max_distance_m is not None and not (max_distance_m > 0 and np.isfinite(max_distance_m)):
            raise ArgumentError(
                f"max_distance_m: expected a positive distance, got {max_distance_m!r}"
            )
        if positions is None or footprints is None:
            if dataset is None:
                raise ArgumentError(
                    "SpatialBatchSampler: give a dataset, or positions and footprints"
                )
            positions, footprints = footprints_of(dataset)
        self.positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        self.footprints = np.asarray(footprints, dtype=object)
        if len(self.footprints) != len(self.positions):
            raise ArgumentError("positions and footprints: one of each per sample")
        self.batch_size = batch_size
        self.max_distance_m = max_distance_m
        self.seed = int(seed)
        self.drop_last = bool(drop_last)
        self.epoch = 0
        self.overlaps = self._overlaps()
        try:
            from scipy.spatial import cKDTree
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise ArgumentError(
                "SpatialBatchSampler needs scipy: pip install 'mars-pairs[lightning]'"
            ) from exc
        finite = np.where(np.isfinite(self.positions), self.positions, 0.0)
        self._tree = cKDTree(finite)
        self._cache: tuple[int, list[list[int]]] | None = None

    def _overlaps(self) -> list[set[int]]:
        """For each sample, the other samples whose footprints intersect its own."""
        n = len(self.footprints)
        out: list[set[int]] = [set() for _ in range(n)]
        if n == 0:
            return out
        tree = shapely.STRtree(self.footprints)
        left, right = tree.query(self.footprints, predicate="intersects")
        for a, b in zip(left.tolist(), right.tolist(), strict=True):
            if a != b:
                out[a].add(b)
        return out

    def set_epoch(self, epoch: int) -> None:
        """Draw the next epoch's batches from ``seed`` + ``epoch``."""
        self.epoch = int(epoch)

    def batches(self) -> list[list[int]]:
        """This epoch's batches (sample indices), computed once per epoch."""
        if self._cache is not None and self._cache[0] == self.epoch:
            return self._cache[1]
        n = len(self.positions)
        rng = np.random.default_rng(self.seed + self.epoch)
        used = np.zeros(n, dtype=bool)
        out: list[list[int]] = []
        bound = np.inf if self.max_distance_m is None else self.max_distance_m
        for start in rng.permutation(n).tolist():
            if used[start]:
                continue
            batch, blocked = [start], set(self.overlaps[start])
            used[start] = True
            k = min(n, 4 * self.batch_size)
            while len(batch) < self.batch_size:
                dist, near = self._tree.query(
                    self.positions[start], k=k, distance_upper_bound=bound
                )
                near = np.atleast_1d(near)[np.isfinite(np.atleast_1d(dist))]
                for c in near.tolist():
                    if len(batch) == self.batch_size:
                        break
                    if not used[c] and c not in blocked:
                        batch.append(c)
                        used[c] = True
                        blocked |= self.overlaps[c]
                if k >= n or len(near) < k:
                    break  # every sample in reach was looked at
                k = min(n, 4 * k)
            if len(batch) == self.batch_size or not self.drop_last:
                out.append(sorted(batch))
        self._cache = (self.epoch, out)
        return out

    def __iter__(self) -> Iterator[list[int]]:
        yield from self.batches()

    def __len__(self) -> int:
        return len(self.batches())
