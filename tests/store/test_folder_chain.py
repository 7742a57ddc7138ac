"""The folder's integrity chain (``store.seal``): dataset.json records the SHA-256 and size of
the manifest, the failures, the card, croissant.json and the shard index; SHA256SUMS records
dataset.json's. ``mars-pairs verify`` names every damaged file, ``MarsPairsDataset(verify=True)``
refuses a damaged manifest or dataset.json at open: no flipped bit is served silently."""

from __future__ import annotations

import hashlib
import json
import random
import shutil
import subprocess
import warnings
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import DatasetError
from mars_pairs.store.seal import FILES_KEY, NO_RECORD, SEALED, SUMS, chain_damage, sealed_names
from mars_pairs.store.verify import verify_dataset
from mars_pairs.torch import MarsPairsDataset
from support.builds import build_small

SEED = 35


@pytest.fixture(scope="module")
def sealed(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small dataset, built once (read only: tests damage a copy)."""
    return build_small(small_mission, tmp_path_factory.mktemp("chain") / "ds")


@pytest.fixture()
def copy(sealed: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(sealed, tmp_path / "ds"))


def named(root: Path) -> set[str]:
    """The files ``verify`` names as damaged (an unreadable manifest: the one error naming it,
    with what the chain found)."""
    try:
        return {d.path for d in verify_dataset(root).damage}
    except DatasetError as exc:
        return {Path(str(exc.path)).name}


def refused(root: Path) -> bool:
    """Whether ``MarsPairsDataset(verify=True)`` refuses to open ``root``, or serves every
    sample only with a DatasetError."""
    try:
        with MarsPairsDataset(root, verify=True) as ds:
            for i in range(len(ds)):
                ds[i]
    except DatasetError:
        return True
    return False


def test_the_record_covers_the_folders_own_files_only(tmp_path: Path) -> None:
    """A split list or pairs file in a subfolder is not the folder's: not sealed."""
    (tmp_path / "parts").mkdir()
    for name in ("shards-val.txt", "pairs.parquet", "shardindex-test.json"):
        (tmp_path / "parts" / name).write_text("x")
    (tmp_path / "shards-train.txt").write_text("x")
    (tmp_path / "shardindex-train.json").mkdir()  # a folder of that name: not a file
    assert sealed_names(tmp_path) == [*SEALED, "shards-train.txt"]


def test_a_build_seals_its_folder(sealed: Path) -> None:
    doc = json.loads((sealed / "dataset.json").read_bytes())
    assert sorted(doc[FILES_KEY]) == sorted(sealed_names(sealed))
    assert set(SEALED) <= set(doc[FILES_KEY])
    assert any(n.startswith("shards-") for n in doc[FILES_KEY])  # the split lists too
    for name, entry in doc[FILES_KEY].items():
        data = (sealed / name).read_bytes()
        assert entry == {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    sums = (sealed / SUMS).read_text()
    assert (
        sums
        == f"{hashlib.sha256((sealed / 'dataset.json').read_bytes()).hexdigest()}  dataset.json\n"
    )
    # the coreutils tool checks the sidecar as it is
    assert subprocess.run(["sha256sum", "-c", "--quiet", SUMS], cwd=sealed).returncode == 0
    assert chain_damage(sealed) == []
    report = verify_dataset(sealed)
    assert report.damage == [] and report.notes == []


def test_60_random_bit_flips_in_the_manifest_are_all_caught(copy: Path) -> None:
    path = copy / "manifest.parquet"
    original = path.read_bytes()
    rng = random.Random(SEED)
    flips = [(rng.randrange(len(original)), rng.randrange(8)) for _ in range(60)]
    if len(original) > 21496:  # the sweep's silent flip on the demo
        flips.append((21496, 1))
    silent = []
    for offset, bit in flips:
        damaged = bytearray(original)
        damaged[offset] ^= 1 << bit
        path.write_bytes(bytes(damaged))
        in_verify = "manifest.parquet" in named(copy)
        if not in_verify or not refused(copy):
            silent.append((offset, bit, in_verify))
    path.write_bytes(original)
    assert silent == []
    assert named(copy) == set()


def test_30_digit_flips_in_dataset_json_are_all_caught(copy: Path) -> None:
    path = copy / "dataset.json"
    original = path.read_bytes()
    digits = [i for i, c in enumerate(original) if chr(c).isdigit()]
    rng = random.Random(SEED)
    silent = []
    for at in rng.sample(digits, 30):
        damaged = bytearray(original)
        damaged[at] = ord(str((int(chr(damaged[at])) + 1) % 10))
        path.write_bytes(bytes(damaged))
        if "dataset.json" not in named(copy) or not refused(copy):
            silent.append(at)
    assert silent == []


def test_the_sweeps_edits_of_dataset_json_are_caught(copy: Path) -> None:
    """ray_stride 8 -> 9 changed corr_ground, an edited CRS the returned crs: both named."""
    path = copy / "dataset.json"
    doc = json.loads(path.read_bytes())
    doc["config"]["geometry"]["ray_stride"] += 1
    path.write_text(json.dumps(doc, indent=2))
    assert named(copy) == {"dataset.json"}
    with pytest.raises(DatasetError, match=r"dataset\.json.*SHA256SUMS"):
        MarsPairsDataset(copy, verify=True)


def _rewrite(root: Path, edit: object) -> None:
    table = pq.read_table(root / "manifest.parquet")
    rows = table.to_pylist()
    edit(rows)  # type: ignore[operator]
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), root / "manifest.parquet")


@pytest.mark.parametrize(
    "edit",
    [
        lambda rows: rows.pop(1),
        lambda rows: rows[0].update(azimuth_deg=rows[0]["azimuth_deg"] + 88),
    ],
    ids=["row-removed", "value-edited"],
)
def test_a_valid_rewritten_manifest_is_caught(copy: Path, edit: object) -> None:
    _rewrite(copy, edit)
    assert "manifest.parquet" in named(copy)
    with pytest.raises(DatasetError, match=r"manifest\.parquet"):
        MarsPairsDataset(copy, verify=True)


@pytest.mark.parametrize("name", [n for n in SEALED if n != "manifest.parquet"])
@pytest.mark.parametrize("how", ["deleted", "truncated"])
def test_a_deleted_or_truncated_file_is_named(copy: Path, name: str, how: str) -> None:
    path = copy / name
    if how == "deleted":
        path.unlink()
    else:
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    report = verify_dataset(copy)
    assert name in {d.path for d in report.damage}, report.format()
    line = next(str(d) for d in report.damage if d.path == name)
    assert ("missing" if how == "deleted" else "truncated") in line


def test_cli_verify_names_the_file_and_exits_2(
    copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (copy / "croissant.json").write_text("{}")
    assert main(["verify", str(copy)]) == 2
    err = capsys.readouterr().err
    assert "croissant.json: 2 bytes, dataset.json records" in err


def test_sidecar_missing_or_damaged_is_named(copy: Path) -> None:
    (copy / SUMS).write_text("not a sum\n")
    assert named(copy) == {"dataset.json"}
    (copy / SUMS).unlink()
    assert named(copy) == {SUMS}


def test_an_old_dataset_warns_no_integrity_record_once(
    copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = json.loads((copy / "dataset.json").read_bytes())
    del doc[FILES_KEY]
    (copy / "dataset.json").write_text(json.dumps(doc))
    (copy / SUMS).unlink()
    assert main(["verify", str(copy)]) == 0
    out = capsys.readouterr().out
    assert out.count("no integrity record") == 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with MarsPairsDataset(copy, verify=True) as ds:
            for i in range(len(ds)):
                ds[i]
    assert [str(w.message).count(NO_RECORD) for w in caught] == [1]
