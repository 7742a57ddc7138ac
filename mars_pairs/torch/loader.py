"""MarsPairsLoader: a torch DataLoader whose batches cross from its workers with no copy.

A plain DataLoader worker puts every batch into new shared memory and passes its file
descriptors to the main process, which together cost more than decoding the batch (figures
in docs/benchmarks.md). Each ``MarsPairsLoader`` worker keeps a few batch slots in shared
memory (:mod:`mars_pairs.torch.transport`) and refills them: ``MarsPairsDataset`` decodes a
batch straight into a slot, the slot's memory reaches the main process once, and every
later batch in it is named by its slot and generation only. Like ``webdataset.WebLoader``,
it is a ``DataLoader`` subclass taking the same arguments.

The lease. A yielded batch's tensors view its worker's slot: the slot is lent to the caller
until every tensor of the batch (and every view of them) is gone, and the worker refills it
only then. Dropping each batch before the next one is asked for (a training loop that
moves it to a GPU, or converts it) keeps the worker's few slots turning. A caller who keeps
batches may: they never change, but each one kept holds a slot, and a worker with none free
sends its batches the plain DataLoader way (new shared memory, slower); ``.clone()`` what
you keep for long, or pass ``copy_batches=True`` (each batch copied into memory of this
process, the slot given back at once). Modifying a batch in place is allowed (the caller
holds the slot). With ``pin_memory`` batches are copied, into pinned memory where an
accelerator is there.

Slots are used when the loader has workers and collates with :func:`collate_samples` (the
default); with a ``collate_fn`` of the caller's, it behaves as a DataLoader. Its workers
keep the memory they free for the next batch (:mod:`mars_pairs.allocator`).

Only public torch API is used (``DataLoader.__iter__``, its ``collate_fn`` attribute,
``get_worker_info``, ``Tensor.share_memory_`` / ``is_shared``). The loader relies on two
behaviours of ``DataLoader.__iter__`` (``tests/torch/test_loader.py::
test_torch_behaviours_the_loader_relies_on`` fails if torch changes them):

- with workers, the iterator it returns has taken ``collate_fn`` as it was during the call
  (the loader sets its slot-filling collate function for the call only, so the attribute
  stays the caller's plain one, for wrappers that rebuild loaders from it);
- with ``persistent_workers``, every call returns the same iterator, reset, whose workers
  keep running (so the loader keeps that iterator's slot board).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import torch
from torch.utils.data import DataLoader, get_worker_info

from mars_pairs.allocator import reuse_freed_memory
from mars_pairs.torch.collate import batch_layout, collate_samples
from mars_pairs.torch.transport import (
    BatchSlots,
    BlockLayout,
    SlotBoard,
    SlotTicket,
    WarmBuffers,
    block_views,
    layout_end,
    leased_views,
    stacked_base,
    use_worker_slots,
)

#: the batch key that carries (worker id, slot, layout, block, allocations) to the loader
SLOT_KEY = "_mars_pairs_slot"


class RecyclingCollate:
    """``collate_samples`` into a worker's recycled shared-memory slot.

    ``board``: the iterator's :class:`~mars_pairs.torch.transport.SlotBoard`, made by the
    loader. In the main process (no workers) it is ``collate_samples``. Fields the dataset
    made inside the worker's current slot (``MarsPairsDataset.__getitems__`` through
    :func:`~mars_pairs.torch.transport.batch_empty`) stay where they are; the others are
    written after them.
    """

    def __init__(self, board: SlotBoard) -> None:
        self.board = board
        self._slots: BatchSlots | None = None  # per process, made on first use

    def __getstate__(self) -> dict[str, Any]:
        return {"board": self.board, "_slots": None}

    def __call__(self, batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
        info = get_worker_info()
        if info is None or not batch:
            return collate_samples(batch)
        slots = self._slots
        if slots is None:
            slots = self._slots = self.board.worker_slots(info.id)
            use_worker_slots(slots)  # the dataset's next batches are made in the slots
        layout = batch_layout(batch)
        if not layout:
            slots.current = None
            return collate_samples(batch)
        placed: BlockLayout = {}
        missing = {}
        for key, (shape, dtype) in layout.items():
            base = stacked_base([b[key] for b in batch])
            offset = None if base is None else slots.offset_of(base)
            if offset is None:
                missing[key] = (shape, dtype)
            else:
                placed[key] = (offset, shape, dtype)
        lent = slots.lend(placed, missing) if slots.current is not None else None
        if lent is None:
            taken = slots.take(layout)
            if taken is None:  # no free slot: new shared memory, as a plain DataLoader
                return collate_samples(batch)
            slot, block = taken
            where, copy_all = block.layout, True
        else:
            slot, block, where, copy_all = lent
        targets = where if copy_all else {k: where[k] for k in missing}
        out = collate_samples(batch, into=block_views(block.block, targets))
        for key in where:
            out[key] = None  # travels in the block (one shared storage for the batch)
        out[SLOT_KEY] = slots.ticket(info.id, slot, where)
        return out


class WorkerInit:
    """A loader worker's start: keep freed memory for the next batch (see
    :mod:`mars_pairs.allocator`), then the caller's ``worker_init_fn``."""

    def __init__(self, then: Callable[[int], None] | None) -> None:
        self.then = then

    def __call__(self, worker_id: int) -> None:
        reuse_freed_memory()
        if self.then is not None:
            self.then(worker_id)


def _slot_count(prefetch_factor: int | None) -> int:
    """Slots a worker may need: in flight (prefetch), lost when an epoch is cut short
    (prefetch), and the one being built."""
    return 2 * (prefetch_factor or 2) + 2


class MarsPairsLoader(DataLoader[dict[str, Any]]):
    """A ``torch.utils.data.DataLoader`` over a mars-pairs dataset whose workers lend their
    shared-memory batch slots to the caller (see the module docstring: the lease).

    Takes DataLoader's arguments, and ``copy_batches``: copy each batch out of its slot into
    this process's memory (reused once the caller drops the batch) instead of lending the
    slot. ``collate_fn`` defaults to :func:`collate_samples`; slots are used when
    ``num_workers > 0``, batches are made (``batch_size`` not None) and the collate function
    is :func:`collate_samples` (each worker keeps up to ``2 * prefetch_factor + 2`` slots,
    allocated as needed; every iterator has its own). ``recycled`` and ``fresh`` count the
    batches received through a slot and through new shared memory, ``allocations`` the slot
    blocks each worker has allocated, ``handovers`` the slot blocks received (each crosses
    once a generation).
    """

    def __init__(
        self,
        dataset: Any,
        batch_size: int | None = 1,
        shuffle: bool | None = None,
        *,
        num_workers: int = 0,
        collate_fn: Callable[[Any], Any] | None = None,
        prefetch_factor: int | None = None,
        worker_init_fn: Callable[[int], None] | None = None,
        copy_batches: bool = False,
        **kwargs: Any,
    ) -> None:
        if collate_fn is None and batch_size is not None:
            collate_fn = collate_samples
        super().__init__(
            dataset,
            batch_size,
            shuffle,
            num_workers=num_workers,
            collate_fn=collate_fn,
            prefetch_factor=prefetch_factor,
            worker_init_fn=WorkerInit(worker_init_fn) if num_workers > 0 else worker_init_fn,
            **kwargs,
        )
        self.copy_batches = bool(copy_batches)
        self.recycled = 0
        self.fresh = 0
        self.handovers = 0
        self.allocations: dict[int, int] = {}  # worker id -> slot blocks it has allocated
        self._warm = WarmBuffers(keep=_slot_count(prefetch_factor))
        self._persistent_board: SlotBoard | None = None  # the persistent workers' board

    def __repr__(self) -> str:
        batches = f"{len(self)} batches" if hasattr(self.dataset, "__len__") else "streamed"
        head = (
            f"{type(self).__name__}(batch_size={self.batch_size}, "
            f"num_workers={self.num_workers}, {batches}"
            + (", recycled slots" if self.recycles else "")
            + ")"
        )
        inner = "\n".join("    " + line for line in repr(self.dataset).splitlines())
        return f"{head}\n{inner}"

    @property
    def recycles(self) -> bool:
        """Whether this loader's workers recycle their batch slots."""
        return self.num_workers > 0 and self.collate_fn is collate_samples

    def __iter__(self) -> LoaderIterator:  # type: ignore[override]  # wraps torch's iterator
        """DataLoader's iterator, its workers collating into slots of a board of its own
        (two iterators alive at once never share a slot)."""
        if not self.recycles:
            return LoaderIterator(self, super().__iter__(), None)
        if self.persistent_workers and self._persistent_board is not None:
            # the same iterator again, reset: its workers run, collating with their board
            return LoaderIterator(self, super().__iter__(), self._persistent_board)
        board = SlotBoard(self.num_workers, _slot_count(self.prefetch_factor))
        plain = self.collate_fn
        self.collate_fn = RecyclingCollate(board)  # the new iterator's workers take this one
        try:
            inner = super().__iter__()
        finally:
            self.collate_fn = plain
        if self.persistent_workers:
            self._persistent_board = board
        return LoaderIterator(self, inner, board)

    def _receive(self, batch: Any, board: SlotBoard | None) -> Any:
        """The batch handed to the caller: its fields leased views of its slot (or, copying,
        the caller's copy, the slot given back)."""
        if not isinstance(batch, dict) or SLOT_KEY not in batch or board is None:
            self.fresh += isinstance(batch, dict)
            return batch
        ticket: SlotTicket = batch.pop(SLOT_KEY)
        w, s = ticket.worker, ticket.slot
        self.allocations[w] = ticket.allocations
        self.handovers += ticket.block is not None
        block = board.receive(ticket)
        self.recycled += 1
        if self.copy_batches or self.pin_memory:
            mine = self._warm.copy(block[: layout_end(ticket.layout)])
            board.release(w, s)
            if self.pin_memory and _accelerator_available():
                mine = mine.pin_memory()
            batch.update(block_views(mine, ticket.layout))
        else:
            batch.update(leased_views(block, ticket.layout, partial(board.release, w, s)))
        return batch


class LoaderIterator:
    """An iterator of a :class:`MarsPairsLoader`: torch's, each batch leased from its slot.

    Like torch's, it goes on after a worker's exception is raised (the next batch follows).
    A worker's exception keeps its type (a DatasetError stays a DatasetError, its message the
    worker's traceback) and reaches the caller without torch's frames: they hold torch's
    iterator in a reference cycle, whose late collection waits 5 s for each worker.
    """

    def __init__(self, loader: MarsPairsLoader, inner: Any, board: SlotBoard | None) -> None:
        self._loader = loader
        self._inner = inner
        self._board = board

    def __iter__(self) -> LoaderIterator:
        return self

    def __next__(self) -> Any:
        error = None
        try:
            batch = next(self._inner)
        except StopIteration:
            raise
        except Exception as exc:  # a worker's, re-raised by torch's ExceptionWrapper
            exc.__traceback__ = None  # its frames: the exception and torch's iterator
            error = exc
        if error is not None:
            try:
                raise error
            finally:
                error = None  # no cycle through this frame either
        return self._loader._receive(batch, self._board)

    def __len__(self) -> int:
        return len(self._inner)


def _accelerator_available() -> bool:
    """Whether pinned memory can serve a device: ``torch.accelerator`` (torch >= 2.6), else
    CUDA's own test (the torch versions the package allows before it)."""
    accelerator = getattr(torch, "accelerator", None)
    if accelerator is not None:
        return bool(accelerator.is_available())
    return bool(torch.cuda.is_available())
