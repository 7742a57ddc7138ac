"""The streaming dataset: shard by shard through a shuffle buffer, across ranks and workers."""

from __future__ import annotations

import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import IterableDataset, get_worker_info

from mars_pairs.torch.datasets import MarsPairsDataset, describe_dataset
from mars_pairs.torch.options import DatasetOptions


def _world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class MarsPairsIterableDataset(IterableDataset[dict[str, Any]]):
    """Streams samples shard by shard through a shuffle buffer.

    Shards are split across distributed ranks and DataLoader workers (every shard goes to
    exactly one (rank, worker)); within a shard members are read in file order. Call
    ``set_epoch`` to reshuffle between epochs. A context manager, like the map-style one.
    Takes the map-style dataset's options and filters (:class:`MarsPairsDataset`), and
    ``shuffle_buffer`` (samples held for shuffling) and ``seed``.
    """

    def __init__(
        self,
        root: str | Path,
        options: DatasetOptions | None = None,
        *,
        shuffle_buffer: int = 64,
        seed: int = 0,
        **kwargs: Any,
    ) -> None:
        self._inner = MarsPairsDataset(root, options, **kwargs)
        self.options = self._inner.options
        self.shuffle_buffer = int(shuffle_buffer)
        self.seed = int(seed)
        self.epoch = 0
        self._by_shard = self._inner.shard_order()
        self.shards = sorted(self._by_shard)

    def close(self) -> None:
        """Close the shard files this process opened."""
        self._inner.close()

    def __enter__(self) -> MarsPairsIterableDataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def plot(self, sample: dict[str, Any], **kwargs: Any) -> Any:
        """A matplotlib Figure of one sample or of a batch (see :meth:`MarsPairsDataset.plot`,
        whose keyword arguments it takes)."""
        return self._inner.plot(sample, **kwargs)

    def set_epoch(self, epoch: int) -> None:
        """Reseed the shard order and shuffle buffer."""
        self.epoch = int(epoch)

    def my_shards(self) -> list[str]:
        """The shards this (rank, worker) streams."""
        rank, world = _world()
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        order = list(self.shards)
        random.Random(self.seed + self.epoch).shuffle(order)
        slot, slots = rank * workers + worker, world * workers
        return order[slot::slots]

    def __iter__(self) -> Iterator[dict[str, Any]]:
        mine = self.my_shards()
        rng = random.Random(f"{self.seed}:{self.epoch}:{','.join(mine)}")
        buffer: list[dict[str, Any]] = []
        for shard in mine:
            for index in self._by_shard[shard]:
                buffer.append(self._inner[int(index)])
                if len(buffer) >= max(self.shuffle_buffer, 1):
                    yield buffer.pop(rng.randrange(len(buffer)))
        rng.shuffle(buffer)
        yield from buffer

    def __len__(self) -> int:
        return len(self._inner)

    def __repr__(self) -> str:
        lines = describe_dataset(self._inner, type(self).__name__)
        lines.insert(3, f"    shards: {len(self.shards)}, shuffle buffer {self.shuffle_buffer}, "
                        f"seed {self.seed}, epoch {self.epoch}")  # fmt: skip
        return "\n".join(lines)
