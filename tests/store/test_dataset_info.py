"""Every reader of dataset.json goes through store.dataset_info: one error for one fault."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mars_pairs.errors import DatasetError
from mars_pairs.store.dataset_info import dataset_crs, read_dataset_doc
from mars_pairs.store.inspect import split_warnings


def test_the_document_absent_damaged_or_not_an_object(tmp_path: Path) -> None:
    assert read_dataset_doc(tmp_path) == {}
    with pytest.raises(DatasetError, match=r"dataset\.json: missing"):
        dataset_crs(tmp_path)
    (tmp_path / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match=r"dataset\.json: unreadable"):
        read_dataset_doc(tmp_path)
    assert split_warnings(tmp_path) == []  # the summary: nothing to say of a damaged file
    (tmp_path / "dataset.json").write_text("[1]")
    with pytest.raises(DatasetError, match="expected a JSON object"):
        read_dataset_doc(tmp_path)


def test_the_crs_names_the_file_and_the_field(tmp_path: Path) -> None:
    path = tmp_path / "dataset.json"
    for doc, fault in (({}, "None"), ({"crs": 5}, "int"), ({"crs": ""}, "''")):
        path.write_text(json.dumps(doc))
        with pytest.raises(
            DatasetError, match=rf"dataset\.json: crs: expected CRS text, got {fault}"
        ):
            dataset_crs(tmp_path)
    path.write_text(json.dumps({"crs": "EPSG:4326", "splits": {"warnings": ["val empty"]}}))
    assert dataset_crs(tmp_path) == "EPSG:4326"
    assert split_warnings(tmp_path) == ["val empty"]
