"""Torch datasets over a built mars-pairs dataset: map-style and streaming.

Samples are dicts of tensors (torchgeo style): ``ground`` float32 [3, H, W] in [0, 1],
``ortho`` float32 [1, h, w] in [0, 1], ``dem`` float32 [1, h, w] (metres, or normalised),
``viewshed`` float32 [1, h, w] in {0, 1}, ``corr`` float32 [2, H/k, W/k] (chip column, row of
each strided ground pixel's ray hit, NaN for no hit) and ``meta`` (plain Python values).
"""

from __future__ import annotations

import io
import json
import os
import random
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from mars_pairs.manifest import Manifest

DEFAULT_FIELDS = ("ground", "ortho", "dem", "viewshed")
ALL_FIELDS = ("ground", "ortho", "dem", "viewshed", "corr")
META_COLUMNS = (
    "key",
    "mission",
    "instrument",
    "product_id",
    "sol",
    "site",
    "drive",
    "split",
    "latitude",
    "longitude",
    "easting",
    "northing",
    "elevation",
    "azimuth_deg",
    "elevation_deg",
    "hfov_deg",
    "vfov_deg",
    "localization",
    "viewshed_area_m2",
    "max_visible_range_m",
)

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


# -- decoding ------------------------------------------------------------------------------------
def _decode_image(data: bytes, mode: str, size: tuple[int, int] | None = None) -> torch.Tensor:
    with Image.open(io.BytesIO(data)) as im:
        im = im.convert(mode)
        if size is not None and (im.height, im.width) != tuple(size):
            im = im.resize((size[1], size[0]), Image.BILINEAR)
        arr = np.asarray(im, dtype=np.float32) / 255.0
    arr = arr[None] if arr.ndim == 2 else np.ascontiguousarray(arr.transpose(2, 0, 1))
    return torch.from_numpy(arr)


def _decode_npy(data: bytes) -> np.ndarray:
    return np.load(io.BytesIO(data), allow_pickle=False)


def decode_member(
    field: str,
    data: bytes,
    *,
    ground_size: tuple[int, int] | None = None,
    normalize_dem: bool = False,
) -> Any:
    """Decode one member's bytes into its tensor (or dict, for ``meta``)."""
    if field == "ground":
        return _decode_image(data, "RGB", ground_size)
    if field == "ortho":
        return _decode_image(data, "L")
    if field == "viewshed":
        return (_decode_image(data, "L") > 0.5).float()
    if field == "dem":
        dem = _decode_npy(data).astype(np.float32)
        if normalize_dem:
            finite = np.isfinite(dem)
            centre = float(np.median(dem[finite])) if finite.any() else 0.0
            dem = np.where(finite, dem - centre, 0.0).astype(np.float32)
        return torch.from_numpy(dem)[None]
    if field == "corr":
        return torch.from_numpy(np.ascontiguousarray(_decode_npy(data).transpose(2, 0, 1)))
    if field == "meta":
        return json.loads(data)
    raise KeyError(f"unknown field {field!r}")


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


class _ShardFiles:
    """Open shard file handles, opened lazily and per process (safe under fork and spawn)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._pid = -1
        self._files: dict[str, Any] = {}

    def read(self, shard: str, offset: int, size: int) -> bytes:
        if self._pid != os.getpid():
            self._files, self._pid = {}, os.getpid()
        fh = self._files.get(shard)
        if fh is None:
            fh = self._files[shard] = open(self.root / shard, "rb")  # noqa: SIM115
        fh.seek(offset)
        return fh.read(size)

    def __getstate__(self) -> dict[str, Any]:
        return {"root": self.root, "_pid": -1, "_files": {}}


# -- map-style ---------------------------------------------------------------------------------
class MarsPairsDataset(Dataset):
    """Map-style dataset: ``ds[i]`` reads sample i's members with one seek each.

    Filter arguments are those of :meth:`mars_pairs.Manifest.filter`. ``ground_size`` (int or
    (H, W)) resizes ground images so they batch; ``normalize_dem`` subtracts each chip's
    median elevation. ``transform`` is applied to the sample dict.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        fields: Sequence[str] = DEFAULT_FIELDS,
        transform: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
        ground_size: int | Sequence[int] | None = None,
        normalize_dem: bool = False,
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
        manifest = Manifest.open(self.root).filter(**filters)
        columns = [*list(META_COLUMNS), "ground_member"]
        for name in self.fields:
            columns += [f"{name}_shard", f"{name}_offset", f"{name}_size"]
        table = manifest.to_table(columns=list(dict.fromkeys(columns)))
        self._rows = table.to_pylist()
        self._files = _ShardFiles(self.root)

    def __len__(self) -> int:
        return len(self._rows)

    def __getitem__(self, index: int) -> dict[str, Any]:
        row = self._rows[index]
        sample: dict[str, Any] = {}
        for name in self.fields:
            data = self._files.read(
                row[f"{name}_shard"], row[f"{name}_offset"], row[f"{name}_size"]
            )
            sample[name] = decode_member(
                name, data, ground_size=self.ground_size, normalize_dem=self.normalize_dem
            )
        sample["meta"] = {k: row[k] for k in META_COLUMNS}
        return self.transform(sample) if self.transform is not None else sample


# -- streaming -----------------------------------------------------------------------------------
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
            **filters,
        )
        self.shuffle_buffer = shuffle_buffer
        self.seed = seed
        self.epoch = 0
        by_shard: dict[str, list[int]] = {}
        first = self._inner.fields[0]
        for i, row in enumerate(self._inner._rows):
            by_shard.setdefault(row[f"{first}_shard"], []).append(i)
        for indices in by_shard.values():
            indices.sort(key=lambda i: self._inner._rows[i][f"{first}_offset"])
        self.shards = sorted(by_shard)
        self._by_shard = by_shard

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


def collate_samples(batch: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack tensors of a batch; ``meta`` becomes a dict of lists."""
    out: dict[str, Any] = {}
    for key in batch[0]:
        if key == "meta":
            out["meta"] = {k: [b["meta"][k] for b in batch] for k in batch[0]["meta"]}
        else:
            out[key] = torch.stack([b[key] for b in batch])
    return out
