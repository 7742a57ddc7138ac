"""MarsPairsLoader: a torch DataLoader whose workers refill the same shared-memory batches.

A plain DataLoader worker puts every batch into new shared memory, which costs about as much
as decoding the batch (figures in the README's loader benchmark). With ``MarsPairsLoader``
each worker keeps a few batch slots in shared memory and refills them;
the loader copies every batch it receives into its own process's memory (one memcpy, into
pages it reuses once the caller drops a batch) and hands the slot back. The batches it
yields are ordinary tensors that the caller owns: they may be kept, modified or sent to a
GPU at leisure. Like ``webdataset.WebLoader``, it is a ``DataLoader`` subclass taking the
same arguments.

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
  keep running (so the loader keeps that iterator's slot flags).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch.utils.data import DataLoader, get_worker_info

from mars_pairs.allocator import reuse_freed_memory
from mars_pairs.torch.collate import batch_layout, collate_samples
from mars_pairs.torch.transport import FREE, BatchSlots, WarmBuffers, block_views

#: the batch key that carries (worker id, slot, layout, block, allocations) to the loader
SLOT_KEY = "_mars_pairs_slot"


class RecyclingCollate:
    """``collate_samples`` into a worker's recycled shared-memory slot.

    ``flags``: shared uint8 [workers, slots] (FREE / LENT), made by the loader. In the main
    process (no workers) it is ``collate_samples``.
    """

    def __init__(self, flags: torch.Tensor) -> None:
        self.flags = flags
        self._slots: BatchSlots | None = None  # per process, made on first use

    def __getstate__(self) -> dict[str, Any]:
        return {"flags": self.flags, "_slots": None}

    def __call__(self, batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
        info = get_worker_info()
        if info is None or not batch:
            return collate_samples(batch)
        if self._slots is None:
            self._slots = BatchSlots(self.flags[info.id])
        layout = batch_layout(batch)
        taken = self._slots.take(layout) if layout else None
        if taken is None:  # no free slot: new shared memory, as a plain DataLoader
            return collate_samples(batch)
        slot, block = taken
        out = collate_samples(batch, into=block.views)
        for key in block.layout:
            out[key] = None  # travels in the block (one shared storage for the batch)
        out[SLOT_KEY] = (info.id, slot, block.layout, block.block, self._slots.allocations)
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
    """A ``torch.utils.data.DataLoader`` over a mars-pairs dataset whose workers reuse their
    shared-memory batch buffers.

    Takes DataLoader's arguments. ``collate_fn`` defaults to :func:`collate_samples`; slots
    are recycled when ``num_workers > 0``, batches are made (``batch_size`` not None) and the
    collate function is :func:`collate_samples` (each worker keeps up to
    ``2 * prefetch_factor + 2`` slots, allocated as needed; every iterator has its own). A
    received batch is copied into this process's memory, reused once the caller drops the
    batch's tensors. ``recycled`` and ``fresh`` count the batches received through a slot
    and through new shared memory, ``allocations`` the slot blocks each worker has allocated.
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
        self.recycled = 0
        self.fresh = 0
        self.allocations: dict[int, int] = {}  # worker id -> slot blocks it has allocated
        self._warm = WarmBuffers(keep=_slot_count(prefetch_factor))
        self._persistent_flags: torch.Tensor | None = None  # the persistent workers' flags

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
        """DataLoader's iterator, its workers collating into slots freed through flags of its
        own (two iterators alive at once never share a slot), each batch copied out."""
        if not self.recycles:
            return LoaderIterator(self, super().__iter__(), None)
        if self.persistent_workers and self._persistent_flags is not None:
            # the same iterator again, reset: its workers run, collating with their flags
            return LoaderIterator(self, super().__iter__(), self._persistent_flags)
        flags = torch.full((self.num_workers, _slot_count(self.prefetch_factor)), FREE,
                           dtype=torch.uint8)  # fmt: skip
        flags.share_memory_()
        plain = self.collate_fn
        self.collate_fn = RecyclingCollate(flags)  # the new iterator's workers take this one
        try:
            inner = super().__iter__()
        finally:
            self.collate_fn = plain
        if self.persistent_workers:
            self._persistent_flags = flags
        return LoaderIterator(self, inner, flags)

    def _receive(self, batch: Any, flags: torch.Tensor | None) -> Any:
        """The caller's copy of a received batch; its slot handed back to the worker."""
        if not isinstance(batch, dict) or SLOT_KEY not in batch or flags is None:
            self.fresh += isinstance(batch, dict)
            return batch
        worker, slot, layout, block, allocations = batch.pop(SLOT_KEY)
        self.allocations[int(worker)] = int(allocations)
        # a pinned block is already a copy (pin_memory); a shared one is the worker's slot
        mine = self._warm.copy(block) if block.is_shared() else block
        batch.update(block_views(mine, layout))
        flags[int(worker), int(slot)] = FREE
        self.recycled += 1
        return batch


class LoaderIterator:
    """An iterator of a :class:`MarsPairsLoader`: torch's, each batch copied out of its slot.

    Like torch's, it goes on after a worker's exception is raised (the next batch follows).
    A worker's exception keeps its type (a DatasetError stays a DatasetError, its message the
    worker's traceback) and reaches the caller without torch's frames: they hold torch's
    iterator in a reference cycle, whose late collection waits 5 s for each worker.
    """

    def __init__(self, loader: MarsPairsLoader, inner: Any, flags: torch.Tensor | None) -> None:
        self._loader = loader
        self._inner = inner
        self._flags = flags

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
        return self._loader._receive(batch, self._flags)

    def __len__(self) -> int:
        return len(self._inner)
