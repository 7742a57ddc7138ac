"""Torch datasets over a built dataset: map-style and streaming datasets, collate, transport."""

from mars_pairs.torch.collate import collate_samples
from mars_pairs.torch.datasets import MarsPairsDataset, MarsPairsIterableDataset
from mars_pairs.torch.decode import ALL_FIELDS, DEFAULT_FIELDS, decode_member

__all__ = [
    "ALL_FIELDS",
    "DEFAULT_FIELDS",
    "MarsPairsDataset",
    "MarsPairsIterableDataset",
    "collate_samples",
    "decode_member",
]
