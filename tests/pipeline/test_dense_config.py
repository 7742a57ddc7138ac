"""The dense members' config keys: output.members, output.dense_stride, chips.offset_m."""

from __future__ import annotations

from pathlib import Path

import pytest

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import parse_config
from mars_pairs.store.manifest import MANIFEST_SCHEMA, manifest_schema
from mars_pairs.store.members import DENSE_MEMBERS, member_fields


def _doc(tmp_path: Path, **sections: dict) -> dict:
    for name in ("dem.tif", "ortho.tif", "places.csv"):
        (tmp_path / name).write_bytes(b"x")
    doc = {
        "inputs": {"labels": "*.xml", "places": "places.csv", "dem": "dem.tif",
                   "ortho": "ortho.tif"},
        "output": {"dir": "out"},
    }  # fmt: skip
    for name, values in sections.items():
        doc[name] = {**doc.get(name, {}), **values}
    return doc


def test_defaults_leave_the_fingerprint_alone(tmp_path: Path) -> None:
    cfg = parse_config(_doc(tmp_path), tmp_path)
    assert cfg.output.members == () and cfg.chips.offset_m is None
    doc = cfg.to_dict()
    assert "members" not in doc["output"] and "dense_stride" not in doc["output"]
    assert "offset_m" not in doc["chips"]
    assert manifest_schema(member_fields(cfg.output.members)) is MANIFEST_SCHEMA


def test_members_all_list_and_order(tmp_path: Path) -> None:
    cfg = parse_config(_doc(tmp_path, output={"members": "all"}), tmp_path)
    assert cfg.output.members == DENSE_MEMBERS
    cfg = parse_config(_doc(tmp_path, output={"members": ["hits", "range"]}), tmp_path)
    assert cfg.output.members == ("range", "hits")
    assert cfg.to_dict()["output"]["members"] == ["range", "hits"]
    fields = member_fields(("ortho_view", "dem_view"))
    assert fields == ("ortho_view", "view_valid", "dem_view")
    names = manifest_schema(fields).names
    assert names[: len(MANIFEST_SCHEMA)] == MANIFEST_SCHEMA.names
    assert names[len(MANIFEST_SCHEMA) :][:4] == [
        "ortho_view_shard", "ortho_view_offset", "ortho_view_size", "ortho_view_crc32c",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("sections", "match"),
    [
        ({"output": {"members": ["range", "normals"]}}, "output.members: unknown member 'normals'"),
        ({"output": {"members": 3}}, "output.members: expected a list"),
        ({"output": {"dense_stride": 0}}, "output.dense_stride"),
        ({"chips": {"offset_m": -1}}, "chips.offset_m"),
        ({"chips": {"offset_m": "far"}}, "chips.offset_m"),
    ],
)
def test_bad_values_name_the_key(tmp_path: Path, sections: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_config(_doc(tmp_path, **sections), tmp_path)
