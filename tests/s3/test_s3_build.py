"""A build whose output folder is on the S3 test server equals the same build on local disk,
byte for byte; it survives a worker killed mid-upload (``--resume``); the readers read it."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch
import yaml

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import BuildConfig, parse_config
from mars_pairs.store import fs
from mars_pairs.store.inspect import inspect_dataset
from mars_pairs.store.query import Manifest
from mars_pairs.store.verify import verify_dataset
from mars_pairs.torch.datasets import MarsPairsDataset
from mars_pairs.torch.streaming import MarsPairsIterableDataset
from support.builds import small_doc

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

#: The files whose bytes a build makes the same wherever it writes them (besides the shards;
#: shardindex.json names the folder).
SAME_BYTES = ("manifest.parquet", "failures.parquet")


def config_for(mission: Path, out: str | Path, **sections: Any) -> BuildConfig:
    """The cheap build of ``mission`` (2 samples a shard) into ``out`` (a folder or URL)."""
    doc = small_doc(mission, Path("/unused"), **sections)
    doc["output"]["dir"] = str(out)
    return parse_config(doc, base=mission)


def digests(root: str | Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (a folder or a URL) but the build's own card."""
    root = fs.dataset_root(root)
    return {
        rel: hashlib.sha256(fs.read_bytes(fs.join(root, rel))).hexdigest()
        for rel in fs.list_files(root)
        if rel.startswith("shards/") or rel in SAME_BYTES
    }


@pytest.fixture(scope="module")
def local_build(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("s3_local") / "ds"
    summary = run_build(config_for(small_mission, out), progress=False)
    assert summary.samples == 4 and summary.failures == 0
    return out


@pytest.fixture(scope="module")
def s3_build(small_mission: Path, s3_prefix_factory: Callable[[], str]) -> str:
    """The cheap build of the small mission into a fresh S3 prefix, by 2 pool workers."""
    url = s3_prefix_factory()
    summary = run_build(config_for(small_mission, url), workers=2, progress=False)
    assert (summary.samples, summary.chunks_built) == (4, 2)
    return url


def test_a_build_to_s3_equals_the_local_build(
    small_mission: Path, local_build: Path, s3_build: str
) -> None:
    """Two workers upload their shards; the manifest, failures and shards on the server have
    the bytes of the local build; parts/ is gone; every dataset file is there; a resume
    over the finished build does nothing."""
    assert digests(s3_build) == digests(local_build)
    files = fs.list_files(s3_build)
    assert not [f for f in files if f.startswith("parts/")]
    for name in ("dataset.json", "README.md", "croissant.json", "shardindex.json"):
        assert name in files
    again = run_build(config_for(small_mission, s3_build), resume=True, progress=False)
    assert (again.chunks_built, again.samples) == (0, 4)


def test_a_dask_build_to_s3_equals_the_local_build(
    small_mission: Path, local_build: Path, s3_prefix: str
) -> None:
    """Dask workers (a LocalCluster of 2 processes, the environment's credentials inherited)
    upload the shards: the local build's bytes."""
    pytest.importorskip("distributed", reason="the dask extra is not installed")
    from mars_pairs.pipeline.builder.dask_engine import DaskEngine

    engine = DaskEngine(workers=2, announce=False)
    summary = run_build(config_for(small_mission, s3_prefix), engine=engine, progress=False)
    assert summary.samples == 4
    assert digests(s3_prefix) == digests(local_build)


def test_the_readers_read_a_dataset_on_s3(
    local_build: Path, s3_build: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """MarsPairsDataset (verify=True), the streaming dataset, Manifest, verify and inspect
    (and ``mars-pairs verify URL``) read the dataset on the server as the local one."""
    fields = ("ground", "ortho", "dem", "viewshed", "corr")
    with (
        MarsPairsDataset(s3_build, fields=fields, verify=True) as checked,
        MarsPairsDataset(s3_build, fields=fields) as fetched,  # one batch of ranges a sample
        MarsPairsDataset(local_build, fields=fields) as local,
    ):
        assert len(checked) == len(fetched) == len(local) == 4
        for i in range(len(local)):
            for remote in (checked[i], fetched[i]):
                assert remote["meta"] == local[i]["meta"]
                for name in fields:
                    torch.testing.assert_close(
                        remote[name], local[i][name], rtol=0, atol=0, equal_nan=True
                    )
    with MarsPairsIterableDataset(s3_build, fields=("ortho",), shuffle_buffer=1) as stream:
        assert sorted(s["meta"]["key"] for s in stream) == sorted(local_build_keys(local_build))
    assert len(Manifest.open(s3_build).filter(split="train")) == len(
        Manifest.open(local_build).filter(split="train")
    )
    report = verify_dataset(s3_build)
    assert not report.damage and report.shards == 2 and report.members > 0
    text = inspect_dataset(s3_build)
    assert "samples: 4" in text and f"dataset: {s3_build}" in text
    assert main(["verify", s3_build]) == 0
    assert "all intact" in capsys.readouterr().out


def local_build_keys(root: Path) -> list[str]:
    return Manifest.open(root).to_table(columns=["key"])["key"].to_pylist()


def test_verify_names_a_damaged_member_on_s3(local_build: Path, s3_prefix: str) -> None:
    """A dataset uploaded with one shard byte flipped: verify names that shard's member."""
    damaged = []
    for rel in fs.list_files(local_build):
        data = (local_build / rel).read_bytes()
        if rel.startswith("shards/shard-000001-") and not damaged:  # chunk 1's (first) shard
            data = data[:1000] + bytes([data[1000] ^ 0xFF]) + data[1001:]
            damaged.append(rel)
        fs.put_bytes(fs.join(s3_prefix, rel), data)
    report = verify_dataset(s3_prefix)
    assert damaged and [d.path for d in report.damage] == damaged


def test_rasters_on_s3_build_as_local(
    small_mission: Path, local_build: Path, s3_prefix: str, tmp_path: Path
) -> None:
    """inputs.dem and inputs.ortho given as s3:// URLs (read through GDAL's /vsis3/) build
    the local build's manifest and shards; an object replaced since (its ETag) refuses a
    resume, naming the input."""
    for name in ("dem.tif", "ortho.tif"):
        fs.upload(small_mission / "orbital" / name, fs.join(s3_prefix, name))
    doc = small_doc(small_mission, tmp_path / "ds", output={"keep_parts": True})
    doc["inputs"] |= {"dem": f"{s3_prefix}/dem.tif", "ortho": f"{s3_prefix}/ortho.tif"}
    config = parse_config(doc, base=small_mission)
    assert str(config.inputs.dem).startswith("/vsis3/")
    summary = run_build(config, progress=False)
    assert summary.samples == 4
    assert digests(tmp_path / "ds") == digests(local_build)
    fs.upload(small_mission / "orbital" / "dem.tif", fs.join(s3_prefix, "ortho.tif"))
    with pytest.raises(ConfigError, match=r"inputs\.ortho changed .*ETag"):
        run_build(config, resume=True, progress=False)


def test_a_rebuild_on_s3_clears_the_old_build_and_refuses_a_strangers_file(
    small_mission: Path, local_build: Path, s3_prefix: str
) -> None:
    """A prefix holding an object no build stamp lists is refused untouched; a rebuild over
    a finished build (another label count) clears it and gives the local build's bytes."""
    config = config_for(small_mission, s3_prefix)
    assert run_build(config, limit=2, progress=False).samples == 2
    fs.put_bytes(fs.join(s3_prefix, "notes.txt"), b"mine")
    with pytest.raises(ConfigError, match=r"holds notes\.txt"):
        run_build(config, progress=False)
    assert fs.read_bytes(fs.join(s3_prefix, "notes.txt")) == b"mine"
    fs.remove(fs.join(s3_prefix, "notes.txt"))
    assert run_build(config, progress=False).samples == 4
    assert digests(s3_prefix) == digests(local_build)
    assert not [f for f in fs.list_files(s3_prefix) if f.startswith("parts/") or ".tmp-" in f]


def test_the_cli_builds_to_an_s3_url(
    small_mission: Path,
    local_build: Path,
    s3_prefix: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``mars-pairs build --out s3://...``: a dry run writes nothing there, the build gives
    the local build's bytes and prints the URL; ``inspect`` reads it."""
    doc = small_doc(small_mission, tmp_path / "unused")
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert main(["build", "--config", str(path), "--out", s3_prefix + "/", "--dry-run"]) == 0
    assert f"nothing written to {s3_prefix}" in capsys.readouterr().out
    assert fs.list_files(s3_prefix) == []
    assert main(["build", "--config", str(path), "--out", s3_prefix, "--quiet"]) == 0
    assert f"dataset: {s3_prefix}" in capsys.readouterr().out
    assert digests(s3_prefix) == digests(local_build)
    assert main(["inspect", s3_prefix]) == 0
    assert "samples: 4" in capsys.readouterr().out


def test_append_on_s3_is_refused_naming_the_url(small_mission: Path, s3_prefix: str) -> None:
    with pytest.raises(ConfigError, match=r"--append: output\.dir s3://.* object storage"):
        run_build(config_for(small_mission, s3_prefix), append=True, progress=False)


def test_duplicates_across_chunks_on_s3_give_the_local_bytes(
    small_mission: Path, s3_prefix: str, tmp_path: Path
) -> None:
    """Labels repeating product ids of earlier chunks: the driver rewrites a shard on the
    server without its duplicate (downloaded, rewritten, uploaded) or removes it, as it does
    on disk: the same bytes. Chunks of 2: [L0, L1], [copy of L0, L2], [L3, zz copy of L2],
    [zzz copy of L3]."""
    labels = tmp_path / "labels"
    labels.mkdir()
    for f in (small_mission / "labels").iterdir():
        shutil.copy(f, labels / f.name)
    first = sorted(labels.glob("*.xml"))
    shutil.copy(first[0], labels / f"{first[1].stem}_copy.xml")  # sorts right after L1
    shutil.copy(first[2], labels / "zz_copy.xml")
    shutil.copy(first[3], labels / "zzz_copy.xml")

    def build(out: str | Path) -> None:
        doc = small_doc(small_mission, Path("/unused"))
        doc["inputs"]["labels"] = str(labels / "*.xml")
        doc["output"]["dir"] = str(out)
        summary = run_build(parse_config(doc, base=small_mission), progress=False)
        assert (summary.samples, summary.failures) == (4, 3)

    build(tmp_path / "local")
    build(s3_prefix)
    assert digests(s3_prefix) == digests(tmp_path / "local")
    shards = [f for f in fs.list_files(s3_prefix) if f.startswith("shards/")]
    assert sorted({f[: len("shards/shard-000000")] for f in shards}) == [
        f"shards/shard-00000{k}" for k in range(3)
    ]


@pytest.mark.parametrize(
    "target", ["shards/shard-000001-", "parts/.manifest-000001.parquet.tmp-"], ids=str
)
def test_a_worker_killed_mid_upload_resumes_to_the_same_bytes(
    small_mission: Path, local_build: Path, s3_prefix: str, target: str
) -> None:
    """The worker (the one process of a build: ``kill_upload_driver.py``) dies while
    uploading chunk 1's shard or its staged manifest part: nothing appears under that name,
    chunk 0 stays committed, and ``resume`` gives the local build's bytes."""
    config = config_for(small_mission, s3_prefix)
    here = Path(__file__).resolve().parent
    path = os.pathsep.join(
        [str(here.parents[1]), str(here.parent), os.environ.get("PYTHONPATH", "")]
    )
    run = subprocess.run(
        [
            sys.executable,
            str(here / "kill_upload_driver.py"),
            str(small_mission),
            s3_prefix,
            target,
        ],
        env={**os.environ, "PYTHONPATH": path},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == -signal.SIGKILL, run.stderr[-2000:]
    files = fs.list_files(s3_prefix)
    assert "parts/manifest-000000.parquet" in files  # chunk 0 committed
    assert "parts/manifest-000001.parquet" not in files and "manifest.parquet" not in files
    assert not [f for f in files if target in f]  # never completed, never there
    summary = run_build(config, resume=True, progress=False)
    assert (summary.chunks_built, summary.chunks_resumed) == (1, 1)
    assert digests(s3_prefix) == digests(local_build)
    assert not [f for f in fs.list_files(s3_prefix) if ".tmp-" in f]
