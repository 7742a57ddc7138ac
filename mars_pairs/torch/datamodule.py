"""A Lightning DataModule over a built dataset: train, val and test from its splits.

Needs the ``lightning`` extra (``pip install 'mars-pairs[lightning]'``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lightning.pytorch import LightningDataModule

from mars_pairs.errors import ArgumentError
from mars_pairs.torch.datasets import MarsPairsDataset
from mars_pairs.torch.loader import MarsPairsLoader
from mars_pairs.torch.options import DatasetOptions
from mars_pairs.torch.sampler import SpatialBatchSampler


class MarsPairsDataModule(LightningDataModule):
    """Train, val and test loaders of a built dataset, one per split (``splits``: the split
    names of each stage, default ``train``, ``val``, ``test``; the buffer split is never
    read). Every stage's dataset takes ``options`` (:class:`DatasetOptions`, or its fields
    as keyword arguments) and the other keyword arguments as filters.

    ``hard_negatives``: the training batches come from a :class:`SpatialBatchSampler`
    (spatially close samples whose footprints do not intersect; ``max_distance_m``), else
    they are shuffled with ``seed``. Val and test batches are in dataset order. Loaders are
    :class:`MarsPairsLoader` (a ``DataLoader``) with ``num_workers`` workers.
    """

    def __init__(
        self,
        root: str | Path,
        options: DatasetOptions | None = None,
        *,
        batch_size: int = 8,
        num_workers: int = 0,
        hard_negatives: bool = False,
        max_distance_m: float | None = None,
        seed: int = 0,
        splits: dict[str, str] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__()
        self.root = root
        self.options, self.filters = DatasetOptions.split(options, kwargs)
        if "split" in self.filters:
            raise ArgumentError("split: the DataModule reads one split per stage (see splits=)")
        self.splits = {"train": "train", "val": "val", "test": "test", **(splits or {})}
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.hard_negatives = bool(hard_negatives)
        self.max_distance_m = max_distance_m
        self.seed = int(seed)
        self.datasets: dict[str, MarsPairsDataset] = {}

    def _dataset(self, stage: str) -> MarsPairsDataset:
        if stage not in self.datasets:
            self.datasets[stage] = MarsPairsDataset(
                self.root, self.options, split=self.splits[stage], **self.filters
            )
        return self.datasets[stage]

    def setup(self, stage: str | None = None) -> None:
        """Open the datasets of ``stage`` (fit: train and val; validate; test; predict: test)."""
        wanted = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": ("test",),
            "predict": ("test",),
            None: ("train", "val", "test"),
        }.get(stage, ())
        for name in wanted:
            self._dataset(name)

    def train_dataloader(self) -> MarsPairsLoader:
        ds = self._dataset("train")
        if self.hard_negatives:
            sampler = SpatialBatchSampler(
                ds, self.batch_size, max_distance_m=self.max_distance_m, seed=self.seed
            )
            return MarsPairsLoader(
                ds, batch_size=1, batch_sampler=sampler, num_workers=self.num_workers
            )
        import torch

        return MarsPairsLoader(
            ds,
            batch_size=self.batch_size,
            shuffle=True,
            num_workers=self.num_workers,
            generator=torch.Generator().manual_seed(self.seed),
        )

    def val_dataloader(self) -> MarsPairsLoader:
        return MarsPairsLoader(
            self._dataset("val"), batch_size=self.batch_size, num_workers=self.num_workers
        )

    def test_dataloader(self) -> MarsPairsLoader:
        return MarsPairsLoader(
            self._dataset("test"), batch_size=self.batch_size, num_workers=self.num_workers
        )

    def teardown(self, stage: str | None = None) -> None:
        for ds in self.datasets.values():
            ds.close()

    def __repr__(self) -> str:
        opened = ", ".join(f"{k} {len(v)}" for k, v in self.datasets.items()) or "not set up"
        return (
            f"{type(self).__name__}(root={str(self.root)!r}, batch_size={self.batch_size}, "
            f"hard_negatives={self.hard_negatives}, splits={self.splits}, rows: {opened})"
        )
