"""`mars-pairs locate`: JSON output, several labels, and clean failures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mars_pairs.cli.main import main

ZLF = "m2020/ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"


def test_locate_reports_the_places_row(
    samples_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    places = samples_dir / "m2020" / "best_interp.csv"
    assert main(["locate", str(samples_dir / ZLF), "--places", str(places), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["site"], out["drive"]) == (3, 1950)
    assert (out["easting"], out["northing"]) == (4354557.816, 1093309.691)
    assert out["localization"] == "places"
    for key in (
        "product_id",
        "mission",
        "instrument",
        "sol",
        "azimuth_deg",
        "elevation_deg",
        "hfov_deg",
        "vfov_deg",
        "width",
        "height",
        "camera_model_type",
        "latitude",
        "longitude",
        "elevation_m",
    ):
        assert out[key] is not None, key
    assert out["mission"] == "m2020" and out["sol"] == 52


def test_several_labels_give_one_object_per_line(
    samples_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    labels = sorted(str(p) for p in samples_dir.glob("msl/*.LBL"))
    assert main(["locate", *labels, "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(labels)
    assert {json.loads(line)["mission"] for line in lines} == {"msl"}


def test_bad_label_exits_2_with_one_line_naming_file_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "broken.LBL"
    bad.write_text('PDS_VERSION_ID = PDS3\nPRODUCT_ID = "X"\nEND\n')
    proc = subprocess.run(
        [sys.executable, "-m", "mars_pairs.cli", "locate", str(bad), "--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "broken.LBL" in lines[0] and "Traceback" not in proc.stderr
    assert proc.stdout == ""


def test_good_labels_still_print_when_one_is_bad(
    samples_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty.xml"
    empty.write_bytes(b"")
    assert main(["locate", str(samples_dir / ZLF), str(empty), "--json"]) == 2
    captured = capsys.readouterr()
    assert len(captured.out.strip().splitlines()) == 1
    assert "empty.xml" in captured.err
