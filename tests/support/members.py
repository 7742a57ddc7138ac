"""THE readers of a finished dataset's tar members and manifest keys, independent of the
package's own readers: members through ``tarfile``, rows through ``pyarrow.parquet``, the
DEM chip's TIFF through GDAL (rasterio), which applies the scale, offset and no-data value the
file carries.

``root`` is a dataset folder (``shards/*.tar``, ``manifest.parquet``); a member's name is
``<key>.<member>`` (e.g. ``<key>.meta.json``).
"""

from __future__ import annotations

import json
import tarfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import rasterio
from rasterio.io import MemoryFile

SUFFIX = {
    "ortho": "ortho.png",
    "dem": "dem.tif",
    "viewshed": "viewshed.png",
    "corr": "corr.npy",
    "meta": "meta.json",
}


def tar_members(root: Path) -> dict[str, bytes]:
    """Every member of every shard under ``root/shards`` (in shard order), bytes by name."""
    found: dict[str, bytes] = {}
    for shard in sorted((root / "shards").glob("*.tar")):
        with tarfile.open(shard) as tar:
            for info in tar.getmembers():
                fh = tar.extractfile(info)
                assert fh is not None, f"{shard}: {info.name} is not a regular file"
                assert info.name not in found, f"{shard}: duplicate member {info.name}"
                found[info.name] = fh.read()
    return found


def sample_members(root: Path) -> dict[str, dict[str, bytes]]:
    """``tar_members`` grouped by sample: {key: {member (e.g. "meta.json"): bytes}}."""
    out: dict[str, dict[str, bytes]] = {}
    for name, data in tar_members(root).items():
        key, _, member = name.partition(".")
        out.setdefault(key, {})[member] = data
    return out


def metas(root: Path) -> dict[str, dict[str, Any]]:
    """Every sample's ``meta.json``, parsed, by key."""
    return {
        key: json.loads(members["meta.json"])
        for key, members in sample_members(root).items()
        if "meta.json" in members
    }


def manifest_rows(root: Path) -> list[dict[str, Any]]:
    """The rows of ``root/manifest.parquet``, sorted by key."""
    rows = pq.read_table(root / "manifest.parquet").to_pylist()
    return sorted(rows, key=lambda r: r["key"])


def rows_by_key(root: Path) -> dict[str, dict[str, Any]]:
    """The rows of ``root/manifest.parquet`` by key."""
    return {r["key"]: r for r in manifest_rows(root)}


def manifest_keys(root: Path) -> set[str]:
    """The keys of ``root/manifest.parquet`` (the ``key`` column alone)."""
    return set(pq.read_table(root / "manifest.parquet", columns=["key"])["key"].to_pylist())


def dem_metres(data: bytes) -> np.ndarray:
    """A ``dem.tif`` member's float64 (H, W) metres as GDAL reads it (value * scale + offset
    from the file's GDAL tags, NaN where its no-data value is)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with MemoryFile(data) as mem, mem.open() as ds:
            values = ds.read(1, masked=True)
            scale, offset = ds.scales[0], ds.offsets[0]
    return np.asarray((values.astype(np.float64) * scale + offset).filled(np.nan))


def tiff_array(data: bytes) -> np.ndarray:
    """A TIFF member's pixels as GDAL reads them: (H, W) for one band, (H, W, C) for C."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with MemoryFile(data) as mem, mem.open() as ds:
            bands = ds.read()
    return bands[0] if len(bands) == 1 else np.moveaxis(bands, 0, -1)
