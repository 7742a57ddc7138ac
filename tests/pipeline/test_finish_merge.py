"""The finish's merge, a part at a time (sorted runs on disk, merged), against the whole
table sorted in memory and written at once: the same bytes, the same counts."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.pipeline.builder import finish
from mars_pairs.store import parquet_stream
from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.geoparquet import table_geo_metadata
from mars_pairs.store.manifest import FAILURE_SCHEMA, MANIFEST_SCHEMA, rows_to_table
from mars_pairs.store.wids_index import shard_counts
from mars_pairs.synth.label_tree import plan_config
from tests.support.manifests import write_place_manifest


def _in_memory(config, parts, fails, out: Path) -> tuple[pa.Table, pa.Table]:
    """The reference: every part concatenated, sorted and written at once."""
    parts = [t.replace_schema_metadata(None) for t in parts]
    fails = [t.replace_schema_metadata(None) for t in fails]
    manifest = pa.concat_tables(parts) if parts else MANIFEST_SCHEMA.empty_table()
    manifest = manifest.sort_by([("hilbert", "ascending"), ("key", "ascending")])
    failures = pa.concat_tables(fails) if fails else FAILURE_SCHEMA.empty_table()
    crs = finish.dataset_crs(config)
    manifest = manifest.replace_schema_metadata(table_geo_metadata(manifest, crs))
    write_parquet_atomic(
        manifest, out / "manifest.parquet", row_group_size=finish.MANIFEST_ROW_GROUP
    )
    write_parquet_atomic(failures, out / "failures.parquet")
    return manifest, failures


def _parts(tmp_path: Path, n: int, seed: int) -> tuple[list[pa.Table], list[pa.Table]]:
    """``n`` manifest rows in shuffled parts of random sizes (Hilbert ties, some parts with
    no footprint), and failure parts."""
    rng = np.random.default_rng(seed)
    table = write_place_manifest(tmp_path / "gen", n=n, seed=seed)
    order = rng.permutation(n)
    table = table.take(order)
    hilbert = pa.array(rng.integers(0, n // 4, n), pa.int64())  # ties: ordered by key
    shards = pa.array([f"shards/shard-{i % 7:06d}-x.tar" for i in range(n)])
    table = table.set_column(table.schema.get_field_index("hilbert"), "hilbert", hilbert)
    table = table.set_column(table.schema.get_field_index("meta_shard"), "meta_shard", shards)
    cuts = np.sort(rng.choice(np.arange(1, n), size=n // 40, replace=False))
    parts = [table.slice(a, b - a) for a, b in zip([0, *cuts], [*cuts, n], strict=True)]
    parts[1] = parts[1].set_column(
        parts[1].schema.get_field_index("bbox"),
        "bbox",
        pa.nulls(parts[1].num_rows, parts[1].schema.field("bbox").type),
    )
    parts.insert(3, table.slice(0, 0))  # an empty chunk
    stages = ("label", "pose", "view", "duplicate")
    fails = [
        rows_to_table(
            [
                {"path": f"p{k}-{i}.lbl", "stage": stages[(k + i) % 4], "error_type": f"E{i % 3}"}
                for i in range(int(rng.integers(100, 200)))
            ],
            FAILURE_SCHEMA,
        )
        for k in range(len(parts))
    ]
    return parts, fails


@pytest.mark.parametrize("run_rows", [100_000, 97])  # one run in memory; runs on disk
def test_merge_equals_the_whole_table_sorted(tmp_path: Path, monkeypatch, run_rows) -> None:
    monkeypatch.setattr(finish, "RUN_ROWS", run_rows)
    monkeypatch.setattr(finish, "MANIFEST_ROW_GROUP", 1024)  # more than one row group
    monkeypatch.setattr(parquet_stream, "FAN_IN", 4)  # merged in passes too
    monkeypatch.setattr(parquet_stream, "RUN_ROW_GROUP", 5)
    monkeypatch.setattr(parquet_stream, "OUT_ROWS", 40)
    parts, fails = _parts(tmp_path, 1200, seed=5)
    assert sum(t.num_rows for t in fails) > 4096  # more than one failures row group
    config = plan_config(tmp_path / "inputs", "none/*.lbl", tmp_path / "new")
    (tmp_path / "old").mkdir()
    manifest, failures = _in_memory(config, parts, fails, tmp_path / "old")
    merged = finish.write_merged(config, iter(parts), iter(fails))
    for name in ("manifest.parquet", "failures.parquet"):
        assert (tmp_path / "new" / name).read_bytes() == (tmp_path / "old" / name).read_bytes()
    assert pq.read_metadata(tmp_path / "new" / "manifest.parquet").num_row_groups == 2
    assert merged.samples == manifest.num_rows == 1200
    assert merged.failures == failures.num_rows
    split_counts = dict(Counter(manifest["split"].to_pylist()))
    assert list(merged.by_split.items()) == list(split_counts.items())  # first seen first
    assert merged.by_mission == dict(Counter(manifest["mission"].to_pylist()))
    assert merged.shards == shard_counts(manifest)
    reasons = Counter(
        f"{s} ({e})"
        for s, e in zip(
            failures["stage"].to_pylist(), failures["error_type"].to_pylist(), strict=True
        )
    )
    assert list(merged.failures_by_reason.items()) == list(reasons.items())


def test_merge_of_no_part(tmp_path: Path) -> None:
    config = plan_config(tmp_path / "inputs", "none/*.lbl", tmp_path / "new")
    (tmp_path / "old").mkdir()
    _in_memory(config, [], [], tmp_path / "old")
    merged = finish.write_merged(config, iter([]), iter([]))
    assert (merged.samples, merged.failures, merged.shards) == (0, 0, {})
    for name in ("manifest.parquet", "failures.parquet"):
        assert (tmp_path / "new" / name).read_bytes() == (tmp_path / "old" / name).read_bytes()


def test_the_sorted_runs_are_in_the_output_folder(tmp_path: Path, monkeypatch) -> None:
    """A local build's runs are written in parts/sort of its output folder (never the
    system's temporary folder) and removed when the merge ends."""
    monkeypatch.setattr(finish, "RUN_ROWS", 97)
    seen: list[Path] = []
    real = finish.sorted_runs

    def spy(tables, keys, run_rows, folder):
        runs, whole = real(tables, keys, run_rows, folder)
        seen.extend(runs)
        assert all(p.is_file() for p in runs)
        return runs, whole

    def no_staging():
        raise AssertionError("a local build staged its runs outside its output folder")

    monkeypatch.setattr(finish, "sorted_runs", spy)
    monkeypatch.setattr(finish.fs, "local_staging", no_staging)
    parts, fails = _parts(tmp_path, 400, seed=3)
    out = tmp_path / "new"
    config = plan_config(tmp_path / "inputs", "none/*.lbl", out)
    finish.write_merged(config, iter(parts), iter(fails))
    assert len(seen) >= 2  # runs on disk, not one table in memory
    assert {p.parent for p in seen} == {out / "parts" / "sort"}
    assert not (out / "parts" / "sort").exists()


def test_a_killed_finishs_runs_are_build_files(tmp_path: Path) -> None:
    """Runs a killed finish left do not make the folder foreign; the next build clears them
    (and a resumed finish replaces them); a file of another name in the folder stays."""
    from mars_pairs.pipeline.builder.hygiene import clear_outputs, foreign_file
    from mars_pairs.pipeline.builder.layout import SORT_RUNS

    out = tmp_path / "ds"
    (out / SORT_RUNS).mkdir(parents=True)
    (out / "parts/build.json").write_text('{"count": 1, "config": {"output": {"shard_size": 1}}}')
    for name in ("run-000000.arrow", "run-000001.arrow", "merged-001-000000.arrow"):
        (out / SORT_RUNS / name).write_bytes(b"x")
    assert foreign_file(out) is None
    clear_outputs(out)
    assert not (out / SORT_RUNS).exists()
    (out / SORT_RUNS).mkdir(parents=True)
    (out / SORT_RUNS / "notes.txt").write_text("mine")
    assert foreign_file(out) == f"{SORT_RUNS}/notes.txt"
