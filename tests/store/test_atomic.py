"""store.atomic: the one temporary naming and the all-or-nothing writes."""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.pipeline.builder.layout import is_temporary
from mars_pairs.store.atomic import (
    atomic_path,
    atomic_write_bytes,
    temporary_path,
    temporary_target,
    write_parquet_atomic,
    write_parquet_staged,
)


def test_temporary_name_is_recognised_and_names_its_target(tmp_path: Path) -> None:
    tmp = temporary_path(tmp_path / "shard-000001.tar")
    assert tmp.parent == tmp_path
    assert tmp.name == f".shard-000001.tar.tmp-{os.getpid()}"
    assert temporary_target(tmp.name) == "shard-000001.tar"
    assert temporary_target("shard-000001.tar") is None
    assert temporary_target(".x.tmp-12.gpkg") is None  # a suffixed name is no build's
    assert temporary_target(temporary_path(tmp_path / "a.gpkg", ".gpkg").name) is None


def test_build_temporaries_are_those_of_files_a_build_writes() -> None:
    assert is_temporary("shards/.shard-000003.tar.tmp-99")
    assert is_temporary("parts/.manifest-1234567.parquet.tmp-1")
    assert is_temporary(".dataset.json.tmp-5")
    assert is_temporary("parts/.build.json.tmp-5")
    assert not is_temporary("shards/.shard-03.tar.tmp-99")  # not a name a build writes
    assert not is_temporary("shards/.shard-0000003.tar.tmp-99")  # extra leading zero
    assert not is_temporary("other/.dataset.json.tmp-5")
    assert not is_temporary(".notes.txt.tmp-5")
    assert not is_temporary("shards/shard-000003.tar")


def test_atomic_path_renames_on_success_and_keeps_the_old_file_on_error(tmp_path: Path) -> None:
    path = tmp_path / "a.bin"
    with atomic_path(path) as tmp:
        tmp.write_bytes(b"new")
        assert not path.exists()
    assert path.read_bytes() == b"new"
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("killed")
    assert path.read_bytes() == b"new"
    assert os.listdir(tmp_path) == ["a.bin"]


def test_atomic_write_bytes_leaves_no_temporary(tmp_path: Path) -> None:
    atomic_write_bytes(tmp_path / "d.json", b"{}")
    assert os.listdir(tmp_path) == ["d.json"]
    assert (tmp_path / "d.json").read_bytes() == b"{}"


def test_staged_parquet_is_synced_but_not_renamed(tmp_path: Path) -> None:
    table = pa.table({"a": [1, 2, 3]})
    path = tmp_path / "parts" / "m.parquet"
    tmp = write_parquet_staged(table, path)
    assert tmp == temporary_path(path) and not path.exists()
    assert pq.read_table(tmp).equals(table)
    write_parquet_atomic(table, path)
    assert pq.read_table(path).equals(table)
