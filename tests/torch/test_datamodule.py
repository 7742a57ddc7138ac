"""The spatial batch sampler (close samples, footprints disjoint) and the Lightning
DataModule (train/val/test from the splits; one epoch of a tiny model trains)."""

from __future__ import annotations

import itertools
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely
import torch

from mars_pairs.errors import ArgumentError
from mars_pairs.torch import MarsPairsDataset, SpatialBatchSampler


def squares(centres: list[tuple[float, float]], half: float) -> list[shapely.Polygon]:
    return [shapely.box(x - half, y - half, x + half, y + half) for x, y in centres]


def test_batches_are_close_and_their_footprints_disjoint() -> None:
    # 60 samples on a line, 10 m apart; footprints 12 m wide: neighbours overlap, the next
    # but one do not
    centres = [(10.0 * i, 0.0) for i in range(60)]
    feet = squares(centres, 6.0)
    sampler = SpatialBatchSampler(positions=np.array(centres), footprints=feet, batch_size=4)
    batches = list(sampler)
    counts = Counter(itertools.chain.from_iterable(batches))
    assert sorted(counts) == list(range(60)) and set(counts.values()) == {1}
    assert len(sampler) == len(batches)
    spans = []
    for batch in batches:
        for a, b in itertools.combinations(batch, 2):
            assert not feet[a].intersects(feet[b]), (a, b)  # independent of the sampler's tree
        if len(batch) == 4:
            spans.append(10.0 * (max(batch) - min(batch)))
    # full batches: four samples two steps apart span 60 m, where random ones span ~360 m
    assert np.median(spans) <= 80.0 and len(spans) >= 10
    # the same seed and epoch give the same batches; another epoch others
    again = SpatialBatchSampler(positions=np.array(centres), footprints=feet, batch_size=4)
    assert list(again) == batches
    again.set_epoch(1)
    assert list(again) != batches
    # a distance bound: nothing farther than it shares a batch
    bounded = SpatialBatchSampler(
        positions=np.array(centres), footprints=feet, batch_size=4, max_distance_m=25.0
    )
    for batch in bounded:
        assert 10.0 * (max(batch) - min(batch)) <= 50.0


def test_the_sampler_reads_the_manifest_footprints(dataset_dir: Path) -> None:
    table = pq.read_table(dataset_dir / "manifest.parquet").to_pylist()
    feet = {r["key"]: shapely.from_wkb(r["footprint"]) for r in table}
    with MarsPairsDataset(dataset_dir, fields=("ortho",)) as ds:
        sampler = SpatialBatchSampler(ds, batch_size=3)
        keys = ds._index.column("key").to_pylist()
        seen = []
        for batch in sampler:
            for a, b in itertools.combinations(batch, 2):
                assert not feet[keys[a]].intersects(feet[keys[b]])
            seen += batch
        assert sorted(seen) == list(range(len(ds)))
        loader = torch.utils.data.DataLoader(ds, batch_sampler=sampler)
        assert sum(len(b["ortho"]) for b in loader) == len(ds)


lightning = pytest.importorskip("lightning")


def largest_split(root: Path) -> str:
    """The split holding most rows (this small fixture lands its samples in few splits)."""
    splits = pq.read_table(root / "manifest.parquet", columns=["split"])["split"].to_pylist()
    return Counter(splits).most_common(1)[0][0]


def test_the_datamodule_reads_one_split_per_stage(dataset_dir: Path) -> None:
    from mars_pairs.torch import MarsPairsDataModule

    split_of = {r["key"]: r["split"] for r in pq.read_table(dataset_dir / "manifest.parquet")
                .select(["key", "split"]).to_pylist()}  # fmt: skip
    # the default stages read the splits of their names; a mapping may point them elsewhere
    assert MarsPairsDataModule(dataset_dir).splits == {"train": "train", "val": "val",
                                                        "test": "test"}  # fmt: skip
    names = sorted(set(split_of.values()))
    chosen = {"train": largest_split(dataset_dir), "val": names[0], "test": names[-1]}
    dm = MarsPairsDataModule(dataset_dir, batch_size=2, fields=("ortho",), splits=chosen)
    dm.setup()
    for stage, split in chosen.items():
        ds = dm.datasets[stage]
        assert {split_of[k] for k in ds._index.column("key").to_pylist()} == {split}
        assert len(ds) == sum(s == split for s in split_of.values())
    with pytest.raises(ArgumentError, match="one split per stage"):
        MarsPairsDataModule(dataset_dir, split="train")
    loaders = {"train": dm.train_dataloader(), "val": dm.val_dataloader()}
    assert sum(len(b["ortho"]) for b in loaders["train"]) == len(dm.datasets["train"])
    assert dm.datasets["train"].options.fields == ("ortho",)


class Tiny(lightning.pytorch.LightningModule):
    """Ground and ortho embeddings matched by an InfoNCE loss over the batch."""

    def __init__(self) -> None:
        super().__init__()
        self.ground = torch.nn.Linear(3 * 8 * 8, 4)
        self.ortho = torch.nn.Linear(8 * 8, 4)
        self.losses: list[float] = []

    def _loss(self, batch: dict) -> torch.Tensor:
        pool = torch.nn.functional.adaptive_avg_pool2d
        g = self.ground(pool(batch["ground"].float() / 255, 8).flatten(1))
        o = self.ortho(pool(batch["ortho"].float() / 255, 8).flatten(1))
        logits = torch.nn.functional.normalize(g, dim=1) @ torch.nn.functional.normalize(o, dim=1).T
        return torch.nn.functional.cross_entropy(logits / 0.1, torch.arange(len(g)))

    def training_step(self, batch: dict, index: int) -> torch.Tensor:
        loss = self._loss(batch)
        self.losses.append(float(loss))
        return loss

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_a_lightning_trainer_fits_one_epoch(dataset_dir: Path) -> None:
    from mars_pairs.torch import MarsPairsDataModule

    def fit() -> tuple[int, list[float]]:
        lightning.seed_everything(0, verbose=False)
        dm = MarsPairsDataModule(
            dataset_dir, batch_size=3, hard_negatives=True, fields=("ground", "ortho"),
            splits={"train": largest_split(dataset_dir)},
        )  # fmt: skip
        trainer = lightning.Trainer(
            max_epochs=1, accelerator="cpu", devices=1, deterministic=True, logger=False,
            enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
            limit_val_batches=0,
        )  # fmt: skip
        model = Tiny()
        trainer.fit(model, datamodule=dm)
        assert trainer.state.finished and trainer.current_epoch == 1
        return trainer.global_step, model.losses

    steps, losses = fit()
    with MarsPairsDataset(
        dataset_dir, fields=("ortho",), split=largest_split(dataset_dir)
    ) as train:
        expected = len(SpatialBatchSampler(train, batch_size=3))
    assert steps == expected >= 1 and len(losses) == steps
    assert all(np.isfinite(losses))
    assert fit() == (steps, losses)  # deterministic
