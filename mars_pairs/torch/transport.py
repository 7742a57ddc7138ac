"""Tensors for DataLoader worker transport: shared memory, batch buffers."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch


def shared_empty(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """A tensor in shared memory (sent from a DataLoader worker without a copy)."""
    numel = int(np.prod(shape))
    try:
        empty = torch.empty(0, dtype=dtype)
        storage = empty._typed_storage()._new_shared(numel)  # as default_collate does
        return empty.set_(storage).view(shape)
    except (AttributeError, RuntimeError):  # private API moved: share afterwards instead
        return torch.empty(shape, dtype=dtype).share_memory_()


def stacked_base(tensors: Sequence[torch.Tensor]) -> torch.Tensor | None:
    """The [B, ...] tensor whose rows are exactly ``tensors`` (consecutive views), or None."""
    first = tensors[0]
    storage = first.untyped_storage()
    n = first.numel()
    for j, t in enumerate(tensors):
        if (
            t.untyped_storage().data_ptr() != storage.data_ptr()
            or t.storage_offset() != first.storage_offset() + j * n
            or t.shape != first.shape
            or t.dtype != first.dtype
            or not t.is_contiguous()
        ):
            return None
    start = first.storage_offset()
    return torch.empty(0, dtype=first.dtype).set_(storage, start, (len(tensors), *first.shape))
