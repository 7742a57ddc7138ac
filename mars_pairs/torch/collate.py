"""Batching samples: tensors stacked (or handed on as the buffer they view), meta as lists."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch.utils.data import default_collate

from mars_pairs.torch.lazy_float import Uint8AsFloat32
from mars_pairs.torch.transport import stacked_base


def collate_samples(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Stack tensors of a batch; ``meta`` becomes a dict of lists.

    Rows of one batch buffer (from ``MarsPairsDataset.__getitems__``) are returned as that
    buffer, without a copy; other tensors are stacked with ``default_collate``, which in a
    DataLoader worker writes the batch straight into shared memory. Lazy float32 image rows
    of one uint8 buffer (a worker's batch) stay lazy: they cross to the main process as
    uint8 and arrive as float32.
    """
    out: dict[str, Any] = {}
    for key in batch[0]:
        if key == "meta":
            out["meta"] = {k: [b["meta"][k] for b in batch] for k in batch[0]["meta"]}
        elif isinstance(batch[0][key], torch.Tensor):
            out[key] = _collate_tensors([b[key] for b in batch])
        else:
            out[key] = [b[key] for b in batch]
    return out


def _collate_tensors(tensors: list[torch.Tensor]) -> torch.Tensor:
    """One field's [B, ...] batch: the buffer the rows view (no copy), else a stack (into
    shared memory inside a worker). Unused lazy rows stay lazy: the batch is their uint8
    buffer, or their uint8 rows stacked."""
    lazy = [t for t in tensors if isinstance(t, Uint8AsFloat32) and not t.materialized]
    if len(lazy) == len(tensors) and len({(t.divisor, t.shape) for t in lazy}) == 1:
        base = stacked_base([t.uint8 for t in lazy])
        pooled = base is not None and all(t.pooled for t in lazy)
        if base is None:
            base = default_collate([t.uint8 for t in lazy])
        return Uint8AsFloat32(base, lazy[0].divisor, pooled=pooled).stacked_from(lazy)
    base = stacked_base(tensors)
    return base if base is not None else default_collate(tensors)
