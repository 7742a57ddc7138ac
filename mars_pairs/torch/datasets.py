"""Torch datasets over a built mars-pairs dataset: map-style and streaming.

Samples are dicts (torchgeo style). Images are uint8 by default, the transport DataLoader
workers send best (convert with :class:`~mars_pairs.torch.transforms.ToFloat`, in a collate
function or on the GPU): ``ground`` uint8 [3, H, W], ``ortho`` uint8 [1, h, w], ``viewshed``
uint8 [1, h, w] in {0, 1}; with ``image_dtype=torch.float32`` they are float32 in [0, 1].
``dem`` float32 [1, h, w] (metres above the areoid, or normalised); ``corr`` float32
[2, H/k, W/k] and ``corr_ground`` float32 [2, H/k, W/k], the keypoints (chip pixel and
ground pixel of each strided ray, NaN for no hit); ``crs``, ``bounds``, ``transform`` and
``rotation`` place the chips on the map (:mod:`mars_pairs.torch.georef`); ``meta`` holds
plain Python values of the manifest row, a missing one NaN (floats), -1 (integers) or ``""``
(strings), never None, so torch's ``default_collate`` batches samples
(:mod:`mars_pairs.torch.collate`).

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
from collections import Counter
from collections.abc import Sequence
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
from mars_pairs.store.dense_codec import version_suffixes
from mars_pairs.store.filter_args import sample_index
from mars_pairs.store.fs import Location, dataset_root, join
from mars_pairs.store.integrity import MemberSpec, check_member, repeated_keys
from mars_pairs.store.manifest import SUMMARY_COLUMNS
from mars_pairs.store.member_index import MemberIndex
from mars_pairs.store.members import DENSE_GROUND_FIELDS, MEMBERS
from mars_pairs.store.query import Manifest
from mars_pairs.store.seal import require_sealed
from mars_pairs.torch.collate import fill_missing_meta
from mars_pairs.torch.decode import (
    ALL_FIELDS,  # noqa: F401  (re-exported)
    DEFAULT_FIELDS,  # noqa: F401  (re-exported)
    IMAGE_FIELDS,
    MEMBER_SUFFIXES,
    chw_shape,
    decode_raw,
    finish_chw,
    out_dtype,
)
from mars_pairs.torch.files import ShardFiles
from mars_pairs.torch.georef import GEO_COLUMNS, chip_transform, corr_ground_grid
from mars_pairs.torch.options import DatasetOptions
from mars_pairs.torch.transport import batch_empty, batch_start

META_COLUMNS = SUMMARY_COLUMNS


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


def _split_counts(table: pa.Table) -> dict[str, int]:
    """Split name -> rows, the usual splits first (train, val, test, buffer), then the others
    by name."""
    counts = {str(k): int(v) for k, v in Counter(table["split"].to_pylist()).items()}
    usual = [s for s in ("train", "val", "test", "buffer") if s in counts]
    return {s: counts[s] for s in [*usual, *sorted(set(counts) - set(usual))]}


def describe_dataset(ds: MarsPairsDataset, name: str) -> list[str]:
    """The lines of a dataset's ``repr``: its class, folder, rows by split, fields, sizes."""
    splits = ", ".join(f"{k} {v}" for k, v in ds.split_counts.items()) or "none"
    opts = ds.options
    if "ground" not in opts.fields:
        ground = "not read"
    elif opts.pad and "ground" in ds._pad_hw:
        h, w = ds._pad_hw["ground"]
        how = "resized and padded" if opts.ground_size else "padded (largest frame)"
        ground = f"{how} to {h} x {w}, with ground_mask"
    elif opts.ground_size:
        ground = f"resized to {opts.ground_size[0]} x {opts.ground_size[1]}"
    else:
        ground = "native sizes (pad=False): batch with collate_samples"
    lines = [
        name,
        f"    root: {ds.root}",
        f"    rows: {len(ds)}",
        f"    splits: {splits}",
        f"    fields: {', '.join(opts.fields)}",
        f"    ground: {ground}",
        f"    images: {str(opts.image_dtype).replace('torch.', '')}"
        + (", localization targets" if opts.localization else "")
        + (", verified reads" if opts.verify else ""),
    ]
    if ds.filters:
        lines.append(f"    filters: {', '.join(f'{k}={v!r}' for k, v in ds.filters.items())}")
    if opts.transform is not None:
        lines.append(f"    transform: {opts.transform!r}")
    return lines


class MarsPairsDataset(Dataset[dict[str, Any]]):
    """Map-style dataset: ``ds[i]`` reads sample i's members with one seek each.

    ``options`` (:class:`~mars_pairs.torch.options.DatasetOptions`: fields, transform,
    ground_size, pad, normalize_dem, image_dtype, verify, localization), or its fields as
    keyword arguments (which override ``options``' values); the other keyword arguments are
    filters, those of :meth:`mars_pairs.Manifest.filter`. ``verify`` costs one extra 512-byte
    read per member (see the module docstring).
    A ``split`` the dataset does not know (dataset.json's split config and counts) is an
    ArgumentError listing the known ones; a known split without samples gives 0 rows.
    Use as a context manager, or call :meth:`close`. ``root`` is a local folder or an fsspec
    URL (``s3://bucket/prefix``: ``store.fs``; each member one range request).
    """

    def __init__(
        self, root: str | Path, options: DatasetOptions | None = None, **kwargs: Any
    ) -> None:
        opts, filters = DatasetOptions.split(options, kwargs)
        self.options = opts
        self.root = dataset_root(root)
        self.fields = opts.fields
        self.transform = opts.transform
        self.ground_size = opts.ground_size
        self.normalize_dem = opts.normalize_dem
        self._dtypes = {f: out_dtype(f, opts.image_dtype) for f in self.fields}
        self.image_dtype = opts.image_dtype
        self.filters = dict(filters)
        if opts.verify:  # dataset.json and the manifest against the folder's chain, once
            require_sealed(self.root)
        manifest = Manifest.open(self.root).filter(**filters)  # ManifestFilter's arguments
        info = read_dataset_info(self.root)
        self.crs: str = info.crs or manifest.crs or ""
        self.chip_px = info.chip_px
        self.ray_stride = info.ray_stride
        self.verify = opts.verify
        self.localization = opts.localization
        self.dense_stride = info.dense_stride
        self._suffixes = {**MEMBER_SUFFIXES, **version_suffixes(info.format_version)}
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
        meta = fill_missing_meta(table, META_COLUMNS)  # default_collate takes no None
        self._index = MemberIndex(meta, self._located, META_COLUMNS)
        self._geo = np.column_stack(
            [table[c].fill_null(np.nan).to_numpy().astype(np.float64) for c in GEO_COLUMNS]
        ).reshape(table.num_rows, len(GEO_COLUMNS))
        self._size = np.column_stack(
            [table[c].fill_null(0).to_numpy().astype(np.int64) for c in ("width", "height")]
        ).reshape(table.num_rows, 2)
        self._ground_member = (
            table["ground_member"].combine_chunks() if "ground_member" in names else None
        )
        heights, widths = self._size[:, 1], self._size[:, 0]
        #: (H, W) label pixels of the largest frame among this dataset's rows (None if empty)
        self.frame_hw: tuple[int, int] | None = (
            (int(heights.max()), int(widths.max())) if table.num_rows else None
        )
        self._pad_hw = self._pad_shapes() if opts.pad else {}
        self.split_counts = _split_counts(table)
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

    def __repr__(self) -> str:
        return "\n".join(describe_dataset(self, type(self).__name__))

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
            suffix = self._suffixes[field]
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
        """The bytes of sample ``index``'s fields (and ``meta`` with ``localization``), not
        checked: on object storage in one concurrent batch of range requests; in a local
        shard that holds them side by side (the builder writes a sample's members in a row)
        in one scatter read (:meth:`ShardFiles.read_adjacent`). {} where that cannot be done
        (a missing member, members apart): each member is then read as it is decoded."""
        names = [*self.fields, *(["meta"] if self.localization else [])]
        try:
            requests = [self._index.location(index, name) for name in names]
        except MissingMemberError:
            return {}
        if not self._files.remote:
            if len({shard for shard, _, _ in requests}) != 1:
                return {}
            order = sorted(range(len(names)), key=lambda k: requests[k][1])
            spans = [requests[k][1:] for k in order]
            try:
                datas = self._files.read_adjacent(requests[0][0], spans)
            except (DatasetError, OSError):  # read one by one: the error names the member
                return {}
            if datas is None:
                return {}
            return {names[k]: data for k, data in zip(order, datas, strict=True)}
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

    def _chip_size(self, raw: dict[str, np.ndarray]) -> int | None:
        """The chip's side in pixels: a decoded chip's, else dataset.json's (None or 0:
        unknown)."""
        size_px = self.chip_px
        for name in ("ortho", "dem", "viewshed"):
            if name in raw:
                size_px = raw[name].shape[0]
        return size_px

    def _placement(self, index: int, raw: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        """bounds, rotation and (with a known chip size) transform of sample ``index``."""
        xmin, ymin, xmax, ymax, rotation = (float(v) for v in self._geo[index])
        out = {
            "bounds": torch.tensor([xmin, ymin, xmax, ymax], dtype=torch.float64),
            "rotation": torch.tensor(rotation, dtype=torch.float64),
        }
        size_px = self._chip_size(raw)
        if size_px:
            affine = chip_transform((xmin, ymin, xmax, ymax), rotation, size_px)
            out["transform"] = torch.tensor(affine, dtype=torch.float64)
        return out

    def _placements(
        self, indices: Sequence[int], raws: Sequence[dict[str, np.ndarray]]
    ) -> list[dict[str, torch.Tensor]]:
        """:meth:`_placement` of several samples, equal to it: each field one [B, ...] tensor
        whose rows the samples hold (``collate_samples`` hands it on without a copy)."""
        geo = self._geo[np.asarray(indices, dtype=np.int64)]
        bounds = torch.from_numpy(np.ascontiguousarray(geo[:, :4]))
        rotation = torch.from_numpy(np.ascontiguousarray(geo[:, 4]))
        out = [{"bounds": bounds[j], "rotation": rotation[j]} for j in range(len(raws))]
        sizes = [self._chip_size(r) for r in raws]
        known = [size for size in sizes if size]
        if len(known) == len(sizes):
            affine = np.array(
                [
                    chip_transform((g[0], g[1], g[2], g[3]), g[4], size)
                    for g, size in zip(geo.tolist(), known, strict=True)
                ],
                dtype=np.float64,
            ).reshape(len(raws), 6)
            transform = torch.from_numpy(affine)
            for j, placed in enumerate(out):
                placed["transform"] = transform[j]
        else:  # a chip size unknown for some: those have no transform
            for j, (i, r) in enumerate(zip(indices, raws, strict=True)):
                if sizes[j]:
                    out[j]["transform"] = self._placement(i, r)["transform"]
        return out

    def _georef(
        self,
        index: int,
        raw: dict[str, np.ndarray],
        placed: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, Any]:
        """crs, bounds, transform, rotation (and corr_ground with corr) of sample ``index``;
        ``placed``: its :meth:`_placement`, made already."""
        out: dict[str, Any] = {"crs": self.crs}
        out.update(self._placement(index, raw) if placed is None else placed)
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
        made: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """The sample's dict; ``made`` (from ``__getitems__``): its ``meta``, its
        :meth:`_placement` and its ``ground_mask``, made for the whole batch already."""
        made = made or {}
        sample: dict[str, Any] = dict(tensors)
        if "ground_px" in sample and "ground" in raw:
            sample["ground_px"] = self._scaled_ground_px(index, sample["ground_px"], raw)
        sample.update(self._georef(index, raw, made.get("placed")))
        if self._pad_hw:
            self._padded(sample, raw, made.get("ground_mask"))
        sample.update(targets)
        sample["meta"] = made["meta"] if "meta" in made else self._index.meta(index)
        return self.transform(sample) if self.transform is not None else sample

    def _pad_shapes(self) -> dict[str, tuple[int, int]]:
        """Field -> the (H, W) every sample's tensor is padded to (``pad``): the ground image
        to ``ground_size`` or the largest frame; the keypoint and dense ground-grid fields to
        the largest frame's grid (one cell per ``stride`` label pixels, rounded up)."""
        if self.frame_hw is None:
            return {}
        fh, fw = self.frame_hw
        out = {"ground": self.ground_size or (fh, fw)}
        for stride, names in (
            (self.ray_stride, ("corr", "corr_ground")),
            (self.dense_stride, (*DENSE_GROUND_FIELDS, "dense_ground")),
        ):
            for name in names:
                out[name] = (-(-fh // stride), -(-fw // stride))
        return out

    def _padded_chw(self, index: int, field: str, raw: np.ndarray) -> tuple[int, int, int]:
        """The [C, H, W] shape of ``field``'s tensor: its own, or padded (``pad``)."""
        c, h, w = chw_shape(raw)
        target = self._pad_hw.get(field)
        if target is None:
            return c, h, w
        if h > target[0] or w > target[1]:
            shard = self._index.location(index, field)[0]
            raise DatasetError(
                join(self.root, shard),
                self.member_name(index, field),
                f"{h} x {w} cells, more than the {target[0]} x {target[1]} of the dataset's "
                f"largest frame {self.frame_hw} (manifest width, height)",
            )
        return c, target[0], target[1]

    def _write(self, index: int, field: str, raw: np.ndarray, out: np.ndarray) -> None:
        """``raw``'s [C, H, W] values into ``out`` (of ``_padded_chw``'s shape): the top-left
        corner; the rest NaN (float fields other than images) or 0."""
        _, h, w = chw_shape(raw)
        if out.shape[1:] != (h, w):
            floating = out.dtype.kind == "f" and field not in IMAGE_FIELDS
            out.fill(np.nan if floating else 0)
            out = out[:, :h, :w]
        finish_chw(field, raw, out)

    def _tensor(self, index: int, field: str, raw: np.ndarray) -> torch.Tensor:
        """One sample's [C, H, W] tensor of a stage-1 array (its own memory, padded with
        ``pad``)."""
        out = np.empty(self._padded_chw(index, field, raw), dtype=self._dtypes[field])
        self._write(index, field, raw, out)
        return torch.from_numpy(out)

    def _padded(
        self,
        sample: dict[str, Any],
        raw: dict[str, np.ndarray],
        ground_mask: torch.Tensor | None = None,
    ) -> None:
        """With ``pad``: ``corr_ground`` / ``dense_ground`` padded with NaN to their grids, and
        ``ground_mask`` (bool [1, H, W], True on the decoded image's own pixels; the one
        given, if given)."""
        for name in ("corr_ground", "dense_ground"):
            target = self._pad_hw.get(name)
            value = sample.get(name)
            if target is not None and value is not None and value.shape[1:] != target:
                grid = np.full((value.shape[0], *target), np.nan, dtype=value.numpy().dtype)
                grid[:, : value.shape[1], : value.shape[2]] = value.numpy()
                sample[name] = torch.from_numpy(grid)
        if ground_mask is not None:
            sample["ground_mask"] = ground_mask
        elif "ground" in raw and "ground" in self._pad_hw:
            # numpy, not torch: torch's fill and slice assignment start intra-op threads in
            # the main process (9 ms of CPU a sample at 2 threads on a busy box, against 0.05)
            h, w = raw["ground"].shape[:2]
            mask = np.zeros((1, *self._pad_hw["ground"]), dtype=np.bool_)
            mask[:, :h, :w] = True
            sample["ground_mask"] = torch.from_numpy(mask)

    def __getitem__(self, index: int) -> dict[str, Any]:
        """Sample ``index`` (negative indices count from the end)."""
        i = self._checked(index)
        raw, targets = self._raw(i)
        tensors = {name: self._tensor(i, name, r) for name, r in raw.items()}
        return self._finish_sample(tensors, i, raw, targets)

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """A batch of samples (the DataLoader's batched fetch).

        Members are decoded to compact arrays first; each field whose shapes agree across the
        batch is then converted into one [B, C, H, W] buffer whose rows are the samples'
        tensors, so ``collate_samples`` hands it on without another copy. The buffers are in
        this process's memory (numpy reuses freed pages, where fresh shared memory is the
        costly part of transport), except in a
        :class:`~mars_pairs.torch.loader.MarsPairsLoader` worker: there they lie in the
        shared-memory slot the batch is sent in (:func:`~mars_pairs.torch.transport.batch_empty`),
        so the batch reaches the main process without a copy.
        """
        batch_start()
        checked = [self._checked(i) for i in indices]
        read = [self._raw(i) for i in checked]
        raws = [r for r, _ in read]
        tensors: list[dict[str, torch.Tensor]] = [{} for _ in raws]
        for name in self.fields:
            shapes = {
                self._padded_chw(i, name, r[name]) for i, r in zip(checked, raws, strict=True)
            }
            dtype = self._dtypes[name]
            if len(shapes) == 1:
                shape = (len(raws), *shapes.pop())
                # this process's memory, or a loader worker's slot (see the docstring)
                batch = torch.from_numpy(batch_empty(shape, dtype))
                for j, (i, r) in enumerate(zip(checked, raws, strict=True)):
                    self._write(i, name, r[name], batch[j].numpy())
                    tensors[j][name] = batch[j]
            else:  # sizes differ (pad=False, no ground_size): a tensor each
                for j, (i, r) in enumerate(zip(checked, raws, strict=True)):
                    tensors[j][name] = self._tensor(i, name, r[name])
        made = self._batch_made(checked, raws)
        return [
            self._finish_sample(t, i, r, targets, m)
            for t, i, (r, targets), m in zip(tensors, checked, read, made, strict=True)
        ]

    def _batch_made(
        self, indices: Sequence[int], raws: Sequence[dict[str, np.ndarray]]
    ) -> list[dict[str, Any]]:
        """Per sample of a batch: its ``meta``, :meth:`_placement` and (with ``pad``) its
        ``ground_mask``, each made once for the batch (one Arrow ``take`` a meta column, one
        array a tensor field; the samples' tensors are rows of one [B, ...] tensor)."""
        made: list[dict[str, Any]] = [
            {"meta": meta, "placed": placed}
            for meta, placed in zip(
                self._index.metas(indices), self._placements(indices, raws), strict=True
            )
        ]
        target = self._pad_hw.get("ground")
        if target is not None and all("ground" in r for r in raws):
            # numpy, not torch (see _padded); in a loader worker's slot (batch_empty)
            mask = batch_empty((len(raws), 1, *target), np.dtype(np.bool_))
            mask.fill(False)
            for j, r in enumerate(raws):
                h, w = r["ground"].shape[:2]
                mask[j, :, :h, :w] = True
            masks = torch.from_numpy(mask)
            for j, m in enumerate(made):
                m["ground_mask"] = masks[j]
        return made

    def plot(
        self,
        sample: dict[str, Any],
        *,
        title: str | None = None,
        dense: bool = False,
        max_samples: int = 8,
    ) -> Any:
        """A matplotlib Figure (needs the ``viz`` extra) of one sample (as ``ds[i]`` returns
        it, transformed or not) or of a batch (a DataLoader's, collated by torch's
        ``default_collate`` or :func:`collate_samples`; split by :func:`unbind_samples`).

        One sample: the ground image, the ortho chip with the viewshed and the camera wedge,
        the DEM with a colourbar, and with ``corr`` the keypoints colour-linked; a legend and
        the sample's numbers (:func:`mars_pairs.viz.sample.sample_figure`). ``dense``: the
        figure of its dense members instead. A batch: its first ``max_samples`` samples, one
        column each, a row per field they hold (:func:`mars_pairs.viz.batch.batch_figure`).
        """
        from mars_pairs.torch.collate import batch_size_of, unbind_samples

        if batch_size_of(sample) is not None:
            from mars_pairs.viz.batch import batch_figure

            return batch_figure(unbind_samples(sample), title=title, max_samples=max_samples)
        from mars_pairs.viz.sample import dense_figure, sample_figure

        if dense:
            return dense_figure(sample, title=title)
        return sample_figure(sample, title=title)
