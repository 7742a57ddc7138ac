"""Where each selected sample's members are, held in columns rather than one dict per row.

A dataset of a million samples as a list of row dicts is ~3 GB of Python objects, ~10 s to
build, a ~400 MB pickle for every spawned DataLoader worker, and it grows in forked workers as
reference counting writes to the shared pages. Here the member locations are numpy arrays
(shard code, offset, size per field) and the ``meta`` values an Arrow table: ~0.3 GB for a
million rows, pickled as buffers, never written after construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from mars_pairs.errors import MissingMemberError
from mars_pairs.store.columns import SampleMeta


class MemberIndex:
    """Member locations of ``fields`` and the ``meta_columns`` of a manifest table's rows.

    ``table`` holds, for each field, ``<field>_shard`` (path relative to the dataset root),
    ``<field>_offset`` and ``<field>_size`` (bytes of the member's data in that file), and the
    meta columns. A null location (a sample without that member) raises MissingMemberError
    (a KeyError too).
    """

    def __init__(self, table: pa.Table, fields: Sequence[str], meta_columns: Sequence[str]) -> None:
        self.fields = tuple(fields)
        self._length: int = table.num_rows
        meta = table.select(list(meta_columns)).combine_chunks()
        self._meta_columns = [
            (name, column.chunk(0) if column.num_chunks == 1 else column)
            for name, column in zip(meta.column_names, meta.columns, strict=True)
        ]
        self._names = {name: k for k, (name, _) in enumerate(self._meta_columns)}
        self._shards: dict[str, list[str]] = {}
        self._columns: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for field in self.fields:
            encoded = pc.dictionary_encode(table[f"{field}_shard"].combine_chunks())
            codes = encoded.indices.fill_null(-1).to_numpy().astype(np.int32)
            offsets = table[f"{field}_offset"].fill_null(-1).to_numpy().astype(np.int64)
            sizes = table[f"{field}_size"].fill_null(-1).to_numpy().astype(np.int64)
            self._shards[field] = encoded.dictionary.to_pylist()
            self._columns[field] = (codes, offsets, sizes)

    def __len__(self) -> int:
        return self._length

    def location(self, index: int, field: str) -> tuple[str, int, int]:
        """(shard, offset, size) of sample ``index``'s ``field`` member."""
        codes, offsets, sizes = self._columns[field]
        code, offset, size = int(codes[index]), int(offsets[index]), int(sizes[index])
        if code < 0 or offset < 0 or size < 0:
            key = self.meta_value(index, "key") if "key" in self._names else index
            raise MissingMemberError("manifest.parquet", f"{key}.{field}", "no such member")
        return self._shards[field][code], offset, size

    def column(self, name: str) -> pa.Array:
        """One meta column (all rows)."""
        return self._meta_columns[self._names[name]][1]

    def meta_value(self, index: int, name: str) -> Any:
        """One meta value of sample ``index``."""
        return self.column(name)[index].as_py()

    def meta(self, index: int) -> dict[str, Any]:
        """The meta values of sample ``index`` as plain Python values (~30 us: one scalar a
        column; a one-row slice of the table costs 4x that)."""
        return SampleMeta((name, column[index].as_py()) for name, column in self._meta_columns)

    def metas(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """The meta values of several samples (one :meth:`meta` each: an Arrow ``take`` a
        column and ``to_pylist`` cost more for a batch of 8)."""
        return [self.meta(int(i)) for i in indices]

    def shard_order(self, field: str) -> dict[str, np.ndarray]:
        """Each shard's sample indices in file order (by ``field``'s offsets)."""
        codes, offsets, _ = self._columns[field]
        order = np.lexsort((offsets, codes))
        bounds = np.searchsorted(codes[order], np.arange(len(self._shards[field]) + 1))
        return {
            shard: order[bounds[k] : bounds[k + 1]]
            for k, shard in enumerate(self._shards[field])
            if bounds[k + 1] > bounds[k]
        }
