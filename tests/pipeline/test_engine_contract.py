"""The engines' contract (issue 24): a worker writes its chunk's shard and stages its parts,
the driver receives rows and member locations only and commits the chunks in order;
duplicate product ids inside a chunk and across chunks give the same failure rows and the
same bytes whatever the worker count."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import re
import shutil
import tarfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.errors import MarsPairsError
from mars_pairs.pipeline.builder import run as build
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, InProcess
from mars_pairs.pipeline.builder.layout import is_temporary
from mars_pairs.pipeline.builder.local_pool import LocalPool
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store.manifest import MANIFEST_SCHEMA
from mars_pairs.store.shards import MemberLocation, ShardWriter, read_member
from support.configs import build_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _digests(out: Path) -> dict[str, str]:
    return {
        p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(out.rglob("*"))
        if p.is_file()
        and p.name not in ("dataset.json", "SHA256SUMS", "shardindex.json")  # hold paths
    }


def _leaves(value: Any, path: str = "") -> Iterator[tuple[str, Any]]:
    """Every leaf value inside dataclasses, dicts, lists and tuples, with its path."""
    if dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            yield from _leaves(getattr(value, f.name), f"{path}.{f.name}")
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, f"{path}[{k}]")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from _leaves(v, f"{path}[{i}]")
    else:
        yield path, value


def test_a_pool_worker_writes_the_shard_and_sends_back_rows_only(
    small_mission: Path, tmp_path: Path
) -> None:
    config = build_config(small_mission, tmp_path / "ds", output={"shard_size": 4})
    labels = tuple(sorted(str(p) for p in (small_mission / "labels").glob("*.xml")))
    with LocalPool(config, workers=1) as pool:
        (result,) = list(pool.run(config, iter([ChunkTask(0, labels)])))
    assert isinstance(result, ChunkResult) and result.index == 0
    assert [o.kind for o in result.outcomes] == ["ok"] * 4
    assert result.worker.rsplit(":", 1)[1] != str(os.getpid())  # built elsewhere
    # no member bytes travel: rows (whose binaries are WKB geometry columns), locations,
    # timings; a few KB a sample at most
    wkb = {f"[{f.name}]" for f in MANIFEST_SCHEMA if pa.types.is_binary(f.type)}
    binary = [p for p, v in _leaves(result) if isinstance(v, (bytes, bytearray, memoryview))]
    assert binary and all(p[p.rindex("[") :] in wkb for p in binary), binary
    assert len(pickle.dumps(result)) < 4096 * len(labels)
    out = tmp_path / "ds"
    assert result.shards
    for rel, size in result.shards:  # in place under their final names, one per split
        assert (out / rel).stat().st_size == size
    assert all(is_temporary(rel) and (out / rel).is_file() for rel in result.staged)
    for o in result.outcomes:  # every location reads back, checksum verified
        for name, loc in o.members.items():
            assert isinstance(loc, MemberLocation)
            assert loc.shard == f"shards/shard-000000-{o.row['split']}.tar"
            read_member(out, loc, name=f"{o.key}.{name}", verify=True)
            fld = name.split(".")[0]
            assert (o.row[f"{fld}_offset"], o.row[f"{fld}_size"]) == (loc.offset, loc.size)
    assert not (out / "parts" / "manifest-000000.parquet").exists()  # the driver commits


@pytest.fixture(scope="module")
def duplicates(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The 4 labels plus 3 copies under other names (the same product ids): one sorted right
    after its original (a duplicate inside chunk 0), one beside a new sample in chunk 2 and
    one alone in chunk 3 (duplicates of earlier chunks). Chunks of 2:
    [L0, L0 copy], [L1, L2], [L3, zz copy of L1], [zzz copy of L2]."""
    folder = tmp_path_factory.mktemp("dup") / "labels"
    folder.mkdir()
    for f in (small_mission / "labels").iterdir():
        shutil.copy(f, folder / f.name)
    labels = sorted(folder.glob("*.xml"))
    assert len(labels) == 4
    shutil.copy(labels[0], folder / f"{labels[0].stem}_copy.xml")
    shutil.copy(labels[1], folder / "zz_copy.xml")
    shutil.copy(labels[2], folder / "zzz_copy.xml")
    return folder


def _dup_config(small_mission: Path, labels: Path, out: Path) -> BuildConfig:
    return build_config(small_mission, out, labels=labels / "*.xml", output={"shard_size": 2})


def test_duplicates_in_and_across_chunks_give_the_same_bytes_on_any_worker_count(
    small_mission: Path, duplicates: Path, tmp_path: Path
) -> None:
    one = run_build(_dup_config(small_mission, duplicates, tmp_path / "one"), progress=False)
    two = run_build(
        _dup_config(small_mission, duplicates, tmp_path / "two"), workers=2, progress=False
    )
    assert (one.samples, one.failures) == (two.samples, two.failures) == (4, 3)
    assert _digests(tmp_path / "one") == _digests(tmp_path / "two")
    out = tmp_path / "one"
    labels = sorted(p for p in duplicates.glob("*.xml") if "copy" not in p.name)
    fails = {Path(r["path"]).name: r for r in pq.read_table(out / "failures.parquet").to_pylist()}
    firsts = {f"{labels[0].stem}_copy.xml": labels[0], "zz_copy.xml": labels[1]}
    firsts["zzz_copy.xml"] = labels[2]
    assert set(fails) == set(firsts)
    for name, first in firsts.items():
        row = fails[name]
        assert (row["stage"], row["error_type"]) == ("record", "DuplicateKeyError")
        assert row["message"].endswith(f"already built from {first.name}"), row["message"]
    # chunk 2's shard was written again without the duplicate: exactly L3's members, the
    # bytes a shard of L3 alone has; chunk 3 (its only sample a duplicate) has no shard
    manifest = pq.read_table(out / "manifest.parquet").to_pylist()
    row = next(r for r in manifest if Path(r["label_path"]).name == labels[3].name)
    shard = out / row["meta_shard"]
    assert shard.name == f"shard-000002-{row['split']}.tar"
    with tarfile.open(shard) as tar:
        names = tar.getnames()
    assert names and all(n.startswith(row["key"] + ".") for n in names)
    assert not list((out / "shards").glob("shard-000003*"))
    members = {}
    for name in names:
        fld = name[len(row["key"]) + 1 :].split(".")[0]
        loc = MemberLocation(row[f"{fld}_shard"], row[f"{fld}_offset"], row[f"{fld}_size"],
                             row[f"{fld}_crc32c"])  # fmt: skip
        members[name[len(row["key"]) + 1 :]] = read_member(out, loc, name=name, verify=True)
    with ShardWriter(tmp_path / "alone", row["meta_shard"]) as alone:
        alone.add(row["key"], members)
    assert (tmp_path / "alone" / row["meta_shard"]).read_bytes() == shard.read_bytes()
    assert not any(is_temporary(p.relative_to(out).as_posix()) for p in out.rglob(".*"))


class _Meddling:
    """The in-process engine, with ``meddle(out, result)`` run on each result."""

    def __init__(self, meddle: Any) -> None:
        self.meddle = meddle

    def run(self, config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        for result in InProcess().run(config, chunks):
            self.meddle(config.output.dir, result)
            yield result


def test_a_dead_workers_temporary_shard_is_gone_when_the_build_ends(
    small_mission: Path, tmp_path: Path
) -> None:
    def leave_a_temporary(out: Path, result: ChunkResult) -> None:
        (out / "shards" / f".shard-{result.index:06d}.tar.tmp-999999").write_bytes(b"half")

    config = build_config(small_mission, tmp_path / "ds", output={"shard_size": 2})
    summary = run_build(config, engine=_Meddling(leave_a_temporary), progress=False)
    assert summary.samples == 4
    names = sorted(p.name for p in (tmp_path / "ds" / "shards").iterdir())
    assert all(re.fullmatch(r"shard-00000[01]-[a-z]+\.tar", n) for n in names), names
    assert {n[:12] for n in names} == {"shard-000000", "shard-000001"}


def test_a_shard_changed_after_its_worker_wrote_it_is_not_committed(
    small_mission: Path, tmp_path: Path
) -> None:
    def truncate(out: Path, result: ChunkResult) -> None:
        rel, size = result.shards[0]
        with open(out / rel, "r+b") as fh:
            fh.truncate(size - 512)

    config = build_config(small_mission, tmp_path / "ds", output={"shard_size": 2})
    with pytest.raises(MarsPairsError, match=r"shard-000000-[a-z]+\.tar: .* bytes, but its worker"):
        run_build(config, engine=_Meddling(truncate), progress=False)
    assert not (tmp_path / "ds" / "parts" / "manifest-000000.parquet").exists()


def test_run_build_takes_typed_engines() -> None:
    import inspect
    import typing

    hints = typing.get_type_hints(build.run_build)
    assert "Engine" in str(hints["engine"])
    assert "Any" not in str(inspect.signature(build._run).parameters["engine"].annotation)
