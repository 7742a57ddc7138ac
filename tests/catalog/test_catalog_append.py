"""``mars-pairs catalog --append``: a catalogue of release A then ``--append`` of release B
equals the catalogue of A+B made at once (the same rows, pairs, failures, STAC items; the
rows of A untouched), a duplicate key is a failure row as in one run, nothing new writes
nothing, a killed append reruns to the same folder, a changed config is refused naming the
key."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.catalog import run as catalog_run
from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.store.seal import files_record
from support.configs import build_config, config_file

#: catalogues of a few labels each, several runs a test
pytestmark = pytest.mark.slow

Releases = tuple[Path, list[str], list[str]]
Folders = tuple[Path, Path, Path]
SECTIONS = {"geometry": {"radius": 100}, "output": {"shard_size": 3}}


@pytest.fixture(scope="module")
def releases(missions, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """(mission, release A's label paths, release B's glob): A the first half of the labels
    and a broken one, B every label of the folder: the rest, a copy of A's first label under
    a later name (a duplicate key) and another broken label."""
    mission = missions(seed=5, stops=3, images_per_stop=3)
    root = tmp_path_factory.mktemp("releases")
    labels = root / "labels"
    shutil.copytree(mission / "labels", labels)
    names = sorted(p.name for p in labels.glob("*.xml"))
    first = names[: len(names) // 2]
    (labels / "AAA_0000_broken.xml").write_text("not a label")
    (labels / "ZZZ_9999_broken.xml").write_text("not a label")
    newer = labels / first[0].replace(".xml", "_v2.xml")
    shutil.copyfile(labels / first[0], newer)
    release_a = [str(labels / n) for n in (*first, "AAA_0000_broken.xml")]
    return mission, release_a, [str(labels / "*.xml")]


def _digests(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _rows(path: Path, key: str) -> list[dict[str, object]]:
    table = pq.read_table(path)
    return sorted(table.to_pylist(), key=lambda r: str(r[key]))


def _failures(folder: Path) -> list[tuple[object, ...]]:
    rows = pq.read_table(folder / "failures.parquet").to_pylist()
    return sorted((r["path"], r["stage"], r["error_type"], r["message"]) for r in rows)


@pytest.fixture(scope="module")
def appended(releases, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """(A then --append B, A+B at once, A alone) catalogue folders."""
    mission, release_a, release_b = releases
    base = tmp_path_factory.mktemp("appended")
    config_a = build_config(mission, base / "x", labels=release_a, **SECTIONS)
    config_b = build_config(mission, base / "x", labels=release_b, **SECTIONS)
    run_catalog(config_a, base / "a", progress=False)
    shutil.copytree(base / "a", base / "ab")
    summary = run_catalog(config_b, base / "ab", progress=False, append=True)
    assert summary.chunks_resumed == 0 and summary.chunks_built > 0
    run_catalog(config_b, base / "once", progress=False)
    return base / "ab", base / "once", base / "a"


def test_append_equals_one_run_of_both_releases(appended: Folders) -> None:
    ab, once, a = appended
    assert _rows(ab / "catalog.parquet", "key") == _rows(once / "catalog.parquet", "key")
    # the same Hilbert order: the table itself is the one-run table
    assert pq.read_table(ab / "catalog.parquet").equals(pq.read_table(once / "catalog.parquet"))
    pairs = _rows(ab / "pairs.parquet", "key_a")
    assert pairs and sorted(pairs, key=lambda r: (r["key_a"], r["key_b"])) == sorted(
        _rows(once / "pairs.parquet", "key_a"), key=lambda r: (r["key_a"], r["key_b"])
    )
    a_keys = set(pq.read_table(a / "catalog.parquet")["key"].to_pylist())
    new_old = [p for p in pairs if (p["key_a"] in a_keys) != (p["key_b"] in a_keys)]
    assert new_old, "no pair between a release-A and a release-B image"
    assert _failures(ab) == _failures(once)
    assert {f[2] for f in _failures(ab)} >= {"DuplicateKeyError"}
    items = sorted((ab / "items.ndjson").read_text().splitlines())
    assert items == sorted((once / "items.ndjson").read_text().splitlines())
    assert pq.read_table(ab / "items.parquet").num_rows == len(items)
    doc, one = (json.loads((f / "catalog.json").read_text()) for f in (ab, once))
    assert doc["counts"] == one["counts"] and doc["input_files"] == one["input_files"]
    assert doc["stamp"] == one["stamp"]
    (record,) = doc["appends"]
    assert record["labels_known"] == len(pq.read_table(a / "catalog.parquet")) + 1
    assert record["images"] + record["failures"] == record["labels_added"]
    assert doc["files"] == files_record(ab, tuple(doc["files"]))
    assert not (ab / "parts").exists()


def test_append_keeps_the_existing_rows(appended: Folders) -> None:
    ab, _, a = appended
    before = {r["key"]: r for r in pq.read_table(a / "catalog.parquet").to_pylist()}
    after = {r["key"]: r for r in pq.read_table(ab / "catalog.parquet").to_pylist()}
    assert before and all(after[k] == row for k, row in before.items())
    assert len(after) > len(before)


def test_nothing_new_writes_nothing_and_a_killed_append_reruns_the_same(
    releases: Releases, appended: Folders, tmp_path: Path
) -> None:
    mission, _, release_b = releases
    ab, _, a = appended
    config_b = build_config(mission, tmp_path / "x", labels=release_b, **SECTIONS)
    again = tmp_path / "again"
    shutil.copytree(ab, again)
    summary = run_catalog(config_b, again, progress=False, append=True)
    assert summary.chunks_built == 0 and _digests(again) == _digests(ab)

    killed = tmp_path / "killed"
    shutil.copytree(a, killed)
    real = catalog_run._commit
    calls = []

    def commit_then_die(out, result, seen):  # type: ignore[no-untyped-def]
        if calls:
            raise KeyboardInterrupt  # killed after the append's first chunk committed
        calls.append(1)
        real(out, result, seen)

    catalog_run._commit = commit_then_die  # type: ignore[assignment]
    try:
        with pytest.raises(KeyboardInterrupt):
            run_catalog(config_b, killed, progress=False, append=True)
    finally:
        catalog_run._commit = real  # type: ignore[assignment]
    assert (killed / "parts" / "base-catalog.parquet").is_file()
    with pytest.raises(ConfigError, match="interrupted --append"):
        run_catalog(config_b, killed, progress=False, resume=True)
    summary = run_catalog(config_b, killed, progress=False, append=True)
    assert summary.chunks_resumed == 1
    assert _digests(killed) == _digests(ab)


def test_append_refuses_a_changed_config_or_no_catalogue(
    releases: Releases, appended: Folders, tmp_path: Path
) -> None:
    mission, _, release_b = releases
    _, _, a = appended
    copy = tmp_path / "copy"
    shutil.copytree(a, copy)
    sections = {**SECTIONS, "geometry": {"radius": 120}}
    changed = build_config(mission, tmp_path / "x", labels=release_b, **sections)
    with pytest.raises(ConfigError, match=r"geometry\.radius: changed"):
        run_catalog(changed, copy, progress=False, append=True)
    assert _digests(copy) == _digests(a)
    config_b = build_config(mission, tmp_path / "x", labels=release_b, **SECTIONS)
    with pytest.raises(ConfigError, match="make it first"):
        run_catalog(config_b, tmp_path / "empty", progress=False, append=True)


def test_cli_append(releases: Releases, appended: Folders, tmp_path: Path) -> None:
    mission, _, release_b = releases
    ab, _, a = appended
    out = tmp_path / "cli"
    shutil.copytree(a, out)
    config = config_file(tmp_path / "b.yaml", mission, tmp_path / "x", labels=release_b, **SECTIONS)
    argv = ["catalog", "--config", str(config), "--out", str(out), "--append", "--quiet"]
    assert main(argv) == 0
    assert pq.read_table(out / "catalog.parquet").equals(pq.read_table(ab / "catalog.parquet"))
    assert main([*argv, "--resume"]) == 2
    unpaired = tmp_path / "unpaired"
    shutil.copytree(a, unpaired)
    argv = ["catalog", "--config", str(config), "--out", str(unpaired), "--append", "--quiet"]
    assert main([*argv, "--no-pairs"]) == 0
    assert not (unpaired / "pairs.parquet").exists()  # the old pairs lack the new images
    assert json.loads((unpaired / "catalog.json").read_text())["counts"]["pairs"] == 0
