"""Column names with units: ``elevation_m`` beside ``elevation_deg``; the old name still reads."""

from __future__ import annotations

import pickle
import warnings
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.columns import SampleMeta
from mars_pairs.store.manifest import MANIFEST_SCHEMA, SUMMARY_COLUMNS, rows_to_table
from mars_pairs.store.query import Manifest


def _rows() -> list[dict]:
    return [
        {"key": f"k{i}", "elevation_m": -2500.0 - i, "elevation_deg": -10.0 + i, "sol": i}
        for i in range(5)
    ]


@pytest.fixture()
def new_root(tmp_path: Path) -> Path:
    write_parquet_atomic(rows_to_table(_rows(), MANIFEST_SCHEMA), tmp_path / "manifest.parquet")
    return tmp_path


@pytest.fixture()
def old_root(tmp_path: Path) -> Path:
    """A manifest written before the rename: an ``elevation`` column."""
    table = rows_to_table(_rows(), MANIFEST_SCHEMA)
    names = ["elevation" if n == "elevation_m" else n for n in table.column_names]
    root = tmp_path / "old"
    root.mkdir()
    pq.write_table(table.rename_columns(names), root / "manifest.parquet")
    return root


def test_units_are_in_the_names() -> None:
    names = MANIFEST_SCHEMA.names
    assert "elevation_m" in names and "elevation" not in names and "elevation_deg" in names
    assert "elevation_m" in SUMMARY_COLUMNS and "elevation" not in SUMMARY_COLUMNS


def test_the_old_name_reads_the_new_column_with_a_warning(new_root: Path) -> None:
    m = Manifest.open(new_root)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new names never warn
        new = m.to_table(columns=["key", "elevation_m"])
        assert "elevation" not in m.to_table().column_names
    with pytest.warns(DeprecationWarning, match="'elevation' is now 'elevation_m'"):
        old = m.to_table(columns=["key", "elevation"])
    assert old.column_names == ["key", "elevation"]
    assert old["elevation"].to_pylist() == new["elevation_m"].to_pylist()
    assert new["elevation_m"].to_pylist()[0] == -2500.0  # metres, not the camera's angle


def test_datasets_built_before_the_rename_read_with_the_new_name(old_root: Path) -> None:
    m = Manifest.open(old_root)
    assert "elevation_m" in m.column_names and "elevation" not in m.column_names
    assert m.to_table()["elevation_m"].to_pylist() == [r["elevation_m"] for r in _rows()]
    assert m.to_table(columns=["elevation_m"])["elevation_m"].to_pylist()[4] == -2504.0
    with pytest.warns(DeprecationWarning):
        assert m.to_table(columns=["elevation"]).column_names == ["elevation"]
    assert m.filter(sol=(1, 2)).to_table(columns=["key", "elevation_m"]).num_rows == 2


def test_sample_meta_reads_the_old_key_with_a_warning() -> None:
    meta = SampleMeta(key="k", elevation_m=-2500.0, elevation_deg=-7.0)
    with pytest.warns(DeprecationWarning):
        assert meta["elevation"] == -2500.0
    with pytest.warns(DeprecationWarning):
        assert meta.get("elevation") == -2500.0
    assert "elevation" not in meta and list(meta) == ["key", "elevation_m", "elevation_deg"]
    assert meta.get("nope", 3) == 3
    with pytest.raises(KeyError):
        meta["nope"]
    assert pickle.loads(pickle.dumps(meta)) == meta


def test_an_old_manifest_meets_the_column_requirements(old_root: Path) -> None:
    m = Manifest.open(old_root)
    assert m.require(["key", "elevation_m"]) is m
    assert m.require(["elevation"]) is m
