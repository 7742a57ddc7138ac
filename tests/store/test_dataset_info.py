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


# -- the typed DatasetInfo -------------------------------------------------------------------------
from mars_pairs.store.dataset_info import (  # noqa: E402
    FORMAT_VERSION,
    DatasetInfo,
    dataset_document,
    read_dataset_info,
)

DOC = {
    "config": {
        "geometry": {"ray_stride": 8},
        "output": {"dense_stride": 4},
        "inputs": {"ortho": "../mission/ortho.tif"},
        "splits": {"style": "same-area", "ratios": {"train": 0.8, "holdout": 0.2}},
    },
    "crs": "EPSG:4326",
    "crs_name": "a sphere",
    "chip": {"size_m": 64.0, "size_px": 128, "orientation": "north-up"},
    "counts": {"samples": 3, "failures": 1, "by_split": {"train": 3}},
    "splits": {"warnings": ["holdout empty"], "dropped_in_buffer": 0},
    "failures_by_reason": {"no_places": 1},
    "versions": {"mars_pairs": "0.1.0"},
    "license": "CC0-1.0",
    "build_seconds": 2.5,
}


def test_an_old_document_without_format_version_reads_as_version_1(tmp_path: Path) -> None:
    (tmp_path / "dataset.json").write_text(json.dumps(DOC))
    info = read_dataset_info(tmp_path)
    assert info.format_version == 1 and info.exists
    assert (info.ray_stride, info.dense_stride, info.chip_px) == (8, 4, 128)
    assert info.crs == "EPSG:4326" and info.crs_name == "a sphere" and info.license == "CC0-1.0"
    assert info.counts["samples"] == 3 and info.failures_by_reason == {"no_places": 1}
    assert info.build_seconds == 2.5 and info.versions["mars_pairs"] == "0.1.0"
    assert info.split_warnings == ["holdout empty"]
    assert info.configured_splits() == {"train", "buffer", "holdout"}
    assert info.build_input(tmp_path, "ortho") == tmp_path / "../mission/ortho.tif"
    assert info.build_input(tmp_path, "dem") is None


def test_the_dense_stride_defaults_to_the_ray_stride() -> None:
    doc = {"config": {"geometry": {"ray_stride": 6}}}
    assert DatasetInfo.from_doc(doc, "d.json").dense_stride == 6


@pytest.mark.parametrize(
    ("version", "match"),
    [
        (FORMAT_VERSION + 1, r"\d+ is newer than this mars-pairs reads"),
        (0, "expected a positive integer, got 0"),
        ("1", "expected a positive integer, got '1'"),
    ],
)
def test_a_format_version_it_cannot_read_is_named(
    tmp_path: Path, version: object, match: str
) -> None:
    (tmp_path / "dataset.json").write_text(json.dumps({**DOC, "format_version": version}))
    for required in (True, False):
        with pytest.raises(DatasetError, match=rf"dataset\.json: format_version: {match}"):
            read_dataset_info(tmp_path, required=required)


def test_the_lenient_reader_of_a_folder_without_one(tmp_path: Path) -> None:
    info = read_dataset_info(tmp_path, required=False)
    assert not info.exists and info.doc == {} and info.configured_splits() is None
    assert info.split_warnings == [] and info.build_input(tmp_path, "ortho") is None
    (tmp_path / "dataset.json").write_text(json.dumps({"crs": "EPSG:4326"}))  # no stride
    assert read_dataset_info(tmp_path, required=False).ray_stride == 0
    with pytest.raises(DatasetError, match=r"config\.geometry\.ray_stride"):
        read_dataset_info(tmp_path)


def test_the_written_document_leads_with_its_format_version(tmp_path: Path) -> None:
    doc = dataset_document(DOC, tmp_path / "dataset.json")
    assert next(iter(doc)) == "format_version" and doc["format_version"] == FORMAT_VERSION
    assert {k: v for k, v in doc.items() if k != "format_version"} == DOC
    with pytest.raises(DatasetError, match="ray_stride"):  # never writes what readers refuse
        dataset_document({"crs": "EPSG:4326"}, tmp_path / "dataset.json")


def test_no_module_reads_dataset_json_by_hand() -> None:
    """Every reader goes through DatasetInfo: no ``doc.get("config"`` chains elsewhere (the
    card renders the build's own config, not a dataset.json)."""
    import re

    package = Path(__file__).resolve().parents[2] / "mars_pairs"
    pattern = re.compile(r"""\.get\(["'](config|counts|splits|chip|output)["']""")
    found = [
        f"{path.relative_to(package)}:{n}"
        for path in package.rglob("*.py")
        # (the card renders the build's config; the catalogue writes and reads its own
        # catalog.json)
        if path.name not in ("dataset_info.py", "card.py")
        and path.relative_to(package).as_posix()
        not in ("pipeline/catalog/run.py", "pipeline/catalog/append.py", "store/catalog.py")
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert found == [], found
