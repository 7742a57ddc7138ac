"""Torch datasets over a built dataset: map-style and streaming datasets, the loader, collate,
transforms."""

from mars_pairs.torch.collate import collate_samples, unbind_samples
from mars_pairs.torch.datasets import MarsPairsDataset
from mars_pairs.torch.decode import ALL_FIELDS, DEFAULT_FIELDS, decode_member
from mars_pairs.torch.loader import MarsPairsLoader
from mars_pairs.torch.options import DatasetOptions
from mars_pairs.torch.streaming import MarsPairsIterableDataset

__all__ = [
    "ALL_FIELDS",
    "DEFAULT_FIELDS",
    "DatasetOptions",
    "MarsPairsDataset",
    "MarsPairsIterableDataset",
    "MarsPairsLoader",
    "collate_samples",
    "decode_member",
    "unbind_samples",
]
