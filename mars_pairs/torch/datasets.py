"""Torch datasets over a built mars-pairs dataset: map-style and streaming.

Samples are dicts (torchgeo style). Images are uint8 by default, the transport DataLoader
workers send best (convert with :class:`~mars_pairs.torch.transforms.ToFloat`, in a collate
function or on the GPU): ``ground`` uint8 [3, H, W], ``ortho`` uint8 [1, h, w], ``viewshed``
uint8 [1, h, w] in {0, 1}; with ``image_dtype=torch.float32`` they are float32 in [0, 1].
``dem`` float32 [1, h, w] (metres above the areoid, or normalised); ``corr`` float32
[2, H/k, W/k] and ``corr_ground`` float32 [2, H/k, W/k], the keypoints (chip pixel and
ground pixel of each strided ray, NaN for no hit); ``crs``, ``bounds``, ``transform`` and
``rotation`` place the chips on the map (:mod:`mars_pairs.torch.georef`); ``meta`` holds
plain Python values of the manifest row.

Datasets built with ``output.members`` also give the dense fields (``store.members``, see
:mod:`mars_pairs.pipeline.sample.dense`): ``range``, ``depth`` and ``dem_view`` float32
[1, H', W'], ``hits`` float64 [3, H', W'] (map x, y, z), ``ortho_view`` and ``view_valid`` on
the ground image's dense grid, with ``dense_ground`` float32 [2, H', W'] (each cell's ground
pixel, as ``corr_ground``); ``ground_on_map`` [3, h, w], ``ground_on_map_cover`` and ``ground_px``
float32 [2, h, w] (the ground pixel of each chip pixel, for the decoded ground image's size)
on the chip grid. ``localization=True`` adds ``rover_px``, ``camera_px`` and ``heading_deg``
from ``meta.json`` (datasets built with ``chips.offset_m`` or ``output.members``).

Every error a user can catch is a :class:`~mars_pairs.errors.MarsPairsError`: a bad
argument an ArgumentError (also a TypeError / ValueError), a damaged shard or member a
DatasetError naming the shard and the member. A dataset opens only with its dataset.json
(the ray stride, CRS and chip size) and the manifest columns it reads. Every read stays
inside the dataset folder and inside the shard file. ``verify=True`` checks each sample it
reads as ``mars-pairs verify`` does (:mod:`mars_pairs.store.integrity`, the same code), after
checking dataset.json and the manifest against the folder's integrity chain once at open
(:func:`~mars_pairs.store.seal.require_sealed`): every member of the sample, requested or
not (``meta.json`` too), must lie inside its shard, follow a tar header naming
``<key>.<field>`` with the manifest's size, and match its CRC-32C where the manifest has
``<member>_crc32c`` columns; and no key may be on two manifest rows.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import torch
from torch.utils.data import Dataset

from mars_pairs.errors import (
    ArgumentError,
    DatasetError,
    MissingMemberError,
    SampleIndexError,
)
from mars_pairs.store.dataset_info import read_dataset_info
from mars_pairs.store.filter_args import check_split_names, configured_splits, sample_index
from mars_pairs.store.fs import Location, dataset_root, join
from mars_pairs.store.integrity import MemberSpec, check_member, repeated_keys
from mars_pairs.store.manifest import SUMMARY_COLUMNS
from mars_pairs.store.member_index import MemberIndex
from mars_pairs.store.members import DENSE_GROUND_FIELDS, MEMBERS
from mars_pairs.store.query import Manifest
from mars_pairs.store.seal import require_sealed
from mars_pairs.torch.decode import (
    ALL_FIELDS,  # noqa: F401  (re-exported)
    DEFAULT_FIELDS,
    KNOWN_FIELDS,
    MEMBER_SUFFIXES,
    chw_shape,
    decode_raw,
    finish_chw,
    out_dtype,
)
from mars_pairs.torch.files import ShardFiles
from mars_pairs.torch.georef import GEO_COLUMNS, chip_transform, corr_ground_grid

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


def _dense_stride(doc: dict[str, Any], ray_stride: int) -> int:
    """The dense members' stride from dataset.json (``output.dense_stride``; default the ray
    stride)."""
    output = doc.get("config", {}).get("output", {}) if isinstance(doc, dict) else {}
    value = output.get("dense_stride") if isinstance(output, dict) else None
    return value if isinstance(value, int) and value >= 1 else ray_stride


def _ground_size(value: int | Sequence[int] | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        if isinstance(value, (int, np.integer)):
            size = (int(value), int(value))
        else:
            h, w = value
            size = (int(h), int(w))
    except (TypeError, ValueError):
        raise ArgumentError(f"ground_size: expected an int or (H, W), got {value!r}") from None
    if min(size) < 1:
        raise ArgumentError(f"ground_size: sizes must be positive, got {value!r}")
    return size


def _check_fields(fields: Sequence[str]) -> tuple[str, ...]:
    if isinstance(fields, str):
        fields = (fields,)
    bad = [f for f in fields if f not in KNOWN_FIELDS]
    if bad or not fields:
        raise ArgumentError(
            f"fields: unknown field(s) {bad}; expected some of {list(KNOWN_FIELDS)}"
        )
    return tuple(fields)


def _refuse_duplicate_keys(root: Location, table: pa.Table) -> None:
    """DatasetError naming the manifest and the first key (in key order) that more than one
    row holds."""
    repeated = repeated_keys(table["key"])
    if repeated:
        key, count = repeated[0]
        raise DatasetError(
            join(root, "manifest.parquet"),
            key,
            f"{count} rows hold this key ({len(repeated)} keys repeated)",
        )


class MarsPairsDataset(Dataset):
    """Map-style dataset: ``ds[i]`` reads sample i's members with one seek each.

    Filter arguments are those of :meth:`mars_pairs.Manifest.filter`. ``ground_size`` (int or
    (H, W)) resizes ground images so they batch; ``normalize_dem`` subtracts each chip's
    median elevation. ``image_dtype`` is torch.uint8 (default) or torch.float32 (images in
    [0, 1]). ``transform`` is applied to the sample dict (see
    :mod:`mars_pairs.torch.transforms`). ``verify`` checks every member of each sample read
    (tar header, size, CRC-32C; see the module docstring): one extra 512-byte read per member.
    A ``split`` the dataset does not know (dataset.json's split config and counts) is an
    ArgumentError listing the known ones; a known split without samples gives 0 rows.
    Use as a context manager, or call :meth:`close`. ``root`` is a local folder or an fsspec
    URL (``s3://bucket/prefix``: ``store.fs``; each member one range request).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        fields: Sequence[str] = DEFAULT_FIELDS,
        transform: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
        ground_size: int | Sequence[int] | None = None,
        normalize_dem: bool = False,
        image_dtype: torch.dtype = torch.uint8,
        verify: bool = False,
        localization: bool = False,
        **filters: Any,
    ) -> None:
        unknown = set(filters) - set(FILTER_KEYS)
        if unknown:
            raise ArgumentError(f"unknown filter argument(s) {sorted(unknown)}")
        if transform is not None and not callable(transform):
            raise ArgumentError(f"transform: expected a callable, got {transform!r}")
        self.root = dataset_root(root)
        self.fields = _check_fields(fields)
        self.transform = transform
        self.ground_size = _ground_size(ground_size)
        self.normalize_dem = bool(normalize_dem)
        self._dtypes = {f: out_dtype(f, image_dtype) for f in self.fields}
        self.image_dtype = image_dtype
        if verify:  # dataset.json and the manifest against the folder's chain, once
            require_sealed(self.root)
        manifest = Manifest.open(self.root).filter(**filters)
        info = read_dataset_info(self.root)
        check_split_names(filters.get("split"), configured_splits(info.doc), str(self.root))
        self.crs: str = info.crs or manifest.crs or ""
        self.chip_px = info.chip_px
        self.ray_stride = info.ray_stride
        self.verify = bool(verify)
        self.localization = bool(localization)
        self.dense_stride = _dense_stride(info.doc, self.ray_stride)
        # verify=True checks every member of a sample read, like `mars-pairs verify`
        located = (*MEMBERS, *self.fields) if self.verify else self.fields
        if self.localization:
            located = (*located, "meta")
        self._located = tuple(dict.fromkeys(located))
        locations = [f"{m}_{s}" for m in self._located for s in ("shard", "offset", "size")]
        required = [*META_COLUMNS, *GEO_COLUMNS, "width", "height", *locations]
        manifest.require(required)
        names = set(manifest.column_names)
        crc_fields = tuple(m for m in self._located if f"{m}_crc32c" in names and self.verify)
        if self.verify and len(crc_fields) < len(self._located):
            missing = [m for m in self._located if m not in crc_fields]
            warnings.warn(
                f"{self.root}: the manifest has no checksums of {missing} (built before "
                "checksums): verify=True checks the others only",
                stacklevel=2,
            )
        columns = [*required, *(["ground_member"] if "ground_member" in names else [])]
        columns += [f"{m}_crc32c" for m in crc_fields]
        table = manifest.to_table(columns=list(dict.fromkeys(columns)))
        if self.verify:
            _refuse_duplicate_keys(self.root, table)
        self._index = MemberIndex(table, self._located, META_COLUMNS)
        self._geo = np.column_stack(
            [table[c].fill_null(np.nan).to_numpy().astype(np.float64) for c in GEO_COLUMNS]
        ).reshape(table.num_rows, len(GEO_COLUMNS))
        self._size = np.column_stack(
            [table[c].fill_null(0).to_numpy().astype(np.int64) for c in ("width", "height")]
        ).reshape(table.num_rows, 2)
        self._ground_member = (
            table["ground_member"].combine_chunks() if "ground_member" in names else None
        )
        self._crc = {
            m: table[f"{m}_crc32c"].fill_null(-1).to_numpy().astype(np.int64) for m in crc_fields
        }
        self._files = ShardFiles(self.root)

    # -- life cycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Close the shard files this process opened (the dataset reopens them on use)."""
        self._files.close()

    def __enter__(self) -> MarsPairsDataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self._index)

    def shard_order(self, field: str | None = None) -> dict[str, np.ndarray]:
        """Each shard's sample indices (int64, into this dataset) in the order ``field``'s
        members (default the first of ``fields``) lie in the shard file; shards as the
        manifest names them (relative to ``root``). ``field``: one this dataset reads."""
        field = self.fields[0] if field is None else field
        if field not in self._located:
            raise ArgumentError(f"shard_order: {field!r} is not read; one of {self._located}")
        return self._index.shard_order(field)

    def index_of(self, key: str) -> int:
        """The index of the sample named by ``key``: its key or its product id, in any case
        (SampleKeyError, a KeyError too, if absent; see ``filter_args.sample_index``)."""
        ids = self._index.column("product_id")
        return sample_index(key, self._index.column("key"), ids, str(self.root))

    def _checked(self, index: Any) -> int:
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            if (
                isinstance(index, torch.Tensor)
                and index.numel() == 1
                and not index.is_floating_point()
            ):
                index = int(index)
            else:
                raise ArgumentError(f"dataset index: expected an int, got {index!r}")
        i, n = int(index), len(self)
        if not -n <= i < n:
            raise SampleIndexError(f"dataset index {i} out of range for {n} samples")
        return i % n

    # -- reading ------------------------------------------------------------------------------
    def member_name(self, index: int, field: str) -> str:
        """The tar member name (``<key>.<suffix>``) of sample ``index``'s ``field``."""
        key = self._index.meta_value(index, "key")
        if field == "ground" and self._ground_member is not None:
            suffix = self._ground_member[index].as_py() or "ground"
        else:
            suffix = MEMBER_SUFFIXES[field]
        return f"{key}.{suffix}"

    def _bytes(self, index: int, field: str) -> bytearray:
        """The bytes of sample ``index``'s ``field`` member (not checked)."""
        shard, offset, size = self._index.location(index, field)
        try:
            return self._files.read(shard, offset, size)
        except DatasetError as exc:  # a shard path outside the dataset, a read past its end
            raise DatasetError(exc.path, self.member_name(index, field), exc.reason) from None
        except OSError as exc:
            name = self.member_name(index, field)
            raise DatasetError(join(self.root, shard), name, f"cannot read: {exc}") from None

    def _prefetched(self, index: int) -> dict[str, bytes | bytearray]:
        """On object storage, the bytes of sample ``index``'s fields (and ``meta`` with
        ``localization``) in one concurrent batch of range requests (not checked); {} for a
        local dataset (each member is read as it is decoded)."""
        if not self._files.remote:
            return {}
        names = [*self.fields, *(["meta"] if self.localization else [])]
        requests = [self._index.location(index, name) for name in names]
        try:
            datas = self._files.read_many(requests)
        except (DatasetError, OSError):  # read one by one: the error names the member
            return {}
        return dict(zip(names, datas, strict=True))

    def _verified(self, index: int) -> dict[str, bytes | bytearray]:
        """Every member of sample ``index`` checked as ``mars-pairs verify`` does
        (:func:`~mars_pairs.store.integrity.check_member`); the bytes of ``self.fields``
        (and of ``meta`` with ``localization``)."""
        key = self._index.meta_value(index, "key")
        ground = self._ground_member[index].as_py() if self._ground_member is not None else None
        wanted = (*self.fields, "meta") if self.localization else self.fields
        out: dict[str, bytes | bytearray] = {}
        for field in self._located:
            try:
                shard, offset, size = self._index.location(index, field)
            except MissingMemberError:
                if field in wanted:
                    raise
                continue  # a sample without this member: nothing to check
            name = self.member_name(index, field)
            crc = self._crc.get(field)
            spec = MemberSpec(
                key, field, offset, size, None if crc is None else int(crc[index]), ground
            )
            try:
                data, problem = check_member(
                    spec,
                    partial(self._files.read, shard),
                    self._files.size(shard),
                )
            except DatasetError as exc:
                raise DatasetError(exc.path, name, exc.reason) from None
            except OSError as exc:
                raise DatasetError(join(self.root, shard), name, f"cannot read: {exc}") from None
            if problem is not None:
                raise DatasetError(join(self.root, shard), name, problem)
            if field in wanted:
                assert data is not None  # check_member: the bytes when there is no problem
                out[field] = data
        return out

    def _raw(self, index: int) -> tuple[dict[str, np.ndarray], dict[str, torch.Tensor]]:
        """Sample ``index``'s fields decoded (stage 1) and its localization targets (none
        without ``localization``); every member read once."""
        raw = {}
        verified = self._verified(index) if self.verify else self._prefetched(index)
        for name in self.fields:
            data = verified[name] if name in verified else self._bytes(index, name)
            try:
                raw[name] = decode_raw(name, data, self.ground_size, self.normalize_dem)
            except (OSError, ValueError, SyntaxError, EOFError) as exc:  # PIL, numpy headers
                shard = self._index.location(index, name)[0]
                raise DatasetError(
                    join(self.root, shard),
                    self.member_name(index, name),
                    f"cannot decode: {type(exc).__name__}: {exc}",
                ) from None
        if not self.localization:
            return raw, {}
        meta = verified["meta"] if "meta" in verified else self._bytes(index, "meta")
        return raw, self._localization(index, meta)

    def _georef(self, index: int, raw: dict[str, np.ndarray]) -> dict[str, Any]:
        """crs, bounds, transform, rotation (and corr_ground with corr) of sample ``index``."""
        xmin, ymin, xmax, ymax, rotation = (float(v) for v in self._geo[index])
        size_px = self.chip_px
        for name in ("ortho", "dem", "viewshed"):
            if name in raw:
                size_px = raw[name].shape[0]
        out: dict[str, Any] = {
            "crs": self.crs,
            "bounds": torch.tensor([xmin, ymin, xmax, ymax], dtype=torch.float64),
            "rotation": torch.tensor(rotation, dtype=torch.float64),
        }
        if size_px:
            affine = chip_transform((xmin, ymin, xmax, ymax), rotation, size_px)
            out["transform"] = torch.tensor(affine, dtype=torch.float64)
        if "corr" in raw:
            width, height = (int(v) for v in self._size[index])
            if "ground" in raw:
                ground_hw = raw["ground"].shape[:2]
            else:
                ground_hw = self.ground_size or (height, width)
            grid = corr_ground_grid(
                raw["corr"].shape[:2], self.ray_stride, (width, height), ground_hw
            )
            out["corr_ground"] = torch.from_numpy(grid)
        dense = next((f for f in DENSE_GROUND_FIELDS if f in raw), None)
        if dense is not None:
            width, height = (int(v) for v in self._size[index])
            ground_hw = raw["ground"].shape[:2] if "ground" in raw else (height, width)
            grid = corr_ground_grid(
                raw[dense].shape[:2], self.dense_stride, (width, height), ground_hw
            )
            out["dense_ground"] = torch.from_numpy(grid)
        return out

    def _scaled_ground_px(
        self, index: int, ground_px: torch.Tensor, raw: dict[str, np.ndarray]
    ) -> torch.Tensor:
        """``ground_px`` (label image pixels, centres at integers) re-expressed for the decoded
        ground image's size (``ground_size``): x' + 0.5 = (x + 0.5) * scale."""
        width, height = (int(v) for v in self._size[index])
        h, w = raw["ground"].shape[:2]
        if (h, w) == (height, width) or not (width and height):
            return ground_px
        scale = torch.tensor([w / width, h / height], dtype=ground_px.dtype)[:, None, None]
        return (ground_px + 0.5) * scale - 0.5

    def _localization(self, index: int, data: bytes | bytearray) -> dict[str, torch.Tensor]:
        """rover_px, camera_px ([2] chip column, row, pixel-edge) and heading_deg (clockwise
        from the chip's up) of sample ``index``, from its meta.json's bytes ``data``."""
        try:
            meta = json.loads(bytes(data))
            values = {k: meta[k] for k in ("rover_px", "camera_px", "heading_deg")}
        except (ValueError, KeyError) as exc:
            raise DatasetError(
                join(self.root, self._index.location(index, "meta")[0]),
                self.member_name(index, "meta"),
                f"no localization targets ({exc}): build with chips.offset_m or output.members",
            ) from None
        return {k: torch.tensor(v, dtype=torch.float64) for k, v in values.items()}

    def _finish_sample(
        self,
        tensors: dict[str, torch.Tensor],
        index: int,
        raw: dict[str, np.ndarray],
        targets: dict[str, torch.Tensor],
    ) -> dict[str, Any]:
        sample: dict[str, Any] = dict(tensors)
        if "ground_px" in sample and "ground" in raw:
            sample["ground_px"] = self._scaled_ground_px(index, sample["ground_px"], raw)
        sample.update(self._georef(index, raw))
        sample.update(targets)
        sample["meta"] = self._index.meta(index)
        return self.transform(sample) if self.transform is not None else sample

    def _tensor(self, field: str, raw: np.ndarray) -> torch.Tensor:
        """One sample's [C, H, W] tensor of a stage-1 array (its own memory)."""
        out = np.empty(chw_shape(raw), dtype=self._dtypes[field])
        finish_chw(field, raw, out)
        return torch.from_numpy(out)

    def __getitem__(self, index: int) -> dict[str, Any]:
        """Sample ``index`` (negative indices count from the end)."""
        i = self._checked(index)
        raw, targets = self._raw(i)
        tensors = {name: self._tensor(name, r) for name, r in raw.items()}
        return self._finish_sample(tensors, i, raw, targets)

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """A batch of samples (the DataLoader's batched fetch).

        Members are decoded to compact arrays first; each field whose shapes agree across the
        batch is then converted into one [B, C, H, W] buffer whose rows are the samples'
        tensors, so ``collate_samples`` hands it on without another copy. The buffers are in
        this process's memory, also in a DataLoader worker (numpy reuses freed pages, where
        fresh shared memory is the costly part of transport): the worker's collate stage moves
        the batch to shared memory, into a recycled slot under
        :class:`~mars_pairs.torch.loader.MarsPairsLoader`.
        """
        checked = [self._checked(i) for i in indices]
        read = [self._raw(i) for i in checked]
        raws = [r for r, _ in read]
        tensors: list[dict[str, torch.Tensor]] = [{} for _ in raws]
        for name in self.fields:
            shapes = {chw_shape(r[name]) for r in raws}
            dtype = self._dtypes[name]
            if len(shapes) == 1:
                shape = (len(raws), *shapes.pop())
                # private memory, also in a worker (see the docstring); the collate stage
                # writes the batch into shared memory
                batch = torch.from_numpy(np.empty(shape, dtype=dtype))
                for j, r in enumerate(raws):
                    finish_chw(name, r[name], batch[j].numpy())
                    tensors[j][name] = batch[j]
            else:  # sizes differ (no ground_size): a tensor each
                for j, r in enumerate(raws):
                    tensors[j][name] = self._tensor(name, r[name])
        return [
            self._finish_sample(t, i, r, targets)
            for t, i, (r, targets) in zip(tensors, checked, read, strict=True)
        ]

    def plot(self, sample: dict[str, Any], *, title: str | None = None, dense: bool = False) -> Any:
        """A matplotlib Figure of one sample (as returned by ``ds[i]``, transformed or not):
        the ground image, the ortho chip with the viewshed and the camera wedge, the DEM as a
        hillshade and the keypoints, colour-linked (needs the ``viz`` extra). ``dense``: the
        figure of its dense members instead (range, depth, the map seen from the rover, the
        ground image laid on the map)."""
        from mars_pairs.viz.sample import dense_figure, sample_figure

        if dense:
            return dense_figure(sample, title=title)
        return sample_figure(sample, title=title)
