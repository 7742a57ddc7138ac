"""croissant.json of a built dataset is Croissant 1.0 that mlcroissant validates, and its
record set ``samples`` iterates the manifest's rows with typed values."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.store.croissant import croissant_type
from support.builds import build_small

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_small(small_mission, tmp_path_factory.mktemp("croissant") / "ds")


def test_mlcroissant_validates_it_and_iterates_the_samples(built: Path) -> None:
    mlc = pytest.importorskip("mlcroissant")
    doc = json.loads((built / "croissant.json").read_text())
    assert doc["conformsTo"] == "http://mlcommons.org/croissant/1.0"
    ids = {d["@id"]: d for d in doc["distribution"]}
    assert ids["manifest"]["contentUrl"] == "manifest.parquet"  # relative: the folder moves
    assert ids["shards"]["includes"] == "shards/*.tar"
    assert ids["member-dem"]["containedIn"] == {"@id": "shards"}
    dataset = mlc.Dataset(jsonld=built / "croissant.json")  # raises on a validation error
    records = list(dataset.records(record_set="samples"))
    table = pq.read_table(built / "manifest.parquet")
    assert len(records) == table.num_rows > 0
    by_key = {r["samples/key"].decode(): r for r in records}
    for row in table.to_pylist():
        got = by_key[row["key"]]
        assert got["samples/sol"] == row["sol"]
        assert got["samples/latitude"] == pytest.approx(row["latitude"])
        assert got["samples/split"].decode() == row["split"]
        assert got["samples/meta_offset"] == row["meta_offset"]


def test_the_manifest_hash_and_typed_fields(built: Path) -> None:
    import hashlib

    doc = json.loads((built / "croissant.json").read_text())
    manifest = next(d for d in doc["distribution"] if d["@id"] == "manifest")
    data = (built / "manifest.parquet").read_bytes()
    assert manifest["sha256"] == hashlib.sha256(data).hexdigest()
    fields = {f["name"]: f["dataType"] for f in doc["recordSet"][0]["field"]}
    assert fields["key"] == "sc:Text" and fields["sol"] == "sc:Integer"
    assert fields["easting"] == "sc:Float" and fields["time"] == "sc:DateTime"
    assert "footprint" not in fields  # WKB geometries: described in the card, not typed here
    assert croissant_type(pa.binary()) is None
