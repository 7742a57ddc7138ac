"""Planning: counts, chunks done, a dry run that writes nothing, memory flat in the label
count, the fingerprint of the sorted-glob days, and engines fed lazily."""

from __future__ import annotations

import glob
import hashlib
import shutil
import tracemalloc
from collections.abc import Iterable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder import run as build
from mars_pairs.pipeline.builder import worker
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, Outcome
from mars_pairs.pipeline.builder.label_list import iter_matches
from mars_pairs.pipeline.builder.layout import part_paths
from mars_pairs.pipeline.builder.plan import plan_build
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.builder.stamp import fingerprint
from mars_pairs.pipeline.config import load_config
from mars_pairs.synth.label_tree import plan_config, write_label_tree
from support.configs import config_file

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    """Every file under ``folder``: modification time (ns) and bytes."""
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_plan_counts_labels_chunks_and_limit(tmp_path: Path) -> None:
    pattern = write_label_tree(tmp_path / "in", 10, per_dir=3)
    config = plan_config(tmp_path / "in", pattern, tmp_path / "ds", shard_size=4)
    plan = plan_build(config)
    assert (plan.labels, plan.chunks, plan.chunks_done, plan.labels_to_build) == (10, 3, 0, 10)
    assert plan.clears
    limited = plan_build(config, limit=5)
    assert (limited.labels, limited.chunks, limited.labels_to_build) == (5, 2, 5)
    assert not (tmp_path / "ds").exists()
    with pytest.raises(ConfigError, match="--limit"):
        plan_build(config, limit=0)
    nothing = replace(config, inputs=replace(config.inputs, labels=(str(tmp_path / "*.LBL"),)))
    with pytest.raises(ConfigError, match=r"inputs\.labels: no file matches"):
        plan_build(nothing)


def test_fingerprint_is_the_one_of_the_sorted_glob_list(tmp_path: Path) -> None:
    # '-' sorts before '/' as a character, after it as a path component: the old list order
    for rel in ("a/x.xml", "a-b/x.xml", "a.b/x.xml", "a_b/x.xml", "a0/x.xml", "a/x-1.xml"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).touch()
    patterns = [str(tmp_path / "**" / "*.xml"), str(tmp_path / "a" / "*.xml")]
    config = plan_config(tmp_path / "in", patterns, tmp_path / "ds", shard_size=2)
    # the build before streaming: sorted(set of Path) of every glob match, joined by newlines
    old = sorted({Path(p) for pattern in patterns for p in glob.glob(pattern, recursive=True)})
    digest = hashlib.sha256("\n".join(str(p) for p in old).encode()).hexdigest()
    stamp = plan_build(config).fingerprint
    assert (stamp["labels"], stamp["count"]) == (digest, 6)
    assert fingerprint(config, old) == stamp  # a list of Paths, as before, the same stamp
    assert fingerprint(config, iter(iter_matches(config.inputs.labels))) == stamp


def test_planning_memory_is_flat_in_the_label_count(tmp_path: Path) -> None:
    peaks = {}
    for count in (2_000, 20_000):
        pattern = write_label_tree(tmp_path / str(count), count, per_dir=100)
        config = plan_config(tmp_path / str(count), pattern, tmp_path / f"ds{count}")
        plan_build(config)  # warm: imports, GDAL drivers, regex caches
        tracemalloc.start()
        try:
            plan = plan_build(config)
            peaks[count] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert plan.labels == count
    # listing, chunking and fingerprinting 18,000 more labels: a few KiB (one longer folder
    # listing); the sorted list of Paths it replaces held ~600 bytes a label (~10 MiB here)
    assert peaks[20_000] - peaks[2_000] < 1 << 20, peaks


def _cheap_config(path: Path, mission: Path, out: Path) -> Path:
    return config_file(
        path, mission, out, geometry={"radius": 200, "ray_stride": 64},
        chips={"size_m": 32, "size_px": 16},
        output={"shard_size": 1, "keep_parts": True},  # parts deleted below
    )  # fmt: skip


def test_dry_run_after_a_partial_build_counts_the_chunks_done_and_writes_nothing(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    path = _cheap_config(tmp_path / "c.yaml", small_mission, out)
    assert main(["build", "--config", str(path), "--dry-run", "--resume"]) == 0
    assert not out.exists()
    assert "labels: 4 " in capsys.readouterr().out
    run_build(load_config(path), progress=False)
    part_paths(out, 3)[1].unlink()  # chunk 3 unfinished, as after a kill
    part_paths(out, 1)[1].unlink()
    before = _snapshot(out)
    assert main(["build", "--config", str(path), "--dry-run", "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "chunks: 4 of up to 1 labels" in printed
    assert "chunks done: 2 (kept by --resume)" in printed
    assert "samples to build: 2 " in printed
    assert main(["build", "--config", str(path), "--dry-run"]) == 0
    assert "chunks done: 0 (no --resume" in capsys.readouterr().out
    assert main(["build", "--config", str(path), "--dry-run", "--resume", "--limit", "2"]) == 2
    assert "cannot resume" in capsys.readouterr().err  # another label list than the stamp's
    assert _snapshot(out) == before
    resumed = run_build(load_config(path), resume=True, progress=False)
    assert (resumed.chunks_built, resumed.chunks_resumed, resumed.samples) == (2, 2, 4)


def _failing(chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
    for task in chunks:
        error = ValueError("not built")
        rows = [worker.failure_row(label, "label", error) for label in task.labels]
        fails = tuple(Outcome("fail", row["path"], row=row) for row in rows)
        yield ChunkResult(task.index, fails, (), 0.0, "test")


def test_engines_get_the_chunks_lazily(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pattern = write_label_tree(tmp_path / "in", 10, per_dir=4)
    config = plan_config(tmp_path / "in", pattern, tmp_path / "ds", shard_size=3)
    config = replace(config, output=replace(config.output, keep_parts=True))  # a part is deleted
    pulled: list[int] = []

    class Engine:
        def run(self, config: Any, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
            assert not isinstance(chunks, (list, tuple))
            for chunk in chunks:
                pulled.append(len(chunk.labels))
                assert len(list((tmp_path / "ds" / "parts").glob("manifest-*"))) == len(pulled) - 1
                yield from _failing([chunk])

    summary = run_build(config, engine=Engine(), progress=False)
    assert pulled == [3, 3, 3, 1]
    assert (summary.failures, summary.chunks_built) == (10, 4)

    seen: list[type] = []

    class Local:  # the one-worker build's engine
        def run(self, config: Any, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
            seen.append(type(chunks))
            assert not isinstance(chunks, (list, tuple))
            return _failing(chunks)

    monkeypatch.setattr(build, "InProcess", Local)
    part_paths(tmp_path / "ds", 2)[1].unlink()
    again = run_build(config, resume=True, progress=False)
    assert (again.chunks_built, again.chunks_resumed, again.failures) == (1, 3, 10)
    assert len(seen) == 1


def test_a_label_list_that_changes_during_the_build_is_refused(tmp_path: Path) -> None:
    pattern = write_label_tree(tmp_path / "in", 10, per_dir=3)
    config = plan_config(tmp_path / "in", pattern, tmp_path / "ds", shard_size=3)
    late = tmp_path / "in" / "sol" / "00003" / "ids" / "ZLF_00003_9999.xml"

    class Engine:
        def run(self, config: Any, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
            for chunk in chunks:
                late.touch()  # a label appears in a folder the second pass has not listed
                yield from _failing([chunk])

    with pytest.raises(ConfigError, match=r"inputs\.labels: .*10 labels listed, then 11"):
        run_build(config, engine=Engine(), progress=False)
    with pytest.raises(ConfigError, match="cannot resume"):
        run_build(config, resume=True, progress=False)


def test_a_real_config_without_its_files_points_at_fetch_all(tmp_path: Path) -> None:
    repo = Path(__file__).resolve().parents[2]
    work = tmp_path / "checkout"
    shutil.copytree(repo / "configs", work / "configs")  # nothing fetched beside it
    config = work / "configs" / "msl_gale.yaml"
    with pytest.raises(ConfigError, match=r"no file matches .*mars-pairs fetch all --config "):
        plan_build(load_config(config))
    assert main(["build", "--config", str(config), "--dry-run"]) == 2
