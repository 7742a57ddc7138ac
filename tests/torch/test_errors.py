"""One error family: everything a dataset user can catch is a MarsPairsError, and a damaged
shard or member names the shard and the member."""

from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from mars_pairs.errors import (
    ArgumentError,
    DatasetError,
    MarsPairsError,
    MissingMemberError,
    SampleIndexError,
    SampleKeyError,
    TerrainError,
    UsageError,
)
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset, MarsPairsIterableDataset
from support.builds import reseal


@pytest.fixture()
def copy(dataset_dir: Path, tmp_path: Path) -> Path:
    """A private copy of the built dataset, to damage."""
    return Path(shutil.copytree(dataset_dir, tmp_path / "ds"))


def location(root: Path, index: int, field: str) -> tuple[str, str, int, int]:
    """(key, shard, offset, size) of row ``index``'s member in the manifest."""
    row = pq.read_table(root / "manifest.parquet").slice(index, 1).to_pylist()[0]
    return row["key"], row[f"{field}_shard"], row[f"{field}_offset"], row[f"{field}_size"]


def overwrite(root: Path, shard: str, offset: int, data: bytes) -> None:
    with open(root / shard, "r+b") as fh:
        fh.seek(offset)
        fh.write(data)


def dataset_index(ds: MarsPairsDataset, key: str) -> int:
    return ds.index_of(key)


@pytest.mark.parametrize(
    ("field", "suffix"), [("ortho", "ortho.png"), ("dem", "dem.tif"), ("ground", "ground")]
)
def test_a_damaged_member_names_the_shard_and_the_member(
    copy: Path, field: str, suffix: str
) -> None:
    key, shard, offset, _ = location(copy, 4, field)
    overwrite(copy, shard, offset, b"\x00garbage" * 8)
    with MarsPairsDataset(copy, fields=ALL_FIELDS) as ds:
        i = dataset_index(ds, key)
        with pytest.raises(DatasetError) as err:
            ds[i]
        ds[(i + 1) % len(ds)]  # the others still read
        with pytest.raises(MarsPairsError):
            ds.__getitems__([0, i])
    message = str(err.value)
    assert shard in message and f"{key}.{suffix}" in message and "cannot decode" in message
    assert err.value.path.endswith(shard) and err.value.member.startswith(f"{key}.{suffix}")


def test_a_truncated_or_missing_shard_names_it(copy: Path) -> None:
    key, shard, offset, size = location(copy, 2, "viewshed")
    os.truncate(copy / shard, offset + size // 2)
    with MarsPairsDataset(copy, fields=("viewshed",)) as ds:
        with pytest.raises(DatasetError, match=f"{shard}: {key}.viewshed.png: cannot read"):
            ds[ds.index_of(key)]
        (copy / shard).unlink()
        ds.close()  # the descriptor of the truncated file goes; the next read reopens
        with pytest.raises(DatasetError, match=f"{shard}: {key}.viewshed.png: cannot read"):
            ds[ds.index_of(key)]


def test_verify_finds_a_flipped_byte_that_still_decodes(copy: Path) -> None:
    key, shard, offset, size = location(copy, 5, "dem")
    with open(copy / shard, "r+b") as fh:  # GDAL's no-data text 65535 -> 65534: still decodes
        fh.seek(offset)
        at = offset + fh.read(size).index(b"65535\x00") + 4
        fh.seek(at)
        fh.write(b"4")
    with MarsPairsDataset(copy, fields=("dem",)) as ds:
        ds[ds.index_of(key)]  # unverified: decodes (wrong value, silently)
    with MarsPairsDataset(copy, fields=("dem",), verify=True) as ds:
        with pytest.raises(DatasetError, match=f"{key}.dem.tif: checksum mismatch"):
            ds[ds.index_of(key)]
        assert ds[(ds.index_of(key) + 1) % len(ds)]["dem"].shape[0] == 1
    stream = MarsPairsIterableDataset(copy, fields=("dem",), verify=True)
    with stream, pytest.raises(DatasetError, match="checksum mismatch"):
        list(stream)


def test_verify_without_checksum_columns_warns_and_reads(copy: Path) -> None:
    table = pq.read_table(copy / "manifest.parquet")
    old = table.drop_columns([c for c in table.column_names if c.endswith("_crc32c")])
    pq.write_table(old, copy / "manifest.parquet")  # a dataset built before checksums
    reseal(copy)  # its integrity record, as such a build would have written it
    with pytest.warns(UserWarning, match="no checksums"):
        ds = MarsPairsDataset(copy, fields=("ortho", "dem"), verify=True)
    with ds:
        assert ds[0]["dem"].shape[0] == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        MarsPairsDataset(copy, fields=("ortho",)).close()  # no verify, no warning


def test_a_missing_member_is_a_key_error_and_a_mars_pairs_error(copy: Path) -> None:
    table = pq.read_table(copy / "manifest.parquet")
    offsets = table.column("corr_offset").to_pylist()
    offsets[3] = None
    key = table.column("key")[3].as_py()
    table = table.set_column(
        table.schema.get_field_index("corr_offset"), "corr_offset", pa.array(offsets, pa.int64())
    )
    pq.write_table(table, copy / "manifest.parquet")
    with (
        MarsPairsDataset(copy, fields=("corr",)) as ds,
        pytest.raises(MissingMemberError, match=f"{key}.corr: no such member") as err,
    ):
        ds[ds.index_of(key)]
    assert isinstance(err.value, KeyError) and isinstance(err.value, MarsPairsError)


def test_indices_keys_and_arguments(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, fields=("viewshed",)) as ds:
        n = len(ds)
        assert ds[-1]["meta"]["key"] == ds[n - 1]["meta"]["key"]
        assert ds[np.int64(2)]["meta"]["key"] == ds[torch.tensor(2)]["meta"]["key"]
        for bad in (n, -n - 1):
            with pytest.raises(SampleIndexError) as err:
                ds[bad]
            assert isinstance(err.value, IndexError) and isinstance(err.value, MarsPairsError)
        with pytest.raises(ArgumentError) as err:
            ds["0"]
        assert isinstance(err.value, TypeError)
        assert len(list(ds)) == n  # iteration ends at the IndexError
        with pytest.raises(SampleKeyError, match="no sample with key 'nope'") as err:
            ds.index_of("nope")
        assert isinstance(err.value, KeyError)
    cases = [
        ({"fields": ("ground", "nope")}, ValueError, "unknown field"),
        ({"nearby": (0, 0, 1)}, TypeError, "unknown filter"),
        ({"image_dtype": torch.float64}, ValueError, "image_dtype"),
        ({"ground_size": "big"}, TypeError, "ground_size"),
        ({"near": (0.0, 0.0)}, ValueError, "near"),
        ({"bbox_lonlat": (0, 0, float("nan"), 1)}, ValueError, "bbox_lonlat"),
        ({"transform": 3}, TypeError, "transform"),
    ]
    for kwargs, builtin, match in cases:
        with pytest.raises(ArgumentError, match=match) as err:
            MarsPairsDataset(dataset_dir, **kwargs)
        assert isinstance(err.value, builtin) and isinstance(err.value, UsageError), kwargs
    with pytest.raises(MarsPairsError, match="no manifest"):
        MarsPairsDataset(dataset_dir / "nowhere")


def open_shards(root: Path) -> int:
    """This process's descriptors open on a shard of ``root`` (other threads and earlier
    tests' pools open and close descriptors of their own meanwhile)."""
    shards = str((root / "shards").resolve())
    count = 0
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):  # closed since the listing
            count += os.readlink(f"/proc/self/fd/{fd}").startswith(shards)
    return count


def test_datasets_are_context_managers(dataset_dir: Path) -> None:
    assert open_shards(dataset_dir) == 0
    with MarsPairsDataset(dataset_dir, fields=("ortho",)) as ds:
        [ds[i] for i in range(len(ds))]
        assert open_shards(dataset_dir) == 3  # the 3 shards are open
    assert open_shards(dataset_dir) == 0
    assert ds[0]["ortho"].shape[0] == 1  # closed, still usable (reopens)
    ds.close()
    with MarsPairsIterableDataset(dataset_dir, fields=("ortho",)) as stream:
        assert len(list(stream)) == len(ds)
    assert open_shards(dataset_dir) == 0


def test_build_stage_usage_and_chip_errors_are_mars_pairs_errors(tmp_path: Path) -> None:
    from mars_pairs.cli.build import UsageError as CliUsageError
    from mars_pairs.errors import BuildError, StageError
    from mars_pairs.raster.chips import ChipReader

    assert issubclass(BuildError, MarsPairsError) and issubclass(StageError, MarsPairsError)
    assert CliUsageError is UsageError and issubclass(UsageError, MarsPairsError)
    with pytest.raises(TerrainError, match="cannot open"):
        ChipReader(tmp_path / "missing.tif")
    (tmp_path / "junk.tif").write_bytes(b"not a tiff")
    with pytest.raises(TerrainError, match=r"junk\.tif"):
        ChipReader(tmp_path / "junk.tif")


def test_chip_reads_outside_the_bands_are_terrain_errors(mission_dir: Path) -> None:
    from mars_pairs.raster.chips import ChipGrid, ChipReader

    with ChipReader(mission_dir / "orbital" / "dem.tif") as reader:
        b = reader.dataset.bounds
        grid = ChipGrid.around(
            (b.left + b.right) / 2, (b.bottom + b.top) / 2, 32.0, 16, reader.dataset.crs
        )
        assert np.isfinite(reader.read(grid)).any()
        with pytest.raises(TerrainError, match="band 2"):
            reader.read(grid, band=2)


def _png_bomb(side: int) -> bytes:
    """A valid PNG header of ``side`` x ``side`` grey pixels (CRCs correct) over a few bytes
    of image data: a decoder that trusts the header allocates side**2 bytes."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * 1024, 9)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_a_decompression_bomb_member_is_a_dataset_error_naming_it(copy: Path) -> None:
    key, shard, offset, size = location(copy, 1, "ortho")
    bomb = _png_bomb(20000)
    assert len(bomb) <= size
    with open(copy / shard, "r+b") as fh:  # the member's bytes, its tar header kept
        fh.seek(offset)
        fh.write(bomb + b"\0" * (size - len(bomb)))
    with MarsPairsDataset(copy, fields=("ortho",)) as ds, pytest.raises(DatasetError) as err:
        ds[1]
    message = str(err.value)
    assert shard in message and f"{key}.ortho.png" in message
    assert "pixel limit" in message or "over the limit" in message
