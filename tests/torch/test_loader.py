"""MarsPairsLoader: workers refill their shared-memory slots; the batches it yields are the
caller's own and equal what a one-process DataLoader gives."""

from __future__ import annotations

import gc
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from mars_pairs.torch import MarsPairsDataset, MarsPairsLoader, collate_samples
from mars_pairs.torch.transforms import Flip
from mars_pairs.torch.transport import FREE, LENT, BatchSlots, WarmBuffers

FIELDS = ("ground", "ortho", "dem", "viewshed", "bounds", "transform", "rotation")


def reference(ds: MarsPairsDataset, batch_size: int) -> list[dict]:
    """Batches built in this process, one sample at a time (no worker, no slot)."""
    return [
        collate_samples([ds[i] for i in range(j, min(j + batch_size, len(ds)))])
        for j in range(0, len(ds), batch_size)
    ]


def assert_same(got: list[dict], want: list[dict]) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g["meta"]["key"] == w["meta"]["key"]
        for key in FIELDS:
            assert g[key].dtype == w[key].dtype, key
            assert torch.equal(g[key], w[key]), key


def test_batches_equal_and_slots_reused(dataset_dir: Path) -> None:
    """Copying: every batch the caller's own memory, the slots refilled."""
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        want = reference(ds, 2)
        loader = MarsPairsLoader(
            ds, batch_size=2, num_workers=2, persistent_workers=True, copy_batches=True
        )
        epochs = [list(loader) for _ in range(4)]  # every batch kept: none may alias another
    for got in epochs:
        assert_same(got, want)
        for batch in got:
            assert not any(batch[k].is_shared() for k in FIELDS)  # the caller's own memory
    assert loader.recycled == 4 * len(want) and loader.fresh == 0
    # 20 batches from 2 workers: a few slots each, refilled, not reallocated
    assert 1 <= sum(loader.allocations.values()) <= 8


def shm_files() -> set[str]:
    """The names in /dev/shm (torch's shared memory, were it left behind)."""
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


def child_pids() -> set[int]:
    """This process's live child processes (Linux /proc; empty elsewhere)."""
    pids: set[int] = set()
    task_dir = Path(f"/proc/{os.getpid()}/task")
    for task in task_dir.iterdir() if task_dir.is_dir() else ():
        try:
            pids.update(int(p) for p in (task / "children").read_text().split())
        except OSError:
            continue
    return pids


def named_by(names: set[str], pids: set[int]) -> set[str]:
    """The names holding one of ``pids`` as a ``_``-separated part (torch names its shared
    memory ``torch_<pid>_...``; other processes on the machine make their own)."""
    return {n for n in names if {str(p) for p in pids} & set(n.split("_"))}


def test_leased_batches_dropped_each_step_turn_the_slots(dataset_dir: Path) -> None:
    """A loop that drops each batch: every batch through a slot, each slot's block handed
    over once, and no shared memory left behind once the loader is gone."""
    before = shm_files()
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        want = reference(ds, 2)
        loader = MarsPairsLoader(ds, batch_size=2, num_workers=2, persistent_workers=True)
        pids = {os.getpid()}
        for _ in range(4):
            got = []
            for batch in loader:
                got.append({k: batch[k].clone() for k in FIELDS} | {"meta": batch["meta"]})
                pids |= child_pids()
            assert_same(got, want)
    assert loader.recycled == 4 * len(want) and loader.fresh == 0
    assert 1 <= sum(loader.allocations.values()) <= 8
    assert loader.handovers == sum(loader.allocations.values())  # a block crosses once
    del loader, batch
    gc.collect()
    assert not named_by(shm_files() - before, pids)


def test_kept_leases_never_change(dataset_dir: Path) -> None:
    """Batches kept past the next step hold their slots: the workers never refill them
    (they send later batches in new shared memory once their slots are all held)."""
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        want = reference(ds, 1)
        loader = MarsPairsLoader(ds, batch_size=1, num_workers=1, persistent_workers=True)
        epochs = [list(loader) for _ in range(3)]
        for got in epochs:
            assert_same(got, want)
        assert loader.recycled + loader.fresh == 3 * len(want)
        assert loader.fresh > 0  # 6 slots, every batch of 3 epochs kept
        del epochs, got
        gc.collect()
        fresh = loader.fresh
        assert_same(
            list({k: b[k].clone() for k in FIELDS} | {"meta": b["meta"]} for b in loader), want
        )
        assert loader.fresh == fresh  # the slots given back, turning again


def test_a_lease_modified_in_place_is_the_callers(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        want = reference(ds, 2)
        loader = MarsPairsLoader(ds, batch_size=2, num_workers=1)
        for batch, w in zip(loader, want, strict=True):
            batch["ground"].zero_()
            assert int(batch["ground"].sum()) == 0
            assert torch.equal(batch["ortho"], w["ortho"])
        assert loader.recycled == len(want)


def test_transforms_keep_slots(dataset_dir: Path) -> None:
    """A transform replaces the sample's tensors: the collate stage still fills the slots."""
    transform = Flip("horizontal", target="chip")
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128), transform=transform) as ds:
        want = reference(ds, 3)
        loader = MarsPairsLoader(ds, batch_size=3, num_workers=2)
        got = list(loader)
    assert_same(got, want)
    assert loader.recycled == len(want) and loader.fresh == 0


def test_epoch_cut_short_reclaims_slots(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        want = reference(ds, 1)
        loader = MarsPairsLoader(ds, batch_size=1, num_workers=2, persistent_workers=True)
        for _ in range(5):
            for _batch in loader:  # leaves batches in flight, never received
                break
            assert_same(list(loader), want)
    assert loader.fresh == 0  # lost slots came back (~2 a worker a round, 6 slots a worker)
    assert sum(loader.allocations.values()) <= 12


@pytest.mark.slow
def test_spawned_workers(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        loader = MarsPairsLoader(ds, batch_size=4, num_workers=1, multiprocessing_context="spawn")
        assert_same(list(loader), reference(ds, 4))
    assert loader.recycled == 3


def test_own_collate_is_plain_dataloader(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, fields=("ortho",)) as ds:
        loader = MarsPairsLoader(ds, batch_size=4, num_workers=1, collate_fn=len)
        assert list(loader) == [4, 4, 1]
        plain = list(DataLoader(ds, batch_size=4, num_workers=1, collate_fn=len))
    assert plain == [4, 4, 1] and loader.recycled == 0


def test_no_workers_no_slots(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        loader = MarsPairsLoader(ds, batch_size=4)
        assert_same(list(loader), reference(ds, 4))
    assert loader.recycled == 0


LAYOUT = {"a": ((2, 3), torch.uint8), "b": ((4,), torch.float64)}


def test_slots_lend_free_and_run_out() -> None:
    flags = torch.full((2,), FREE, dtype=torch.uint8)
    slots = BatchSlots(flags)
    first = slots.take(LAYOUT)
    second = slots.take(LAYOUT)
    assert first is not None and second is not None
    assert {first[0], second[0]} == {0, 1} and flags.tolist() == [LENT, LENT]
    assert slots.take(LAYOUT) is None  # both out: the caller goes the plain way
    flags[first[0]] = FREE
    again = slots.take(LAYOUT)
    assert again is not None and again[0] == first[0]
    assert again[1] is first[1] and slots.allocations == 2  # the same block, refilled
    views = again[1].views
    assert views["a"].shape == (2, 3) and views["b"].dtype == torch.float64
    assert views["b"].data_ptr() % 64 == 0


def test_lost_slot_reclaimed_by_a_later_release() -> None:
    """Batches reach the main process in the order a worker sent them: when a later one is
    freed, an earlier one still out was lost (its epoch was cut short)."""
    flags = torch.full((3,), FREE, dtype=torch.uint8)
    slots = BatchSlots(flags)
    lost, later, _ = (slots.take(LAYOUT) for _ in range(3))
    assert lost is not None and later is not None
    flags[later[0]] = FREE
    first = slots.take(LAYOUT)  # reclaims ``lost`` on the way, and lends it again
    second = slots.take(LAYOUT)
    assert first is not None and second is not None
    assert (first[0], second[0]) == (lost[0], later[0])
    assert slots.take(LAYOUT) is None and slots.allocations == 3


def test_new_layout_reallocates_a_free_slot() -> None:
    flags = torch.full((1,), FREE, dtype=torch.uint8)
    slots = BatchSlots(flags)
    first = slots.take(LAYOUT)
    assert first is not None
    flags[0] = FREE
    other = slots.take({"a": ((5, 3), torch.uint8)})
    assert other is not None and other[1] is not first[1] and slots.allocations == 2
    assert other[1].views["a"].shape == (5, 3)


@pytest.mark.parametrize("pin", [False, True])
def test_pin_memory_flag(dataset_dir: Path, pin: bool) -> None:
    """pin_memory (a no-op without an accelerator, a copy with one) never yields a slot."""
    with MarsPairsDataset(dataset_dir, ground_size=(96, 128)) as ds:
        loader = MarsPairsLoader(ds, batch_size=4, num_workers=1, pin_memory=pin)
        with pytest.warns(UserWarning) if pin and not torch.cuda.is_available() else _nothing():
            got = list(loader)
        assert_same(got, reference(ds, 4))
    assert all(not b["ground"].is_shared() for b in got)


class _nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def test_warm_buffers_come_back_only_when_every_view_is_gone() -> None:
    warm = WarmBuffers(keep=4)
    block = torch.arange(64, dtype=torch.uint8)
    first = warm.copy(block)
    view = first[8:16].view(torch.float64)  # a field of the batch, as the loader makes them
    del first
    gc.collect()
    second = warm.copy(block * 2)  # ``view`` still holds the first buffer: a new one
    assert warm.allocations == 2
    assert torch.equal(view, block[8:16].view(torch.float64))
    del view, second
    gc.collect()
    third = warm.copy(block)
    assert warm.allocations == 2 and torch.equal(third, block)  # refilled, not allocated


class Numbers(torch.utils.data.Dataset):
    """Sample i: {"x": [4] float64 of i, "y": [2, 3] uint8 of i}; sample ``bad`` raises."""

    def __init__(self, n: int, bad: int | None = None) -> None:
        self.n, self.bad = n, bad

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        if i == self.bad:
            raise ValueError(f"sample {i} is broken")
        return {"x": torch.full((4,), float(i)), "y": torch.full((2, 3), i, dtype=torch.uint8)}


def test_two_live_iterators_never_share_a_slot() -> None:
    """Each iterator has its own workers and flags: freeing a slot of one never lets the
    other's worker overwrite a batch not yet copied out."""
    loader = MarsPairsLoader(Numbers(96), batch_size=2, num_workers=2)
    for a, b in zip(loader, loader, strict=True):
        assert torch.equal(a["x"], b["x"]) and torch.equal(a["y"], b["y"])
    first, second = iter(loader), iter(loader)
    got = [next(first), next(second), next(second), next(first)]
    assert [int(b["x"][0, 0]) for b in got] == [0, 0, 2, 2]


def test_a_worker_error_is_raised_and_the_epoch_goes_on() -> None:
    loader = MarsPairsLoader(Numbers(10, bad=5), batch_size=2, num_workers=2)
    it = iter(loader)
    assert len(it) == 5
    got, errors = [], 0
    while True:
        try:
            got.append(int(next(it)["x"][0, 0]))
        except ValueError as exc:
            errors += 1
            assert "sample 5 is broken" in str(exc)
        except StopIteration:
            break
    assert got == [0, 2, 6, 8] and errors == 1  # as a plain DataLoader


def test_unbatched_loading_is_a_dataloaders() -> None:
    loader = MarsPairsLoader(Numbers(4), batch_size=None, num_workers=1)
    assert [int(s["x"][0]) for s in loader] == [0, 1, 2, 3] and loader.recycled == 0


def test_its_collate_fn_in_another_loader_gives_plain_batches() -> None:
    """Wrappers (Accelerate, Lightning) rebuild loaders from ``collate_fn``: it is the plain
    ``collate_samples``, never a slot-filling one."""
    loader = MarsPairsLoader(Numbers(8), batch_size=4, num_workers=1)
    assert loader.collate_fn is collate_samples
    batches = list(
        DataLoader(Numbers(8), batch_size=4, num_workers=1, collate_fn=loader.collate_fn)
    )
    assert [sorted(b) for b in batches] == [["x", "y"], ["x", "y"]]
    again = MarsPairsLoader(Numbers(8), batch_size=4, num_workers=1, collate_fn=loader.collate_fn)
    assert [int(b["x"][3, 0]) for b in again] == [3, 7] and again.recycled == 2


def test_warm_buffers_of_several_sizes() -> None:
    """Batches of two layouts (a last, shorter batch): each size comes back to its own."""
    warm = WarmBuffers(keep=4)
    big, small = (
        warm.copy(torch.zeros(64, dtype=torch.uint8)),
        warm.copy(torch.ones(32, dtype=torch.uint8)),
    )
    del big, small
    gc.collect()
    again = warm.copy(torch.full((32,), 7, dtype=torch.uint8))  # the second free buffer
    assert warm.allocations == 2 and int(again[0]) == 7


class Tag:
    """A collate function that names itself instead of collating."""

    def __init__(self, tag: str) -> None:
        self.tag = tag

    def __call__(self, batch: list) -> str:
        return self.tag


def test_torch_behaviours_the_loader_relies_on() -> None:
    """The two DataLoader behaviours named in ``mars_pairs.torch.loader``'s docstring: fails
    when torch changes them (the loader would then silently stop recycling its slots)."""
    loader = DataLoader(range(4), batch_size=2, num_workers=1)
    loader.collate_fn = Tag("when iter() was called")
    batches = iter(loader)
    loader.collate_fn = Tag("after")
    assert list(batches) == ["when iter() was called"] * 2
    persistent = DataLoader(range(4), batch_size=2, num_workers=1, persistent_workers=True)
    first = iter(persistent)
    assert len(list(first)) == 2
    assert iter(persistent) is first


def test_persistent_workers_keep_their_slots_across_epochs() -> None:
    loader = MarsPairsLoader(Numbers(8), batch_size=2, num_workers=1, persistent_workers=True)
    for _ in range(3):
        assert [int(b["x"][0, 0]) for b in loader] == [0, 2, 4, 6]
    assert loader.recycled == 12 and loader.fresh == 0
    assert sum(loader.allocations.values()) <= 6


def test_a_batch_made_of_two_batches_keeps_both_in_the_slot() -> None:
    """A second start before the slot is lent (a dataset whose batch holds two datasets'
    batches) goes on after what the slot holds; the slot is lent once."""
    flags = torch.full((2,), FREE, dtype=torch.uint8)
    slots = BatchSlots(flags)
    slots.start()
    assert slots.current is not None and slots.alloc((4,), np.dtype(np.uint8)) is None  # no block
    taken = slots.take(LAYOUT)  # the first batch: a block laid out for it
    assert taken is not None
    flags[taken[0]] = FREE
    slots.start()
    first = slots.alloc((2, 3), np.dtype(np.uint8))
    slots.start()
    second = slots.alloc((4,), np.dtype(np.float64))
    assert first is not None and second is not None
    first[:] = 7
    second[:] = 1.5
    assert (first == 7).all() and slots.cursor == 128
    lent = slots.lend({}, {})
    assert lent is not None and flags[lent[0]] == LENT and slots.current is None
