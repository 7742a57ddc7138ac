"""Torch datasets over a built mars-pairs dataset: map-style and streaming.

Samples are dicts of tensors (torchgeo style): ``ground`` float32 [3, H, W] in [0, 1],
``ortho`` float32 [1, h, w] in [0, 1], ``dem`` float32 [1, h, w] (metres, or normalised),
``viewshed`` float32 [1, h, w] in {0, 1}, ``corr`` float32 [2, H/k, W/k] (chip column, row of
each strided ground pixel's ray hit, NaN for no hit) and ``meta`` (plain Python values).
With ``image_dtype=torch.uint8`` ground and ortho are uint8 0..255 and viewshed uint8 {0, 1}.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import torch
from PIL import Image
from torch.utils.data import Dataset, IterableDataset, default_collate, get_worker_info

from mars_pairs.lazy_float import TransportBuffers, Uint8AsFloat32
from mars_pairs.manifest import SUMMARY_COLUMNS, Manifest
from mars_pairs.member_index import MemberIndex

DEFAULT_FIELDS = ("ground", "ortho", "dem", "viewshed")
ALL_FIELDS = ("ground", "ortho", "dem", "viewshed", "corr")
IMAGE_FIELDS = ("ground", "ortho", "viewshed")  # uint8 with image_dtype=torch.uint8
_UINT8_DIVISORS = {"ground": 255.0, "ortho": 255.0, "viewshed": 1.0}  # float32 = uint8 / this
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


# -- decoding ------------------------------------------------------------------------------------
def _image_u8(
    data: bytes | bytearray, mode: str, size: tuple[int, int] | None = None
) -> np.ndarray:
    """Decode an image to uint8 [H, W] or [H, W, C] (resized to ``size`` (H, W) if given)."""
    with Image.open(io.BytesIO(data)) as im:
        if im.mode != mode:
            im = im.convert(mode)
        if size is not None and (im.height, im.width) != tuple(size):
            im = im.resize((size[1], size[0]), Image.BILINEAR)
        return _pil_array(im)


def _pil_array(im: Image.Image) -> np.ndarray:
    """An "L" or "RGB" image's pixels as numpy, zero-copy through Pillow's Arrow export.

    (``np.asarray(im)`` copies the pixels through ``tobytes``; asking PIL for float32 is
    ~10x slower still.) Falls back to ``np.asarray`` on Pillow without Arrow support.
    """
    if im.mode in ("L", "RGB") and hasattr(im, "__arrow_c_array__"):
        try:
            im.load()
            arr = pa.array(im)
            if im.mode == "L":
                return arr.to_numpy(zero_copy_only=True).reshape(im.height, im.width)
            pixels = arr.values.to_numpy(zero_copy_only=True)  # RGBX, 4 bytes a pixel
            return pixels.reshape(im.height, im.width, 4)[..., :3]
        except (ValueError, TypeError, pa.ArrowException):
            pass
    return np.asarray(im)


def _decode_npy(data: bytes | bytearray) -> np.ndarray:
    """A .npy array; zero-copy (and writable) over a ``bytearray``."""
    buf = io.BytesIO(data)
    version = np.lib.format.read_magic(buf)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(buf)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(buf)
    else:
        return np.load(io.BytesIO(data), allow_pickle=False)
    if dtype.hasobject:
        raise ValueError("object arrays are not allowed")
    count = int(np.prod(shape, dtype=np.int64))
    arr = np.frombuffer(data, dtype=dtype, count=count, offset=buf.tell())
    arr = arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)
    return arr if arr.flags.writeable else arr.copy()


def _decode_raw(
    field: str,
    data: bytes | bytearray,
    ground_size: tuple[int, int] | None = None,
    normalize_dem: bool = False,
) -> np.ndarray:
    """Stage 1: a member's compact array (uint8 images, channels last; float32 DEM / corr)."""
    if field == "ground":
        return _image_u8(data, "RGB", ground_size)
    if field in ("ortho", "viewshed"):
        return _image_u8(data, "L")
    if field == "dem":
        dem = _decode_npy(data).astype(np.float32, copy=False)
        if normalize_dem:
            finite = np.isfinite(dem)
            centre = float(np.median(dem[finite])) if finite.any() else 0.0
            dem = np.where(finite, dem - centre, np.float32(0.0)).astype(np.float32)
        return dem
    if field == "corr":
        return _decode_npy(data)
    raise KeyError(f"unknown field {field!r}")


def _chw_shape(raw: np.ndarray) -> tuple[int, int, int]:
    """The [C, H, W] shape of a stage-1 array."""
    return (1, *raw.shape) if raw.ndim == 2 else (raw.shape[2], raw.shape[0], raw.shape[1])


_TORCH_DTYPES = {np.dtype(np.uint8): torch.uint8, np.dtype(np.float32): torch.float32}


def _out_dtype(field: str, image_dtype: torch.dtype) -> np.dtype:
    """The numpy dtype of a field's tensor: ``image_dtype`` for images, else float32."""
    if field in IMAGE_FIELDS and image_dtype == torch.uint8:
        return np.dtype(np.uint8)
    if image_dtype not in (torch.float32, torch.uint8):
        raise ValueError(f"image_dtype must be torch.float32 or torch.uint8, got {image_dtype}")
    return np.dtype(np.float32)


def _finish(field: str, raw: np.ndarray, out: np.ndarray) -> None:
    """Stage 2: write the [C, H, W] tensor of a stage-1 array into ``out``, in one pass.

    float32 ``out``: images in [0, 1], viewshed {0, 1}; uint8 ``out`` (images only): images
    as they are (0..255), viewshed {0, 1}.

    (numpy, not torch: torch's strided uint8 -> float copy is several times slower here and
    spawns intra-op threads in the main process.)
    """
    chw = raw[None] if raw.ndim == 2 else raw.transpose(2, 0, 1)
    if field in ("ground", "ortho") and out.dtype != np.uint8:
        # transposing uint8 then dividing contiguously beats one strided divide (~1.4x)
        np.divide(np.ascontiguousarray(chw), np.float32(255.0), out=out)
    elif field == "viewshed":
        np.greater(chw, 127, out=out, casting="unsafe")
    else:
        np.copyto(out, chw, casting="same_kind")


def decode_member(
    field: str,
    data: bytes | bytearray,
    *,
    ground_size: tuple[int, int] | None = None,
    normalize_dem: bool = False,
    image_dtype: torch.dtype = torch.float32,
) -> Any:
    """Decode one member's bytes into its tensor (or dict, for ``meta``)."""
    if field == "meta":
        return json.loads(data)
    raw = _decode_raw(field, data, ground_size, normalize_dem)
    out = np.empty(_chw_shape(raw), dtype=_out_dtype(field, image_dtype))
    _finish(field, raw, out)
    return torch.from_numpy(out)


def _shared_empty(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """A tensor in shared memory (sent from a DataLoader worker without a copy)."""
    numel = int(np.prod(shape))
    try:
        empty = torch.empty(0, dtype=dtype)
        storage = empty._typed_storage()._new_shared(numel)  # as default_collate does
        return empty.set_(storage).view(shape)
    except (AttributeError, RuntimeError):  # private API moved: share afterwards instead
        return torch.empty(shape, dtype=dtype).share_memory_()


def _stacked_base(tensors: Sequence[torch.Tensor]) -> torch.Tensor | None:
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
    """Shard file descriptors, opened lazily and per process (safe under fork and spawn).

    At most ``max_open`` stay open (least recently used closed first), so datasets with many
    shards do not run out of descriptors. Reads are positioned (``preadv``): no seek state.
    """

    def __init__(self, root: Path, max_open: int = 64) -> None:
        self.root = root
        self.max_open = max_open
        self._pid = -1
        self._files: OrderedDict[str, int] = OrderedDict()

    def _fd(self, shard: str) -> int:
        if self._pid != os.getpid():  # inherited through fork: the parent's, leave them be
            self._files, self._pid = OrderedDict(), os.getpid()
        fd = self._files.get(shard)
        if fd is None:
            while len(self._files) >= self.max_open:
                os.close(self._files.popitem(last=False)[1])
            fd = self._files[shard] = os.open(self.root / shard, os.O_RDONLY)
        else:
            self._files.move_to_end(shard)
        return fd

    def read(self, shard: str, offset: int, size: int) -> bytearray:
        """``size`` bytes at ``offset``, into a fresh writable buffer."""
        fd = self._fd(shard)
        buf = bytearray(size)
        view, done = memoryview(buf), 0
        while done < size:
            if hasattr(os, "preadv"):
                n = os.preadv(fd, [view[done:]], offset + done)
            else:  # no positioned reads (Windows)
                os.lseek(fd, offset + done, os.SEEK_SET)
                chunk = os.read(fd, size - done)
                view[done : done + len(chunk)] = chunk
                n = len(chunk)
            if n <= 0:
                raise OSError(f"{self.root / shard}: short read at offset {offset}")
            done += n
        return buf

    def close(self) -> None:
        """Close this process's descriptors."""
        if self._pid == os.getpid():
            for fd in self._files.values():
                os.close(fd)
        self._files = OrderedDict()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def __getstate__(self) -> dict[str, Any]:
        return {"root": self.root, "max_open": self.max_open, "_pid": -1, "_files": {}}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state, _files=OrderedDict())


# -- map-style ---------------------------------------------------------------------------------
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
        self._dtypes = {f: _out_dtype(f, image_dtype) for f in self.fields}
        self.image_dtype = image_dtype
        manifest = Manifest.open(self.root).filter(**filters)
        columns = list(META_COLUMNS)
        for name in self.fields:
            columns += [f"{name}_shard", f"{name}_offset", f"{name}_size"]
        table = manifest.to_table(columns=list(dict.fromkeys(columns)))
        self._index = MemberIndex(table, self.fields, META_COLUMNS)
        self._files = _ShardFiles(self.root)
        self._transport = TransportBuffers()

    def __len__(self) -> int:
        return len(self._index)

    def _raw(self, index: int) -> dict[str, np.ndarray]:
        raw = {}
        for name in self.fields:
            data = self._files.read(*self._index.location(index, name))
            raw[name] = _decode_raw(name, data, self.ground_size, self.normalize_dem)
        return raw

    def _finish_sample(self, tensors: dict[str, torch.Tensor], meta: dict) -> dict[str, Any]:
        sample: dict[str, Any] = dict(tensors)
        sample["meta"] = meta
        return self.transform(sample) if self.transform is not None else sample

    def __getitem__(self, index: int) -> dict[str, Any]:
        """Sample ``index``. Inside a DataLoader worker (without ``transform``) float32 image
        fields are :class:`~mars_pairs.lazy_float.Uint8AsFloat32`, so they cross to the main
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
        out = np.empty(_chw_shape(raw), dtype=np.uint8 if lazy else self._dtypes[field])
        _finish(field, raw, out)
        tensor = torch.from_numpy(out)
        return Uint8AsFloat32(tensor, _UINT8_DIVISORS[field]) if lazy else tensor

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """A batch of samples (the DataLoader's batched fetch).

        Members are decoded to compact arrays first; each field whose shapes agree across the
        batch is then converted into one [B, C, H, W] buffer whose rows are the samples'
        tensors, so ``collate_samples`` hands it on without another copy. Inside a DataLoader
        worker the buffers are in shared memory, and float32 image fields (without a
        ``transform``) are :class:`~mars_pairs.lazy_float.Uint8AsFloat32` rows of a uint8
        buffer: a quarter of the bytes to the main process, where they arrive as float32.
        """
        raws = [self._raw(int(i)) for i in indices]
        in_worker = get_worker_info() is not None
        tensors: list[dict[str, torch.Tensor]] = [{} for _ in raws]
        for name in self.fields:
            shapes = {_chw_shape(r[name]) for r in raws}
            dtype = self._dtypes[name]
            lazy = self._lazy(name, in_worker)
            if len(shapes) == 1:
                shape = (len(raws), *shapes.pop())
                if lazy:  # a reused buffer: no fresh shared memory in the steady state
                    batch = self._transport.empty(shape)
                elif in_worker:
                    batch = _shared_empty(shape, _TORCH_DTYPES[dtype])
                else:  # numpy reuses freed memory; torch.empty page-faults it in anew
                    batch = torch.from_numpy(np.empty(shape, dtype=dtype))
                for j, r in enumerate(raws):
                    _finish(name, r[name], batch[j].numpy())  # uint8: viewshed {0, 1}
                    tensors[j][name] = (
                        Uint8AsFloat32(batch[j], _UINT8_DIVISORS[name], pooled=True)
                        if lazy
                        else batch[j]
                    )
            else:  # sizes differ (no ground_size): a tensor each
                for j, r in enumerate(raws):
                    tensors[j][name] = self._tensor(name, r[name], lazy)
        metas = self._index.metas([int(i) for i in indices])
        return [self._finish_sample(t, m) for t, m in zip(tensors, metas, strict=True)]


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
        base = _stacked_base([t.uint8 for t in lazy])
        pooled = base is not None and all(t.pooled for t in lazy)
        if base is None:
            base = default_collate([t.uint8 for t in lazy])
        return Uint8AsFloat32(base, lazy[0].divisor, pooled=pooled).stacked_from(lazy)
    base = _stacked_base(tensors)
    return base if base is not None else default_collate(tensors)
