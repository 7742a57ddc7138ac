"""``MarsPairsDataset(verify=True)`` checks what ``mars-pairs verify`` checks, and every
corruption of a built dataset is a DatasetError naming the shard (or file) and the key, in
the dataset, through DataLoader workers and in ``mars-pairs verify`` (exit 2)."""

from __future__ import annotations

import pickle
import shutil
import tarfile
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from torch.utils.data import DataLoader

from mars_pairs import Manifest
from mars_pairs.cli.main import main
from mars_pairs.errors import ArgumentError, DatasetError, MarsPairsError, MissingMemberError
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset, MarsPairsIterableDataset, MarsPairsLoader
from support.builds import reseal

ROW, OTHER = 4, 7  # the damaged sample's manifest row (read first), and a later one's


@pytest.fixture()
def copy(dataset_dir: Path, tmp_path: Path) -> Path:
    """A private copy of the built dataset, to damage."""
    return Path(shutil.copytree(dataset_dir, tmp_path / "ds"))


def rows(root: Path) -> list[dict]:
    return pq.read_table(root / "manifest.parquet").to_pylist()


def write_rows(root: Path, new: list[dict]) -> None:
    schema = pq.read_schema(root / "manifest.parquet")
    pq.write_table(pa.Table.from_pylist(new, schema=schema), root / "manifest.parquet")


def set_row(root: Path, index: int, **values: object) -> None:
    table = rows(root)
    table[index].update(values)
    write_rows(root, table)


@dataclass(frozen=True)
class Damage:
    """What a corruption did: the file named (a shard path, or manifest.parquet /
    dataset.json), the member or key named by the dataset and by ``mars-pairs verify``."""

    file: str
    dataset_names: str
    verify_names: str
    reason: str


# -- corruptions ------------------------------------------------------------------------------
def flip_meta_byte(root: Path) -> Damage:
    row = rows(root)[ROW]
    with open(root / row["meta_shard"], "r+b") as fh:  # a digit of the JSON: still valid JSON
        fh.seek(row["meta_offset"])
        text = fh.read(row["meta_size"])
        at = row["meta_offset"] + next(i for i, c in enumerate(text) if chr(c).isdigit())
        fh.seek(at)
        digit = fh.read(1)
        fh.seek(at)
        fh.write(b"7" if digit != b"7" else b"3")
    key = row["key"]
    return Damage(row["meta_shard"], f"{key}.meta.json", f"{key}.meta", "checksum mismatch")


def swap_ortho(root: Path) -> Damage:
    table = rows(root)
    a, b = table[ROW], table[OTHER]
    for column in ("ortho_shard", "ortho_offset", "ortho_size", "ortho_crc32c"):
        a[column], b[column] = b[column], a[column]
    write_rows(root, table)
    key = a["key"]
    return Damage(a["ortho_shard"], f"{key}.ortho.png", f"{key}.ortho", "tar header names")


def rename_key_in_tar(root: Path) -> Damage:
    row = rows(root)[ROW]
    at = row["ortho_offset"] - tarfile.BLOCKSIZE
    with open(root / row["ortho_shard"], "r+b") as fh:
        fh.seek(at)
        info = tarfile.TarInfo.frombuf(fh.read(tarfile.BLOCKSIZE), "utf-8", "surrogateescape")
        info.name = "renamed_key.ortho.png"  # a valid header (its checksum recomputed)
        fh.seek(at)
        fh.write(info.tobuf(tarfile.USTAR_FORMAT))
    key = row["key"]
    return Damage(row["ortho_shard"], f"{key}.ortho.png", f"{key}.ortho", "tar header names")


def duplicate_rows(root: Path) -> Damage:
    table = rows(root)
    write_rows(root, [*table, table[ROW], table[ROW]])
    return Damage("manifest.parquet", table[ROW]["key"], table[ROW]["key"], "3 rows hold this key")


def delete_dataset_json(root: Path) -> Damage:
    (root / "dataset.json").unlink()
    return Damage("dataset.json", "dataset.json", "dataset.json", "missing")


def drop_column(name: str) -> Callable[[Path], Damage]:
    def damage(root: Path) -> Damage:
        table = pq.read_table(root / "manifest.parquet")
        pq.write_table(table.drop_columns([name]), root / "manifest.parquet")
        return Damage("manifest.parquet", name, name, "no such column")

    return damage


def shard_path(path: str, reason: str) -> Callable[[Path], Damage]:
    def damage(root: Path) -> Damage:
        row = rows(root)[ROW]
        set_row(root, ROW, ortho_shard=path)
        key = row["key"]
        return Damage(path, f"{key}.ortho.png", f"{key}.ortho", reason)

    return damage


def symlink_outside(root: Path) -> Damage:
    outside = root.parent / "elsewhere.tar"
    row = rows(root)[ROW]
    shutil.copy(root / row["ortho_shard"], outside)
    (root / "shards" / "link.tar").symlink_to(outside)
    set_row(root, ROW, ortho_shard="shards/link.tar")
    key = row["key"]
    return Damage("shards/link.tar", f"{key}.ortho.png", f"{key}.ortho", "resolves outside")


def huge_size(root: Path) -> Damage:
    row = rows(root)[ROW]
    set_row(root, ROW, ortho_size=1 << 50)  # a PiB: allocating it is a MemoryError
    key = row["key"]
    return Damage(row["ortho_shard"], f"{key}.ortho.png", f"{key}.ortho", "past the end")


CORRUPTIONS = {
    "meta byte flipped": flip_meta_byte,
    "ortho locations swapped": swap_ortho,
    "key renamed in the tar": rename_key_in_tar,
    "duplicated rows": duplicate_rows,
    "no dataset.json": delete_dataset_json,
    "no ortho_offset column": drop_column("ortho_offset"),
    "no meta_size column": drop_column("meta_size"),
    "shard ../../etc/passwd": shard_path("../../etc/passwd", "leaves the dataset folder"),
    "shard ../ to /etc/passwd": shard_path("../" * 40 + "etc/passwd", "leaves the dataset"),
    "shard /dev/zero": shard_path("/dev/zero", "is absolute"),
    "shard symlinked outside": symlink_outside,
    "huge member size": huge_size,
}


def read_all(root: Path, **kwargs: object) -> None:
    with MarsPairsDataset(root, **kwargs) as ds:
        for i in range(len(ds)):
            ds[i]


@pytest.mark.parametrize("corruption", CORRUPTIONS.values(), ids=CORRUPTIONS.keys())
def test_every_corruption_is_a_dataset_error_and_fails_verify(
    copy: Path, corruption: Callable[[Path], Damage], capsys: pytest.CaptureFixture[str]
) -> None:
    damage = corruption(copy)
    reseal(copy)  # the member checks behind the folder's chain (tests/store/test_folder_chain)
    with pytest.raises(DatasetError) as err:
        read_all(copy, verify=True)
    message = str(err.value)
    for needle in (damage.file, damage.dataset_names, damage.reason):
        assert needle in message, (needle, message)
    assert main(["verify", str(copy)]) == 2
    out = capsys.readouterr().err
    for needle in (damage.file, damage.verify_names, damage.reason):
        assert needle in out, (needle, out)


@pytest.mark.parametrize(
    "corruption",
    [delete_dataset_json, drop_column("ortho_offset"),
     shard_path("../../etc/passwd", "leaves the dataset folder"),
     shard_path("/dev/zero", "is absolute"), symlink_outside, huge_size],
)  # fmt: skip
def test_unverified_reads_refuse_them_too(copy: Path, corruption: Callable[[Path], Damage]) -> None:
    """No silent default stride, no read outside the dataset folder, no MemoryError."""
    damage = corruption(copy)
    with pytest.raises(DatasetError) as err:
        read_all(copy, fields=("ortho",))
    for needle in (damage.file, damage.dataset_names, damage.reason):
        assert needle in str(err.value), (needle, str(err.value))


def test_verified_reads_equal_unverified_ones(dataset_dir: Path) -> None:
    with (
        MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as plain,
        MarsPairsDataset(dataset_dir, fields=ALL_FIELDS, verify=True) as checked,
    ):
        assert len(plain) == len(checked)
        for i in range(len(plain)):
            a, b = plain[i], checked[i]
            assert a["meta"] == b["meta"]
            for name in (*ALL_FIELDS, "corr_ground", "transform"):
                torch.testing.assert_close(a[name], b[name], rtol=0, atol=0, equal_nan=True)
    assert main(["verify", str(dataset_dir)]) == 0


def test_verify_checks_members_not_requested(copy: Path) -> None:
    damage = flip_meta_byte(copy)
    read_all(copy, fields=("dem",))  # unverified: the meta member is not read
    with pytest.raises(DatasetError, match="checksum mismatch") as err:
        read_all(copy, fields=("dem",), verify=True)
    assert damage.dataset_names in str(err.value)


def test_a_missing_column_is_named_by_the_manifest_and_the_datasets(copy: Path) -> None:
    drop_column("dem_shard")(copy)
    with pytest.raises(DatasetError, match=r"manifest\.parquet: dem_shard: no such column"):
        Manifest.open(copy).to_table(columns=["key", "dem_shard"])
    for dataset in (MarsPairsDataset, MarsPairsIterableDataset):
        with pytest.raises(DatasetError, match=r"manifest\.parquet: dem_shard: no such column"):
            dataset(copy, fields=("dem",))
    drop_column("split")(copy)
    with pytest.raises(DatasetError, match=r"manifest\.parquet: split: no such column"):
        Manifest.open(copy).filter(split="train")


def test_an_empty_filter_list_blames_the_argument(dataset_dir: Path) -> None:
    for name in ("split", "mission", "instrument"):
        with pytest.raises(ArgumentError, match=f"{name}: expected a string or a non-empty"):
            MarsPairsDataset(dataset_dir, **{name: []})


# -- worker processes -----------------------------------------------------------------------
@pytest.mark.parametrize("loader", [MarsPairsLoader, DataLoader])
def test_a_worker_error_reaches_the_caller_as_a_dataset_error(
    copy: Path, loader: type[DataLoader]
) -> None:
    damage = swap_ortho(copy)
    reseal(copy)
    kwargs = {} if loader is MarsPairsLoader else {"collate_fn": list}
    kind = message = None
    with MarsPairsDataset(copy, fields=("ortho",), verify=True) as ds:
        batches = iter(loader(ds, batch_size=3, num_workers=2, **kwargs))
        try:
            for _ in batches:
                pass
        except MarsPairsError as exc:
            kind, message = type(exc), str(exc)
        if loader is MarsPairsLoader:  # torch's iterator is gone with the loader's
            inner = weakref.ref(batches._inner)
            del batches
            assert inner() is None
        else:  # torch's re-raise holds its iterator in a cycle (collected late, 5 s a worker)
            batches._shutdown_workers()
    assert kind is DatasetError and message is not None
    for needle in (damage.file, damage.dataset_names, damage.reason):
        assert needle in message, (needle, message)


def test_dataset_error_survives_reconstruction_from_its_message() -> None:
    err = DatasetError("shards/a.tar", "k.ortho.png", "checksum mismatch")
    again = type(err)(str(err))
    assert isinstance(again, DatasetError) and str(again) == str(err)
    assert again.reason == str(err) and again.member is None
    assert "shards/a.tar" in str(again)
    for original in (err, again, MissingMemberError("manifest.parquet", "k.corr", "no such")):
        copied = pickle.loads(pickle.dumps(original))  # as a process pool sends it
        assert type(copied) is type(original) and str(copied) == str(original)
        assert (copied.path, copied.member, copied.reason) == (
            original.path,
            original.member,
            original.reason,
        )
