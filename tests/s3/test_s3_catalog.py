"""``mars-pairs catalog --out s3://...`` on the S3 test server: the same rows, failures and
pairs as the catalogue on local disk, read back by ``Catalog.open`` and ``query``; appended
to; a publish killed mid-upload leaves no catalog.json (no reader takes it for a catalogue)
and a rerun publishes the whole catalogue; ``--resume`` and a foreign prefix refused."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError, DatasetError
from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.store import fs
from mars_pairs.store.catalog import Catalog
from support.configs import build_config, config_file

#: catalogues and a server: more than ~3 s a test
pytestmark = pytest.mark.slow

SECTIONS = {"geometry": {"radius": 100}, "output": {"shard_size": 3}}
#: the files whose bytes do not depend on where the catalogue is (catalog.json and the STAC
#: files name the inputs: relative to a folder, absolute from a bucket)
SAME_BYTES = ("catalog.parquet", "failures.parquet", "pairs.parquet")


@pytest.fixture(scope="module")
def mission(missions):  # type: ignore[no-untyped-def]
    """9 images at 3 stops, whose footprints overlap (the catalogue tests' mission)."""
    return missions(seed=5, stops=3, images_per_stop=3)


@pytest.fixture(scope="module")
def local(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("s3_catalog") / "cat"
    run_catalog(build_config(mission, out, **SECTIONS), out, progress=False)
    return out


@pytest.fixture(scope="module")
def remote(mission: Path, s3_prefix_factory: Callable[[], str]) -> str:
    url = s3_prefix_factory()
    summary = run_catalog(build_config(mission, Path("/unused"), **SECTIONS), url, progress=False)
    assert summary.out_dir == url and summary.images > 0
    return url


def test_the_same_catalogue_as_on_disk_read_back(local: Path, remote: str) -> None:
    assert sorted(fs.list_files(remote)) == sorted(p.name for p in local.iterdir())
    for name in SAME_BYTES:
        assert fs.read_bytes(fs.join(remote, name)) == (local / name).read_bytes(), name
    doc = json.loads(fs.read_bytes(fs.join(remote, "catalog.json")))
    assert doc["counts"] == json.loads((local / "catalog.json").read_text())["counts"]
    assert Path(doc["config"]["inputs"]["dem"]).is_absolute()  # no path leads from a bucket
    item = json.loads(fs.read_bytes(fs.join(remote, "items.ndjson")).splitlines()[0])
    assert Path(item["assets"]["label"]["href"]).is_file()

    there, here = Catalog.open(remote), Catalog.open(local)
    assert there.table.equals(here.table) and there.crs == here.crs
    c = here.geometry[0].representative_point()
    lon, lat = (float(v[0]) for v in map_to_lonlat([c.x], [c.y], json.dumps(here.crs)))
    d = 1e-5
    assert there.bbox(lon - d, lat - d, lon + d, lat + d).equals(
        here.bbox(lon - d, lat - d, lon + d, lat + d)
    )
    assert there.saw(lon, lat).equals(here.saw(lon, lat))
    assert there.saw(lon, lat, per_cell=True).equals(here.saw(lon, lat, per_cell=True))
    key = pq.read_table(local / "pairs.parquet")["key_a"][0].as_py()
    assert len(here.overlaps(key)) and there.overlaps(key).equals(here.overlaps(key))


def test_cli_writes_and_queries_a_bucket(
    mission: Path, local: Path, s3_prefix: str, tmp_path: Path
) -> None:
    config = config_file(tmp_path / "c.yaml", mission, tmp_path / "unused", **SECTIONS)
    assert main(["catalog", "--config", str(config), "--out", s3_prefix, "--quiet"]) == 0
    here = Catalog.open(local)
    c = here.geometry[0].representative_point()
    lon, lat = (float(v[0]) for v in map_to_lonlat([c.x], [c.y], json.dumps(here.crs)))
    box = [repr(v) for v in (lon - 1e-5, lat - 1e-5, lon + 1e-5, lat + 1e-5)]
    out = tmp_path / "box.parquet"
    argv = ["query", s3_prefix, "--bbox", *box, "--format", "parquet", "--out", str(out)]
    assert main(argv) == 0
    assert pq.read_table(out)["key"].to_pylist() == here.bbox(*map(float, box))["key"].to_pylist()
    assert main(["query", s3_prefix, "--saw", repr(lon), repr(lat)]) == 0
    assert main(["catalog", "--config", str(config), "--out", s3_prefix, "--resume"]) == 2


def test_append_to_a_bucket_equals_one_catalogue(
    mission: Path, local: Path, s3_prefix: str, tmp_path: Path
) -> None:
    labels = sorted(str(p) for p in (mission / "labels").glob("*.xml"))
    first = build_config(mission, Path("/unused"), labels=labels[:2], **SECTIONS)
    run_catalog(first, s3_prefix, progress=False)
    every = build_config(mission, Path("/unused"), **SECTIONS)
    summary = run_catalog(every, s3_prefix, progress=False, append=True)
    assert summary.chunks_built > 0 and summary.out_dir == s3_prefix
    for name in SAME_BYTES:
        assert fs.read_bytes(fs.join(s3_prefix, name)) == (local / name).read_bytes(), name
    (record,) = json.loads(fs.read_bytes(fs.join(s3_prefix, "catalog.json")))["appends"]
    assert record["labels_known"] == 2
    before = {rel: fs.read_bytes(fs.join(s3_prefix, rel)) for rel in fs.list_files(s3_prefix)}
    assert run_catalog(every, s3_prefix, progress=False, append=True).chunks_built == 0
    assert {
        rel: fs.read_bytes(fs.join(s3_prefix, rel)) for rel in fs.list_files(s3_prefix)
    } == before


def test_a_publish_killed_mid_upload_is_no_catalogue_until_rerun(
    mission: Path, local: Path, remote: str, s3_prefix: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = build_config(mission, Path("/unused"), **SECTIONS)
    real = fs.upload
    calls: list[str] = []

    def upload_then_die(src: Path, dst: str) -> None:
        if len(calls) == 2:
            raise KeyboardInterrupt  # killed with two files uploaded
        calls.append(dst)
        real(src, dst)

    # over an existing catalogue: its catalog.json goes before any file changes
    prefix = remote + "-copy"
    for rel in fs.list_files(remote):
        fs.put_bytes(fs.join(prefix, rel), fs.read_bytes(fs.join(remote, rel)))
    monkeypatch.setattr(fs, "upload", upload_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_catalog(config, prefix, progress=False)
    monkeypatch.setattr(fs, "upload", real)
    assert "catalog.json" not in fs.list_files(prefix)
    with pytest.raises(DatasetError, match=r"catalog\.json"):
        Catalog.open(prefix)
    run_catalog(config, prefix, progress=False)
    assert Catalog.open(prefix).table.equals(Catalog.open(local).table)

    fs.put_bytes(fs.join(s3_prefix, "notes.txt"), b"mine")
    with pytest.raises(ConfigError, match=r"notes\.txt"):
        run_catalog(config, s3_prefix, progress=False)
    assert fs.list_files(s3_prefix) == ["notes.txt"]
    with pytest.raises(ConfigError, match="make it first"):
        run_catalog(config, s3_prefix + "-none", progress=False, append=True)
