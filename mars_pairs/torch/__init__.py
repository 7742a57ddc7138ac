"""Torch datasets over a built dataset: map-style and streaming datasets, the loader, collate,
transforms."""

from typing import TYPE_CHECKING, Any

from mars_pairs.torch.collate import MISSING_INT, collate_samples, unbind_samples
from mars_pairs.torch.datasets import MarsPairsDataset
from mars_pairs.torch.decode import ALL_FIELDS, DEFAULT_FIELDS, decode_member
from mars_pairs.torch.loader import MarsPairsLoader
from mars_pairs.torch.options import DatasetOptions
from mars_pairs.torch.sampler import SpatialBatchSampler
from mars_pairs.torch.streaming import MarsPairsIterableDataset

if TYPE_CHECKING:
    from mars_pairs.torch.datamodule import MarsPairsDataModule

__all__ = [
    "ALL_FIELDS",
    "DEFAULT_FIELDS",
    "MISSING_INT",
    "DatasetOptions",
    "MarsPairsDataModule",
    "MarsPairsDataset",
    "MarsPairsIterableDataset",
    "MarsPairsLoader",
    "SpatialBatchSampler",
    "collate_samples",
    "decode_member",
    "unbind_samples",
]


def __getattr__(name: str) -> Any:
    """``MarsPairsDataModule`` on first use (it imports lightning, the ``lightning`` extra)."""
    if name == "MarsPairsDataModule":
        try:
            from mars_pairs.torch.datamodule import MarsPairsDataModule
        except ImportError as exc:
            from mars_pairs.errors import MarsPairsError

            raise MarsPairsError(
                f"MarsPairsDataModule needs lightning: pip install 'mars-pairs[lightning]' ({exc})"
            ) from exc
        return MarsPairsDataModule
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
