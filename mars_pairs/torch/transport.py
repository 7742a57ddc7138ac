"""Tensors for DataLoader worker transport: shared memory, batch buffers, recycled slots.

A batch leaves a DataLoader worker through shared memory. Creating and filling fresh shared
memory costs about 20 times as much per byte as refilling a buffer already mapped (figures in
the README's loader benchmark). :class:`BatchSlots` lets a worker refill the same shared
buffers: the main process copies a received batch out into reused memory
(:class:`WarmBuffers`) and marks its slot free in a small shared uint8 flag array
(:class:`~mars_pairs.torch.loader.MarsPairsLoader` does both). This module uses public torch
API only (``Tensor.share_memory_``, ``untyped_storage``, ``set_``, ``numpy``/``from_numpy``);
the DataLoader carries the shared tensors across with its own pickling. Sizes are bytes,
shapes torch's (rows first).
"""

from __future__ import annotations

import weakref
from collections.abc import Mapping, Sequence

import numpy as np
import torch

#: slot states in the shared flag array (uint8): the worker lends, the main process frees
LENT, FREE = 0, 1

#: a batch layout: field -> (shape, dtype) of its stacked tensor
Layout = Mapping[str, tuple[tuple[int, ...], torch.dtype]]


def shared_empty(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """A tensor in shared memory (sent from a DataLoader worker without a copy)."""
    out: torch.Tensor = torch.empty(shape, dtype=dtype).share_memory_()
    return out


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
    size = (len(tensors), *first.shape)
    # torch's stub wants a stride; set_ without one lays the tensor out contiguously (its doc)
    out: torch.Tensor = torch.empty(0, dtype=first.dtype).set_(storage, start, size)  # type: ignore[call-overload]  # stride optional
    return out


class BatchSlots:
    """One DataLoader worker's reusable shared-memory batch buffers.

    A slot is one shared uint8 block holding every field of a batch at 64-byte aligned
    offsets (one block crosses to the main process, not a storage per field). ``flags`` is
    this worker's row of a shared uint8 array, one entry per slot: the worker sets LENT when
    it sends a slot, the main process sets FREE once it has copied it out. A slot whose batch
    never came back (an exception, an epoch cut short) is reclaimed when a batch this worker
    lent after it is freed: the main process receives a worker's batches in the order the
    worker sent them. With no slot free, :meth:`take` returns None and the batch goes the
    plain DataLoader way (new shared memory).

    The flags are plain loads and stores, no fence: on x86 (total store order) the main
    process's FREE is seen only after its copy's reads; on weakly ordered CPUs (aarch64) the
    copy ends long before the worker next looks (it does so when it starts another batch).
    """

    def __init__(self, flags: torch.Tensor) -> None:
        self._flags = flags.numpy()  # a view of the shared array
        n = len(self._flags)
        self._blocks: list[SlotBlock | None] = [None] * n
        self._lent_seq = [0] * n
        self._seq = 0
        self.allocations = 0  # blocks allocated, for tests and benchmarks

    def take(self, layout: Layout) -> tuple[int, SlotBlock] | None:
        """A free slot's index and block, laid out for ``layout``; None if none is free."""
        self._reclaim()
        free = [s for s, b in enumerate(self._blocks) if b is None or self._flags[s] == FREE]
        if not free:
            return None
        same = [s for s in free if (b := self._blocks[s]) is not None and b.fits(layout)]
        unused = [s for s in free if self._blocks[s] is None]
        slot = (same or unused or free)[0]
        block = self._blocks[slot]
        if slot not in same or block is None:  # (a slot in ``same`` has a block)
            block = self._blocks[slot] = SlotBlock.allocate(layout)
            self.allocations += 1
        self._seq += 1
        self._lent_seq[slot] = self._seq
        self._flags[slot] = LENT
        return slot, block

    def _reclaim(self) -> None:
        freed = [
            self._lent_seq[s]
            for s, b in enumerate(self._blocks)
            if b is not None and self._flags[s] == FREE
        ]
        newest = max(freed, default=0)
        for s, b in enumerate(self._blocks):
            if b is not None and self._flags[s] == LENT and self._lent_seq[s] < newest:
                self._flags[s] = FREE  # its batch was lost before the main process got it


#: field -> (byte offset, shape, dtype) inside a slot block
BlockLayout = dict[str, tuple[int, tuple[int, ...], torch.dtype]]
_ALIGN = 64


class SlotBlock:
    """One shared uint8 block and typed views of its fields."""

    def __init__(self, block: torch.Tensor, layout: BlockLayout) -> None:
        self.block = block
        self.layout = layout
        self.views = block_views(block, layout)

    @classmethod
    def allocate(cls, layout: Layout) -> SlotBlock:
        placed: BlockLayout = {}
        size = 0
        for key, (shape, dtype) in layout.items():
            placed[key] = (size, tuple(shape), dtype)
            nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            size += -(-nbytes // _ALIGN) * _ALIGN
        return cls(shared_empty((max(size, 1),), torch.uint8), placed)

    def fits(self, layout: Layout) -> bool:
        """Whether the block holds exactly ``layout``'s fields."""
        mine = {k: (shape, dtype) for k, (_, shape, dtype) in self.layout.items()}
        return mine == {k: (tuple(shape), dtype) for k, (shape, dtype) in layout.items()}


def block_views(block: torch.Tensor, layout: BlockLayout) -> dict[str, torch.Tensor]:
    """The typed field tensors that ``layout`` places in a uint8 ``block`` (views)."""
    views = {}
    for key, (offset, shape, dtype) in layout.items():
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        views[key] = block[offset : offset + nbytes].view(dtype).view(shape)
    return views


class WarmBuffers:
    """Memory this process reuses for the batches it copies out of worker slots.

    A received batch is copied into a buffer from here; its tensors keep the buffer while
    any of them (or a view) lives, and the buffer comes back for a later batch when the last
    one is gone: a training loop that drops each batch refills the same pages instead of
    faulting in fresh ones; a caller who keeps batches only makes the cache allocate more.
    At most ``keep`` free buffers are kept.
    """

    def __init__(self, keep: int = 8) -> None:
        self.keep = keep
        self._free: list[np.ndarray] = []
        self.allocations = 0

    def copy(self, block: torch.Tensor) -> torch.Tensor:
        """A uint8 tensor equal to ``block`` (1-D, uint8) in a reused buffer."""
        n = block.numel()
        index = next((i for i, b in enumerate(self._free) if b.size == n), None)
        if index is None:
            raw = np.empty(n, dtype=np.uint8)
            self.allocations += 1
        else:  # (by position: list.remove would compare arrays element by element)
            raw = self._free.pop(index)
        lease = raw.view()  # a new array object: when it dies, every tensor of it is gone
        weakref.finalize(lease, self._give_back, raw)
        np.copyto(lease, block.numpy())
        return torch.from_numpy(lease)

    def _give_back(self, raw: np.ndarray) -> None:
        if len(self._free) < self.keep:
            self._free.append(raw)
