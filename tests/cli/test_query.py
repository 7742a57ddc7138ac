"""``mars-pairs query``: the manifest filter's refusals as one line and exit 2, values named,
warnings on stderr, longitude first, --polygon in degrees, --polygon-map, --by."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import shapely

from mars_pairs.cli.main import main
from mars_pairs.geometry.frames import M2020_PLACES_CRS, lonlat_to_map
from tests.support.manifests import LAT0, LON0, write_place_manifest


@pytest.fixture(scope="module")
def placed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    root = tmp_path_factory.mktemp("placed")
    return root, write_place_manifest(root)


def _query(root: Path, capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["query", str(root), "--format", "csv", *args])
    out, err = capsys.readouterr()
    return code, out, err


def _rows(out: str) -> int:
    return len(out.strip().splitlines()) - 1


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--bbox", "0", "10", "1", "-10"], "--bbox: S (10) is north of N (-10)"),
        (["--near", "0", "0", "-5"], "--near: RADIUS_M: expected a positive radius, got -5"),
        (["--sol", "9", "1"], "--sol: FIRST (9) is after LAST (1)"),
        (["--instrument", "MAST_LEFT"], "--instrument: "),
        (["--split", "training"], "its splits are test, train, val"),
        (["--mission", "msl"], "its missions are m2020"),
        (
            [
                "--polygon",
                "POLYGON ((4353000 1092000, 4354000 1092000, 4353000 1093000, 4353000 1092000))",
            ],
            "--polygon: coordinates",
        ),
        (
            ["--polygon-map", "POLYGON ((0 0, 1 1, 1 0, 0 1, 0 0))"],
            "--polygon-map: not a valid polygon",
        ),
    ],
)
def test_refusals_are_one_line_naming_the_option(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str], args: list[str], needle: str
) -> None:
    code, out, err = _query(placed[0], capsys, *args)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("mars-pairs query: ") and needle in err, err


def test_mast_left_on_a_perseverance_dataset_lists_its_instruments(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = _query(placed[0], capsys, "--instrument", "MAST_LEFT")
    assert code == 2
    assert (
        "has no instrument 'MAST_LEFT'; its instruments are MCZ_LEFT, MCZ_RIGHT, NAVCAM_LEFT" in err
    )


def test_near_is_longitude_first_and_the_old_order_warns(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    root, _ = placed
    code, new, err = _query(root, capsys, "--near", str(LON0), str(LAT0), "800")
    assert code == 0 and err == "" and _rows(new) > 0
    code, old, err = _query(root, capsys, "--near", str(LAT0), str(LON0), "800")
    assert code == 0 and old == new
    assert "warning: --near: (18.44, 77.45) is read as LAT LON (the old order)" in err


def test_a_missed_place_warns_with_the_extent_in_both_units(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = _query(placed[0], capsys, "--bbox", "0", "0", "1", "1")
    assert code == 0 and _rows(out) <= 0
    assert "warning: --bbox: (0, 0, 1, 1) misses the dataset (by=rover, 0 rows)" in err
    assert "lon 77.4" in err and "map x 435" in err


def test_a_sol_range_outside_warns_with_the_sols(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = _query(placed[0], capsys, "--sol", "300", "400")
    assert code == 0 and _rows(out) <= 0
    assert "warning: --sol: 300..400 holds none of" in err and "(they are 52..140)" in err


def test_polygon_in_degrees_and_polygon_map_agree(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    root, table = placed
    ring = [(LON0 - 0.01, LAT0 - 0.01), (LON0 + 0.01, LAT0 - 0.01), (LON0, LAT0 + 0.01)]
    lonlat = shapely.Polygon(ring)
    x, y = lonlat_to_map([p[0] for p in ring], [p[1] for p in ring], M2020_PLACES_CRS)
    mapped = shapely.Polygon(np.column_stack([x, y]))  # equirectangular: straight edges stay
    code, by_degrees, _ = _query(root, capsys, "--polygon", lonlat.wkt)
    assert code == 0
    code, by_map, _ = _query(root, capsys, "--polygon-map", mapped.wkt)
    assert code == 0 and by_degrees == by_map
    keep = shapely.intersects_xy(
        lonlat, table["longitude"].to_numpy(), table["latitude"].to_numpy()
    )
    assert _rows(by_degrees) == int(keep.sum()) > 0


def test_by_chooses_what_the_place_tests(
    placed: tuple[Path, pa.Table], capsys: pytest.CaptureFixture[str]
) -> None:
    root, _ = placed
    counts = {}
    for by in ("rover", "footprint", "chip"):
        code, out, _ = _query(root, capsys, "--near", str(LON0), str(LAT0), "150", "--by", by)
        assert code == 0
        counts[by] = _rows(out)
    assert counts["rover"] < counts["footprint"] and counts["rover"] < counts["chip"]
    help_text = _help(capsys)
    assert "--by {rover,footprint,chip}" in help_text and "rover position (default)" in help_text
    assert "--near LON LAT RADIUS_M" in help_text and "lon/lat degrees" in help_text


def _help(capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit):
        main(["query", "--help"])
    return " ".join(capsys.readouterr().out.split())
