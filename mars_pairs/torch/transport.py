"""Tensors for DataLoader worker transport: shared-memory slots, handed over once, then leased.

A batch leaves a DataLoader worker through shared memory. Creating and filling fresh shared
memory costs about 20 times as much per byte as refilling a buffer already mapped, and
passing a shared storage to another process (a file descriptor through a socket) costs about
a millisecond (figures in docs/benchmarks.md). So each worker of a
:class:`~mars_pairs.torch.loader.MarsPairsLoader` keeps a few batch slots (:class:`BatchSlots`,
one shared uint8 block each) and refills them: ``MarsPairsDataset.__getitems__`` decodes
straight into the slot (:func:`batch_empty`), the collate stage puts the rest of the batch
after it, and the batch crosses to the main process as a :class:`SlotTicket` naming the slot
and its generation; the block itself crosses once, with the first batch of each generation
the main process has not acknowledged (:class:`SlotBoard`). The main process hands the batch
on as views of the slot (:func:`leased_views`): the slot is lent to the caller until every
tensor of the batch is gone, then given back to its worker.

Slot states live in a small shared uint8 array (LENT: sent by the worker; HELD: received by
the main process; FREE: given back), the main process's receipts and acknowledged
generations in a shared int64 array. This module uses public torch API only
(``Tensor.share_memory_``, ``untyped_storage``, ``set_``, ``numpy``/``from_numpy``); the
DataLoader carries the shared tensors across with its own pickling. Sizes are bytes, shapes
torch's (rows first).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

#: slot states in the shared flag array (uint8): the worker lends, the main process holds
#: a slot it has received and frees it when the caller's batch is gone
LENT, FREE, HELD = 0, 1, 2

#: a batch layout: field -> (shape, dtype) of its stacked tensor
Layout = Mapping[str, tuple[tuple[int, ...], torch.dtype]]

#: field -> (byte offset, shape, dtype) inside a slot block
BlockLayout = dict[str, tuple[int, tuple[int, ...], torch.dtype]]
_ALIGN = 64


def shared_empty(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """A tensor in shared memory (sent from a DataLoader worker without a copy)."""
    out: torch.Tensor = torch.empty(shape, dtype=dtype).share_memory_()
    return out


def aligned(nbytes: int) -> int:
    """``nbytes`` rounded up to the slot blocks' field alignment (64 bytes)."""
    return -(-nbytes // _ALIGN) * _ALIGN


def nbytes_of(shape: Sequence[int], dtype: torch.dtype) -> int:
    """The bytes of a contiguous tensor of ``shape`` and ``dtype``."""
    return int(np.prod(shape, dtype=np.int64)) * dtype.itemsize


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


def place(layout: Layout, start: int = 0) -> tuple[BlockLayout, int]:
    """``layout``'s fields placed one after the other from byte ``start`` (each at a 64-byte
    aligned offset), and the end of the last one."""
    placed: BlockLayout = {}
    end = start
    for key, (shape, dtype) in layout.items():
        placed[key] = (end, tuple(shape), dtype)
        end += aligned(nbytes_of(shape, dtype))
    return placed, end


@dataclass(frozen=True)
class SlotTicket:
    """What crosses to the main process with a batch sent through a slot: the slot's worker
    and index, its generation (which block), the worker's send sequence number, where each
    field lies in the block, and the block itself when the main process has not
    acknowledged this generation yet (else None: no file descriptor passed). Not a tensor nor
    a tuple, so a pin-memory thread hands it on untouched."""

    worker: int
    slot: int
    generation: int
    seq: int
    layout: BlockLayout
    allocations: int
    block: torch.Tensor | None = None


class SlotBoard:
    """The shared state of one loader iterator's slots, made by the main process.

    ``flags`` uint8 [workers, slots] (LENT / HELD / FREE); ``counters`` int64 [workers,
    1 + slots]: the send sequence number of the last batch the main process received from
    the worker, then the generation of each slot's block the main process holds. The main
    process keeps the blocks it has received (:meth:`receive`).
    """

    def __init__(self, workers: int, slots: int) -> None:
        self.flags = torch.full((workers, slots), FREE, dtype=torch.uint8).share_memory_()
        self.counters = torch.zeros((workers, 1 + slots), dtype=torch.int64).share_memory_()
        self._flags = self.flags.numpy()
        self._counters = self.counters.numpy()
        self._blocks: dict[tuple[int, int], tuple[int, torch.Tensor]] = {}

    def __getstate__(self) -> dict[str, torch.Tensor]:
        return {"flags": self.flags, "counters": self.counters}  # (to a worker: no blocks)

    def __setstate__(self, state: dict[str, torch.Tensor]) -> None:
        self.flags, self.counters = state["flags"], state["counters"]
        self._flags = self.flags.numpy()
        self._counters = self.counters.numpy()
        self._blocks = {}

    def worker_slots(self, worker: int) -> BatchSlots:
        """The worker-side slots of ``worker`` (called in the worker)."""
        return BatchSlots(self.flags[worker], self.counters[worker])

    def receive(self, ticket: SlotTicket) -> torch.Tensor:
        """The block of a received ticket's slot; marks the slot HELD, then records the
        receipt (in this order: a worker that sees the receipt sees the slot held) and
        acknowledges a block that came with the ticket."""
        w, s = ticket.worker, ticket.slot
        self._flags[w, s] = HELD
        self._counters[w, 0] = ticket.seq
        if ticket.block is not None:
            self._blocks[w, s] = (ticket.generation, ticket.block)
            self._counters[w, 1 + s] = ticket.generation
        held = self._blocks.get((w, s))
        if held is None or held[0] != ticket.generation:
            raise RuntimeError(
                f"worker {w} slot {s}: generation {ticket.generation} was never received"
            )
        return held[1]

    def release(self, worker: int, slot: int) -> None:
        """Give a held slot back to its worker."""
        self._flags[worker, slot] = FREE


class BatchSlots:
    """One DataLoader worker's reusable shared-memory batch buffers.

    A slot is one shared uint8 block holding every field of a batch at 64-byte aligned
    offsets. ``flags`` is this worker's row of the shared flag array, one entry per slot:
    the worker sets LENT when it sends a slot, the main process HELD when it receives it
    and FREE when it gives it back. ``counters`` (optional): this worker's row of
    :class:`SlotBoard`'s counters. A slot whose batch never reached the main process (an
    exception, an epoch cut short) is reclaimed once the main process has received a batch
    this worker sent after it: the main process receives a worker's batches in the order the
    worker sent them. With no slot free, :meth:`take` returns None and the batch goes the
    plain DataLoader way (new shared memory).

    A batch is made either by :meth:`take` (a slot laid out for a layout, the collate stage
    copies the batch in), or between :meth:`start` and :meth:`lend`: the dataset's buffers
    come from :meth:`alloc` inside the slot, the collate stage places the rest after them.

    The flags are plain loads and stores, no fence: on x86 (total store order) the main
    process's FREE is seen only after its reads of the batch; on weakly ordered CPUs
    (aarch64) those reads end long before the worker next looks (when it starts another
    batch).
    """

    def __init__(self, flags: torch.Tensor, counters: torch.Tensor | None = None) -> None:
        self._flags = flags.numpy()  # a view of the shared array
        self._counters = None if counters is None else counters.numpy()
        n = len(self._flags)
        self._blocks: list[SlotBlock | None] = [None] * n
        self._generation = [0] * n
        self._lent_seq = [0] * n
        self._seq = 0
        self.allocations = 0  # blocks allocated, for tests and benchmarks
        self.current: int | None = None  # the slot the batch being made writes into
        self.cursor = 0  # the bytes of the current slot's block in use

    def _free(self) -> list[int]:
        self._reclaim()
        return [s for s, b in enumerate(self._blocks) if b is None or self._flags[s] == FREE]

    def take(self, layout: Layout) -> tuple[int, SlotBlock] | None:
        """A free slot's index and block, laid out for ``layout``; None if none is free.
        The slot is marked LENT."""
        self.current = None
        free = self._free()
        if not free:
            return None
        same = [s for s in free if (b := self._blocks[s]) is not None and b.fits(layout)]
        unused = [s for s in free if self._blocks[s] is None]
        slot = (same or unused or free)[0]
        block = self._blocks[slot]
        if slot not in same or block is None:  # (a slot in ``same`` has a block)
            block = self._allocate(slot, layout)
        self._mark_lent(slot)
        return slot, block

    def start(self) -> None:
        """Begin a batch: the free slot with the largest block becomes current (an unused
        one if none has a block; none if no slot is free), its block empty. While a batch
        is being made (a current slot not yet lent: a dataset whose batch holds the batches
        of others, or one whose last batch failed) it goes on in the same slot, after what
        that slot holds."""
        if self.current is not None:
            return
        free = self._free()
        with_block = [s for s in free if self._blocks[s] is not None]
        if with_block:
            self.current = max(with_block, key=lambda s: self._capacity(s))
        else:
            self.current = free[0] if free else None
        self.cursor = 0

    def alloc(self, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray | None:
        """An uninitialised C-contiguous array in the current slot's block after what is in
        use, or None (no current slot, or no room)."""
        block = self._current_block()
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if block is None or self.cursor + nbytes > block.capacity:
            return None
        start = self.cursor
        self.cursor += aligned(nbytes)
        raw = block.block.numpy()[start : start + nbytes]
        return raw.view(dtype).reshape(shape)

    def offset_of(self, tensor: torch.Tensor) -> int | None:
        """The byte offset of a contiguous ``tensor`` lying inside the current slot's block
        (made by :meth:`alloc` for this batch), else None."""
        block = self._current_block()
        if block is None or not tensor.is_contiguous():
            return None
        offset = tensor.data_ptr() - block.block.data_ptr()
        end = offset + tensor.numel() * tensor.element_size()
        if offset < 0 or end > self.cursor:
            return None
        return offset

    def lend(
        self, placed: BlockLayout, missing: Layout
    ) -> tuple[int, SlotBlock, BlockLayout, bool] | None:
        """The slot a batch goes out in, once its fields ``placed`` already lie in the
        current slot: ``missing`` fields placed after them (or, when they do not fit, every
        field in a new, larger block of the current slot; a free slot's if there is no
        current one). Returns (slot, block, every field's placement, whether ``placed``
        fields must be copied: a new block) and marks the slot LENT; None if no slot is
        free."""
        slot = self.current
        self.current = None
        block = None if slot is None else self._blocks[slot]
        if slot is not None and block is not None:
            extra, end = place(missing, self.cursor)
            if end <= block.capacity:
                self._mark_lent(slot)
                return slot, block, {**placed, **extra}, False
        if slot is None:
            free = self._free()
            if not free:
                return None
            slot = free[0]
        layout = {k: (shape, dtype) for k, (_, shape, dtype) in placed.items()}
        block = self._allocate(slot, {**layout, **missing})
        self._mark_lent(slot)
        return slot, block, dict(block.layout), True

    def ticket(self, worker: int, slot: int, layout: BlockLayout) -> SlotTicket:
        """The ticket of a batch lent in ``slot``: the block travels with it unless the
        main process has acknowledged this generation."""
        generation = self._generation[slot]
        block = self._blocks[slot]
        known = self._counters is not None and int(self._counters[1 + slot]) == generation
        return SlotTicket(
            worker=worker,
            slot=slot,
            generation=generation,
            seq=self._lent_seq[slot],
            layout=layout,
            allocations=self.allocations,
            block=None if known or block is None else block.block,
        )

    def _current_block(self) -> SlotBlock | None:
        return None if self.current is None else self._blocks[self.current]

    def _capacity(self, slot: int) -> int:
        block = self._blocks[slot]
        return 0 if block is None else block.capacity

    def _allocate(self, slot: int, layout: Layout) -> SlotBlock:
        block = self._blocks[slot] = SlotBlock.allocate(layout)
        self._generation[slot] += 1
        self.allocations += 1
        return block

    def _mark_lent(self, slot: int) -> None:
        self._seq += 1
        self._lent_seq[slot] = self._seq
        self._flags[slot] = LENT

    def _reclaim(self) -> None:
        """Free the slots whose batches were lost on the way."""
        if self._counters is not None:
            received = int(self._counters[0])  # read before the flags (see SlotBoard.receive)
        else:  # no receipts: the newest slot the main process has seen
            received = max(
                (
                    self._lent_seq[s]
                    for s, b in enumerate(self._blocks)
                    if b is not None and self._flags[s] != LENT
                ),
                default=0,
            )
        for s, b in enumerate(self._blocks):
            if b is not None and self._flags[s] == LENT and self._lent_seq[s] < received:
                self._flags[s] = FREE  # its batch was lost before the main process got it


class SlotBlock:
    """One shared uint8 block and typed views of the fields of the layout it was made for."""

    def __init__(self, block: torch.Tensor, layout: BlockLayout) -> None:
        self.block = block
        self.layout = layout
        self.capacity = block.numel()
        self.views = block_views(block, layout)

    @classmethod
    def allocate(cls, layout: Layout) -> SlotBlock:
        placed, size = place(layout)
        return cls(shared_empty((max(size, 1),), torch.uint8), placed)

    def fits(self, layout: Layout) -> bool:
        """Whether the block was made for exactly ``layout``'s fields."""
        mine = {k: (shape, dtype) for k, (_, shape, dtype) in self.layout.items()}
        return mine == {k: (tuple(shape), dtype) for k, (shape, dtype) in layout.items()}


def block_views(block: torch.Tensor, layout: BlockLayout) -> dict[str, torch.Tensor]:
    """The typed field tensors that ``layout`` places in a uint8 ``block`` (views)."""
    views = {}
    for key, (offset, shape, dtype) in layout.items():
        nbytes = nbytes_of(shape, dtype)
        views[key] = block[offset : offset + nbytes].view(dtype).view(shape)
    return views


def layout_end(layout: BlockLayout) -> int:
    """The end of the last byte a block layout uses."""
    return max((o + nbytes_of(shape, dtype) for o, shape, dtype in layout.values()), default=0)


def leased_views(
    block: torch.Tensor, layout: BlockLayout, release: Callable[[], None]
) -> dict[str, torch.Tensor]:
    """``layout``'s field tensors viewing ``block`` (no copy); ``release`` is called once
    every one of them (and every view of them) is gone."""
    lease = block.numpy().view()  # a new array object: when it dies, every tensor of it is gone
    weakref.finalize(lease, release)
    return block_views(torch.from_numpy(lease), layout)


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


#: this process's slots while it is a MarsPairsLoader worker (set by the loader's collate
#: stage on its first batch); None elsewhere
_WORKER_SLOTS: list[BatchSlots | None] = [None]


def use_worker_slots(slots: BatchSlots | None) -> None:
    """Make ``slots`` the ones :func:`batch_start` / :func:`batch_empty` use in this
    process (a loader worker)."""
    _WORKER_SLOTS[0] = slots


def batch_start() -> None:
    """A dataset begins a batch (``__getitems__``): in a loader worker, a free slot becomes
    the one :func:`batch_empty` fills; elsewhere nothing."""
    slots = _WORKER_SLOTS[0]
    if slots is not None:
        slots.start()


def batch_empty(shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """An uninitialised C-contiguous array for one field of the batch being made: in a loader
    worker, inside the slot the batch will be sent in (no copy at collate time); elsewhere,
    or when it does not fit, this process's own memory."""
    slots = _WORKER_SLOTS[0]
    if slots is not None:
        out = slots.alloc(shape, dtype)
        if out is not None:
            return out
    return np.empty(shape, dtype=dtype)
