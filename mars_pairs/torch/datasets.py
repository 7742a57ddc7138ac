"""Torch datasets over a built mars-pairs dataset: map-style and streaming.

Samples are dicts of tensors (torchgeo style): ``ground`` float32 [3, H, W] in [0, 1],
``ortho`` float32 [1, h, w] in [0, 1], ``dem`` float32 [1, h, w] (metres, or normalised),
``viewshed`` float32 [1, h, w] in {0, 1}, ``corr`` float32 [2, H/k, W/k] (chip column, row of
each strided ground pixel's ray hit, NaN for no hit) and ``meta`` (plain Python values).
With ``image_dtype=torch.uint8`` ground and ortho are uint8 0..255 and viewshed uint8 {0, 1}.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from mars_pairs.store.manifest import SUMMARY_COLUMNS, Manifest
from mars_pairs.store.member_index import MemberIndex
from mars_pairs.torch.decode import (
    ALL_FIELDS,
    DEFAULT_FIELDS,
    IMAGE_FIELDS,
    TORCH_DTYPES,
    UINT8_DIVISORS,
    chw_shape,
    decode_raw,
    finish_chw,
    out_dtype,
)
from mars_pairs.torch.files import ShardFiles
from mars_pairs.torch.lazy_float import TransportBuffers, Uint8AsFloat32
from mars_pairs.torch.transport import shared_empty

META_COLUMNS = SUMMARY_COLUMNS


FILTER_KEYS = (
    "bbox_lonlat",
    "bbox_map",
    "near",
    "polygon",
    "mission",
    "instrument",
    "sol",
    "split",
)


def _ground_size(value: int | Sequence[int] | None) -> tuple[int, int] | None:
    if value is None:
        return None
    if isinstance(value, int):
        return (value, value)
    h, w = value
    return (int(h), int(w))


def _check_fields(fields: Sequence[str]) -> tuple[str, ...]:
    bad = [f for f in fields if f not in ALL_FIELDS]
    if bad:
        raise ValueError(f"unknown field(s) {bad}; expected some of {list(ALL_FIELDS)}")
    return tuple(fields)


class MarsPairsDataset(Dataset):
    """Map-style dataset: ``ds[i]`` reads sample i's members with one seek each.

    Filter arguments are those of :meth:`mars_pairs.Manifest.filter`. ``ground_size`` (int or
    (H, W)) resizes ground images so they batch; ``normalize_dem`` subtracts each chip's
    median elevation. ``image_dtype=torch.uint8`` returns ground and ortho as uint8 (0..255)
    and viewshed as uint8 {0, 1}: a quarter of the bytes through DataLoader workers (convert
    on the device). ``transform`` is applied to the sample dict.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        fields: Sequence[str] = DEFAULT_FIELDS,
        transform: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
        ground_size: int | Sequence[int] | None = None,
        normalize_dem: bool = False,
        image_dtype: torch.dtype = torch.float32,
        **filters: Any,
    ) -> None:
        unknown = set(filters) - set(FILTER_KEYS)
        if unknown:
            raise TypeError(f"unknown filter argument(s) {sorted(unknown)}")
        self.root = Path(root)
        self.fields = _check_fields(fields)
        self.transform = transform
        self.ground_size = _ground_size(ground_size)
        self.normalize_dem = normalize_dem
        self._dtypes = {f: out_dtype(f, image_dtype) for f in self.fields}
        self.image_dtype = image_dtype
        manifest = Manifest.open(self.root).filter(**filters)
        columns = list(META_COLUMNS)
        for name in self.fields:
            columns += [f"{name}_shard", f"{name}_offset", f"{name}_size"]
        table = manifest.to_table(columns=list(dict.fromkeys(columns)))
        self._index = MemberIndex(table, self.fields, META_COLUMNS)
        self._files = ShardFiles(self.root)
        self._transport = TransportBuffers()

    def __len__(self) -> int:
        return len(self._index)

    def _raw(self, index: int) -> dict[str, np.ndarray]:
        raw = {}
        for name in self.fields:
            data = self._files.read(*self._index.location(index, name))
            raw[name] = decode_raw(name, data, self.ground_size, self.normalize_dem)
        return raw

    def _finish_sample(self, tensors: dict[str, torch.Tensor], meta: dict) -> dict[str, Any]:
        sample: dict[str, Any] = dict(tensors)
        sample["meta"] = meta
        return self.transform(sample) if self.transform is not None else sample

    def __getitem__(self, index: int) -> dict[str, Any]:
        """Sample ``index``. Inside a DataLoader worker (without ``transform``) float32 image
        fields are :class:`~mars_pairs.torch.lazy_float.Uint8AsFloat32`, so they cross to the main
        process as uint8."""
        in_worker = get_worker_info() is not None
        tensors = {
            name: self._tensor(name, raw, self._lazy(name, in_worker))
            for name, raw in self._raw(index).items()
        }
        return self._finish_sample(tensors, self._index.meta(index))

    def _lazy(self, field: str, in_worker: bool) -> bool:
        """Whether ``field`` is handed out as Uint8AsFloat32 (float32 images in a worker)."""
        return (
            in_worker
            and self.transform is None
            and field in IMAGE_FIELDS
            and self._dtypes[field] == np.float32
        )

    def _tensor(self, field: str, raw: np.ndarray, lazy: bool) -> torch.Tensor:
        """One sample's [C, H, W] tensor of a stage-1 array (its own memory)."""
        out = np.empty(chw_shape(raw), dtype=np.uint8 if lazy else self._dtypes[field])
        finish_chw(field, raw, out)
        tensor = torch.from_numpy(out)
        return Uint8AsFloat32(tensor, UINT8_DIVISORS[field]) if lazy else tensor

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """A batch of samples (the DataLoader's batched fetch).

        Members are decoded to compact arrays first; each field whose shapes agree across the
        batch is then converted into one [B, C, H, W] buffer whose rows are the samples'
        tensors, so ``collate_samples`` hands it on without another copy. Inside a DataLoader
        worker the buffers are in shared memory, and float32 image fields (without a
        ``transform``) are :class:`~mars_pairs.torch.lazy_float.Uint8AsFloat32` rows of a uint8
        buffer: a quarter of the bytes to the main process, where they arrive as float32.
        """
        raws = [self._raw(int(i)) for i in indices]
        in_worker = get_worker_info() is not None
        tensors: list[dict[str, torch.Tensor]] = [{} for _ in raws]
        for name in self.fields:
            shapes = {chw_shape(r[name]) for r in raws}
            dtype = self._dtypes[name]
            lazy = self._lazy(name, in_worker)
            if len(shapes) == 1:
                shape = (len(raws), *shapes.pop())
                if lazy:  # a reused buffer: no fresh shared memory in the steady state
                    batch = self._transport.empty(shape)
                elif in_worker:
                    batch = shared_empty(shape, TORCH_DTYPES[dtype])
                else:  # numpy reuses freed memory; torch.empty page-faults it in anew
                    batch = torch.from_numpy(np.empty(shape, dtype=dtype))
                for j, r in enumerate(raws):
                    finish_chw(name, r[name], batch[j].numpy())  # uint8: viewshed {0, 1}
                    tensors[j][name] = (
                        Uint8AsFloat32(batch[j], UINT8_DIVISORS[name], pooled=True)
                        if lazy
                        else batch[j]
                    )
            else:  # sizes differ (no ground_size): a tensor each
                for j, r in enumerate(raws):
                    tensors[j][name] = self._tensor(name, r[name], lazy)
        metas = self._index.metas([int(i) for i in indices])
        return [self._finish_sample(t, m) for t, m in zip(tensors, metas, strict=True)]


def _world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class MarsPairsIterableDataset(IterableDataset):
    """Streams samples shard by shard through a shuffle buffer.

    Shards are split across distributed ranks and DataLoader workers (every shard goes to
    exactly one (rank, worker)); within a shard members are read in file order. Call
    ``set_epoch`` to reshuffle between epochs.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        fields: Sequence[str] = DEFAULT_FIELDS,
        transform: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
        ground_size: int | Sequence[int] | None = None,
        normalize_dem: bool = False,
        image_dtype: torch.dtype = torch.float32,
        shuffle_buffer: int = 64,
        seed: int = 0,
        **filters: Any,
    ) -> None:
        self._inner = MarsPairsDataset(
            root,
            fields=fields,
            transform=transform,
            ground_size=ground_size,
            normalize_dem=normalize_dem,
            image_dtype=image_dtype,
            **filters,
        )
        self.shuffle_buffer = shuffle_buffer
        self.seed = seed
        self.epoch = 0
        self._by_shard = self._inner._index.shard_order(self._inner.fields[0])
        self.shards = sorted(self._by_shard)

    def set_epoch(self, epoch: int) -> None:
        """Reseed the shard order and shuffle buffer."""
        self.epoch = epoch

    def my_shards(self) -> list[str]:
        """The shards this (rank, worker) streams."""
        rank, world = _world()
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        order = list(self.shards)
        random.Random(self.seed + self.epoch).shuffle(order)
        slot, slots = rank * workers + worker, world * workers
        return order[slot::slots]

    def __iter__(self) -> Iterator[dict[str, Any]]:
        mine = self.my_shards()
        rng = random.Random(f"{self.seed}:{self.epoch}:{','.join(mine)}")
        buffer: list[dict[str, Any]] = []
        for shard in mine:
            for index in self._by_shard[shard]:
                buffer.append(self._inner[index])
                if len(buffer) >= max(self.shuffle_buffer, 1):
                    yield buffer.pop(rng.randrange(len(buffer)))
        rng.shuffle(buffer)
        yield from buffer

    def __len__(self) -> int:
        return len(self._inner)
