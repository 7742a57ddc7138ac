"""Batching samples: tensors stacked (or handed on as the buffer they view), meta as lists.

A sample's ``meta`` never holds None, so torch's ``default_collate`` batches it (numbers to
[B] tensors, strings to lists): a value the manifest lacks (a label without a sol, a site or
drive, a sample with nothing visible) is NaN in a float column, :data:`MISSING_INT` (-1) in
an integer column (sol, site, drive, visible_cells) and ``""`` in a string column."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pyarrow as pa
import torch
from torch.utils.data import default_collate

from mars_pairs.torch.transport import stacked_base

#: a missing integer meta value (sol, site, drive and counts are never negative)
MISSING_INT = -1


def fill_missing_meta(table: pa.Table, columns: Sequence[str]) -> pa.Table:
    """``table`` with the nulls of its meta ``columns`` replaced by the sentinels a ``meta``
    value has for a missing value (NaN for floats, :data:`MISSING_INT` for integers, ``""``
    for strings), so every sample's meta collates with ``default_collate``; columns of other
    types stay as they are."""
    for name in columns:
        k = table.schema.get_field_index(name)
        column = table.column(k)
        if column.null_count == 0:
            continue
        kind = column.type
        if pa.types.is_floating(kind):
            fill: Any = float("nan")
        elif pa.types.is_integer(kind):
            fill = MISSING_INT
        elif pa.types.is_string(kind) or pa.types.is_large_string(kind):
            fill = ""
        else:
            continue
        table = table.set_column(k, name, column.fill_null(pa.scalar(fill, kind)))
    return table


def batch_layout(batch: Sequence[dict[str, Any]]) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """Field -> (shape, dtype) of the [B, ...] tensor each stackable field collates to."""
    layout = {}
    for key in batch[0]:
        values = [b[key] for b in batch]
        if key == "meta" or not all(isinstance(v, torch.Tensor) for v in values):
            continue
        if len({(v.shape, v.dtype) for v in values}) == 1:
            layout[key] = ((len(values), *values[0].shape), values[0].dtype)
    return layout


def collate_samples(
    batch: Sequence[dict[str, Any]], *, into: Mapping[str, torch.Tensor] | None = None
) -> dict[str, Any]:
    """Stack tensors of a batch; ``meta`` becomes a dict of lists, other values lists.

    Rows of one batch buffer (from ``MarsPairsDataset.__getitems__``) are returned as that
    buffer, without a copy; other tensors are stacked with ``default_collate``, which in a
    DataLoader worker writes the batch straight into shared memory. ``into`` (field ->
    [B, ...] tensor, of :func:`batch_layout`'s shapes) receives the stacked fields instead.
    Tensors whose shapes differ across the batch (ground images without ``ground_size``)
    stay a list.
    """
    out: dict[str, Any] = {}
    for key in batch[0]:
        values = [b[key] for b in batch]
        if key == "meta":
            out["meta"] = {k: [m[k] for m in values] for k in values[0]}
        elif all(isinstance(v, torch.Tensor) for v in values):
            target = None if into is None else into.get(key)
            out[key] = _collate_tensors(values, target)
        else:
            out[key] = values
    return out


def _collate_tensors(
    tensors: list[torch.Tensor], target: torch.Tensor | None = None
) -> torch.Tensor | list[torch.Tensor]:
    """One field's [B, ...] batch: written into ``target`` if given, else the buffer the rows
    view (no copy), else a stack (into shared memory inside a worker); a list when the
    shapes differ."""
    if len({t.shape for t in tensors}) > 1:
        return tensors
    base = stacked_base(tensors)
    if target is None:
        return base if base is not None else default_collate(tensors)
    if base is not None:
        target.copy_(base)
    else:
        torch.stack(tensors, out=target)
    return target


def batch_size_of(batch: Mapping[str, Any]) -> int | None:
    """The number of samples of a collated batch (``collate_samples`` or torch's
    ``default_collate``), None for a single sample: a batch's images are [B, C, H, W] (or a
    list of [C, H, W], sizes differing) and its ``meta`` a dict of lists or tensors."""
    for name in ("ground", "ortho", "dem", "viewshed", "corr"):
        value = batch.get(name)
        if isinstance(value, torch.Tensor):
            return int(value.shape[0]) if value.ndim == 4 else None
        if isinstance(value, list):
            return len(value)
    meta = batch.get("meta")
    if isinstance(meta, Mapping) and meta:
        first = next(iter(meta.values()))
        if isinstance(first, (list, tuple)) or (
            isinstance(first, torch.Tensor) and first.ndim == 1
        ):
            return len(first)
    return None


def _item(value: Any) -> Any:
    """A meta value of one sample as plain Python (a 0-d tensor of default_collate's -> item)."""
    if isinstance(value, torch.Tensor) and value.ndim == 0:
        return value.item()
    return value


def unbind_samples(batch: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The samples of a collated batch, as ``ds[i]`` returns them (torchgeo's
    ``unbind_samples``): every [B, ...] tensor unbound along its first dimension, every list
    split, ``meta`` (a dict of lists or of [B] tensors) one dict per sample; values that are
    the same for the whole batch (a string) repeated. A single sample is returned as
    ``[sample]``."""
    n = batch_size_of(batch)
    if n is None:
        return [dict(batch)]
    samples: list[dict[str, Any]] = [{} for _ in range(n)]
    for key, value in batch.items():
        if key == "meta" and isinstance(value, Mapping):
            for j in range(n):
                samples[j]["meta"] = {k: _item(v[j]) for k, v in value.items()}
            continue
        if isinstance(value, torch.Tensor) and value.ndim >= 1 and value.shape[0] == n:
            parts: Sequence[Any] = value.unbind(0)
        elif isinstance(value, (list, tuple)) and len(value) == n:
            parts = value
        else:
            parts = [value] * n
        for j in range(n):
            samples[j][key] = parts[j]
    return samples
