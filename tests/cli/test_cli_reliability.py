"""Hostile command lines and damaged datasets (issue 17): one line naming the file and the
field, exit 2, never a traceback; ``verify`` names damaged members by shard and key."""

from __future__ import annotations

import json
import os
import re
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mars_pairs.cli.main import main
from support.builds import build_small
from support.members import manifest_keys

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = build_small(small_mission, tmp_path_factory.mktemp("built") / "ds")
    assert len(manifest_keys(out)) == 4
    return out


@pytest.fixture()
def copy(built: Path, tmp_path: Path) -> Path:
    """A private copy of the built dataset, to damage."""
    return Path(shutil.copytree(built, tmp_path / "ds"))


def one_line_error(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


# -- verify ---------------------------------------------------------------------------------
def _row(root: Path, i: int = 0) -> dict:
    return sorted(pq.read_table(root / "manifest.parquet").to_pylist(), key=lambda r: r["key"])[i]


def _poke(root: Path, shard: str, offset: int, data: bytes) -> None:
    with open(root / shard, "r+b") as fh:
        fh.seek(offset)
        fh.write(data)


def test_verify_passes_an_intact_dataset(built: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["verify", str(built)]) == 0
    assert "24 members in 2 shards checked: all intact" in capsys.readouterr().out


def test_verify_names_members_with_damaged_payloads(
    copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    row = _row(copy, 0)
    rng = np.random.default_rng(0)
    # 64 random bytes in the middle of a dem.tif payload (its zstd strip), 300 in ground.jpg
    _poke(copy, row["dem_shard"], row["dem_offset"] + row["dem_size"] // 2, rng.bytes(64))
    _poke(copy, row["ground_shard"], row["ground_offset"] + 200, rng.bytes(300))
    assert main(["verify", str(copy)]) == 2
    err = capsys.readouterr().err.splitlines()
    key = row["key"]
    assert (
        err[0]
        == f"{row['ground_shard']}: {key}.{row['ground_member']}: " + err[0].split(": ", 2)[2]
    )
    assert "checksum mismatch" in err[0]
    assert err[1].startswith(f"{row['dem_shard']}: {key}.dem: checksum mismatch")
    assert err[-1].endswith("2 damaged")


def test_verify_names_a_manifest_size_off_by_one_and_a_bad_header(
    copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = pq.read_table(copy / "manifest.parquet")
    rows = table.to_pylist()
    target = min(rows, key=lambda r: r["key"])
    for r in rows:
        if r["key"] == target["key"]:
            r["meta_size"] += 1
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), copy / "manifest.parquet")
    second = _row(copy, 1)
    _poke(copy, second["ortho_shard"], second["ortho_offset"] - 512, b"garbage!" * 8)
    assert main(["verify", str(copy)]) == 2
    err = capsys.readouterr().err
    assert f"{target['key']}.meta: size {target['meta_size']} in the manifest" in err
    assert re.search(
        rf"{second['ortho_shard']}: {second['key']}\.ortho: (bad tar header|tar )", err
    )


def test_verify_names_a_missing_shard(copy: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = pq.read_table(copy / "manifest.parquet").to_pylist()
    shard = rows[1]["meta_shard"]
    (copy / shard).unlink()
    assert main(["verify", str(copy)]) == 2
    err = capsys.readouterr().err
    assert f"{shard}: " in err and "cannot open" in err
    members = sum(  # every member of every sample in that shard
        sum(v == shard for k, v in row.items() if k.endswith("_shard")) for row in rows
    )
    assert members >= 6 and err.strip().endswith(f"{members} damaged")


# -- damaged manifests ----------------------------------------------------------------------
COMMANDS = [
    ["inspect", "{ds}"],
    ["query", "{ds}", "--bbox", "0", "0", "180", "80"],
    ["show", "{ds}", "some_key", "--out", "{tmp}/s.png"],
    ["overview", "{ds}", "--out", "{tmp}/o.png"],
    ["export-qgis", "{ds}", "{tmp}/o.gpkg"],
    ["verify", "{ds}"],
]


@pytest.mark.parametrize("damage", ["garbage", "truncated", "no columns"])
@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
def test_a_damaged_manifest_is_one_line_naming_it(
    copy: Path,
    tmp_path: Path,
    damage: str,
    command: list[str],
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = copy / "manifest.parquet"
    data = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(data[:100] + os.urandom(len(data) - 200) + data[-100:])
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    else:
        pq.write_table(pa.table({"x": [1, 2]}), path)
    argv = [a.format(ds=copy, tmp=tmp_path) for a in command]
    assert main(argv) == 2
    one_line_error(capsys, "manifest.parquet")


def test_a_manifest_missing_one_column_is_named(
    copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = pq.read_table(copy / "manifest.parquet")
    pq.write_table(table.drop_columns(["mission"]), copy / "manifest.parquet")
    for command in COMMANDS[:-1]:  # verify needs no mission column
        assert main([a.format(ds=copy, tmp=tmp_path) for a in command]) == 2, command
        one_line_error(capsys, "manifest.parquet: mission: no such column")


# -- query arguments ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "where",
    [
        ["--bbox", "nan", "0", "180", "80"],
        ["--bbox", "0", "inf", "180", "80"],
        ["--near", "77.44", "nan", "100"],
        ["--bbox-map", "0", "0", "nan", "1"],
    ],
)
def test_query_refuses_non_finite_numbers(
    built: Path, where: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["query", str(built), *where])
    assert exc.value.code == 2
    assert "expected a finite number" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("where", "needle"),
    [
        (["--bbox", "0", "0", "180", "95"], "--bbox: N: latitude 95 is outside [-90, 90]"),
        (["--near", "77.4", "95", "100"], "--near: LAT: latitude 95"),
        (["--near", "18.4", "77.4", "-5"], "--near: RADIUS_M: expected a positive radius"),
        (["--bbox", "0", "30", "180", "10"], "--bbox: S (30) is north of N (10)"),
        (["--polygon", ""], "--polygon"),
        (["--polygon", "POLYGON EMPTY"], "--polygon: an empty geometry"),
        (["--polygon", "POINT (1 2)"], "--polygon: expected a Polygon"),
    ],
)
def test_query_refuses_impossible_places(
    built: Path, where: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["query", str(built), *where]) == 2
    one_line_error(capsys, needle)


# -- locate ---------------------------------------------------------------------------------
def _label_variant(small_mission: Path, tmp_path: Path, old: str, new: str) -> Path:
    """The first label with every match of the regular expression ``old`` replaced."""
    label = sorted((small_mission / "labels").glob("*.xml"))[0]
    text, n = re.subn(old, new, label.read_text())
    assert n >= 1
    out = tmp_path / label.name
    out.write_text(text)
    shutil.copy(label.with_suffix(".jpg"), out.with_suffix(".jpg"))
    return out


def test_locate_a_400_digit_line_count(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    huge = "9" * 400
    label = _label_variant(small_mission, tmp_path, ">600<", f">{huge}<")
    assert main(["locate", str(label), "--json"]) == 2
    one_line_error(capsys, str(label), "expected an integer <= ")


def test_locate_a_400_digit_pds3_line_count(
    samples_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    label = samples_dir / "msl" / "2663ML0139550021002124C00_DRCX.LBL"
    text, n = re.subn(r"(\n\s*LINES\s*=\s*)\d+", r"\g<1>" + "7" * 400, label.read_text())
    assert n >= 1
    bad = tmp_path / label.name
    bad.write_text(text)
    assert main(["locate", str(bad)]) == 2
    one_line_error(capsys, str(bad), "LINES: expected an integer <= ")


def test_locate_a_1e308_camera_component(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    label = _label_variant(  # H's x (its last digits vary with the numpy build)
        small_mission, tmp_path, r"(<geom:Vector_Horizontal>\s*<geom:x_pixel>)[^<]+", r"\g<1>1e308"
    )
    places = small_mission / "places" / "best_interp.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow RuntimeWarnings fail the test
        code = main(["locate", str(label), "--places", str(places), "--json"])
    assert code == 2
    out = capsys.readouterr()
    assert out.out == "" and "NaN" not in out.err
    assert str(label) in out.err and "H of the CAHVOR model exceeds" in out.err


def test_locate_with_a_text_places_cell(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = (small_mission / "places" / "best_interp.csv").read_text().splitlines()
    header = lines[0].split(",")
    bad = []
    for line in lines:
        cells = line.split(",")
        if cells[0] == "SITE":
            cells[header.index("site")] = "abc"
        bad.append(",".join(cells))
    places = tmp_path / "p.csv"
    places.write_text("\n".join(bad) + "\n")
    label = sorted((small_mission / "labels").glob("*.xml"))[0]
    assert main(["locate", str(label), "--places", str(places)]) == 2
    one_line_error(capsys, f"{places}: line 2: site: expected an integer, got 'abc'")


def test_locate_refuses_a_fifo_and_dev_zero(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fifo = tmp_path / "label.xml"
    os.mkfifo(fifo)
    assert main(["locate", str(fifo)]) == 2
    one_line_error(capsys, str(fifo), "not a regular file")
    assert main(["locate", "/dev/zero"]) == 2
    one_line_error(capsys, "/dev/zero", "not a regular file")


def test_an_oversized_label_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    big = tmp_path / "big.xml"
    with open(big, "wb") as fh:
        fh.truncate(65 * 1024 * 1024)  # sparse: no disk used
    start = time.perf_counter()
    assert main(["locate", str(big)]) == 2
    one_line_error(capsys, str(big))
    assert time.perf_counter() - start < 5.0  # its head is read, not its 65 MB


# -- viewshed, synth, config ----------------------------------------------------------------
@pytest.mark.parametrize(
    "extra",
    [
        ["--radius", "0"],
        ["--radius", "nan"],
        ["--radius", "inf"],
        ["--radius", "1e12"],
        ["--radius", "-3"],
        ["--az-min", "nan", "--az-max", "10"],
        ["--el-min", "-100", "--el-max", "10"],
        ["--x", "inf"],
    ],
)
def test_viewshed_refuses_bad_numbers(
    small_mission: Path, tmp_path: Path, extra: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["viewshed", "--dem", str(small_mission / "orbital" / "dem.tif")]
    argv += ["--out", str(tmp_path / "v.tif"), "--x", "1", "--y", "1", "--height", "2"]
    with pytest.raises(SystemExit) as exc:
        main([*argv, *extra])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "expected a" in err and "Traceback" not in err
    assert not (tmp_path / "v.tif").exists()


@pytest.mark.parametrize("option", ["--stops", "--images-per-stop"])
def test_synth_refuses_zero_stops(
    tmp_path: Path, option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["synth", str(tmp_path / "m"), option, "0"])
    assert exc.value.code == 2
    assert f"argument {option}: expected an integer >= 1" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize(
    "data",
    [
        bytes(range(256)) * 4,
        "inputs:\n  labels: caf\xe9/*.xml\n".encode("latin-1"),
        "inputs:\n  labels: a/*.xml\n".encode("utf-16"),
    ],
    ids=["binary", "latin-1", "utf-16"],
)
def test_a_config_that_is_not_utf8_text(
    tmp_path: Path, data: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "c.yaml"
    path.write_bytes(data)
    assert main(["build", "--config", str(path)]) == 2
    one_line_error(capsys, str(path), "not UTF-8 text")


def test_a_config_fifo_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.yaml"
    os.mkfifo(path)
    assert main(["build", "--config", str(path)]) == 2
    one_line_error(capsys, str(path), "not a regular file")


def test_json_output_is_valid_json(small_mission: Path, capsys: pytest.CaptureFixture[str]) -> None:
    label = sorted((small_mission / "labels").glob("*.xml"))[0]
    places = small_mission / "places" / "best_interp.csv"
    assert main(["locate", str(label), "--places", str(places), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["localization"] == "places"


def test_a_symlink_loop_as_out_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    config = Path(__file__).resolve().parents[2] / "configs" / "demo.yaml"
    argv = ["build", "--config", str(config), "--out", str(tmp_path / "a"), "--dry-run"]
    assert main(argv) == 2
    one_line_error(capsys, "--out: ")
