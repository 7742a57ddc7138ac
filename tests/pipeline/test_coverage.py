"""Builds over rasters stored south-up, an ortho off the DEM's area and a partly empty ortho:
the same dataset as north-up, failure rows naming the ortho, and coverage columns that count
the chip pixels with data."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from affine import Affine

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from support.configs import build_config
from support.members import manifest_rows as rows_of
from support.members import tar_members as members_of

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

SIZE_M, SIZE_PX = 64.0, 64  # the config builder's cheap chips


def rewrite(src: Path, dst: Path, transform: Affine, change=lambda a: a) -> Path:
    """``src``'s pixels, changed by ``change``, written to ``dst`` with ``transform``."""
    with rasterio.open(src) as ds:
        profile = ds.profile | {"transform": transform}
        data = np.ascontiguousarray(change(ds.read()))
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
    return dst


def south_up(src: Path, dst: Path) -> Path:
    """``src`` flipped north-south and stored with a positive y pixel size (row 0 south)."""
    with rasterio.open(src) as ds:
        t, rows = ds.transform, ds.height
    assert t.e < 0
    tr = Affine(t.a, 0.0, t.c, 0.0, -t.e, t.f + t.e * rows)
    return rewrite(src, dst, tr, lambda a: a[:, ::-1, :])


def failures_of(out: Path) -> list[dict]:
    return pq.read_table(out / "failures.parquet").to_pylist()


@pytest.fixture(scope="module")
def north_build(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("north") / "ds"
    summary = run_build(build_config(small_mission, out), progress=False)
    assert summary.samples == 4 and summary.failures == 0, summary.failures_by_reason
    return out


def test_a_south_up_dem_and_ortho_build_the_same_dataset(small_mission, north_build, tmp_path):
    orbital = small_mission / "orbital"
    dem = south_up(orbital / "dem.tif", tmp_path / "dem_south.tif")
    ortho = south_up(orbital / "ortho.tif", tmp_path / "ortho_south.tif")
    out = tmp_path / "ds"
    config = build_config(small_mission, out, inputs={"dem": str(dem), "ortho": str(ortho)})
    summary = run_build(config, progress=False)
    assert summary.failures == 0, summary.failures_by_reason
    assert rows_of(out) == rows_of(north_build)
    want, got = members_of(north_build), members_of(out)
    assert sorted(got) == sorted(want) and len(want) == 4 * 6
    for name in want:
        assert got[name] == want[name], name


def test_a_rotated_ortho_stops_the_build_before_any_sample(small_mission, tmp_path):
    src = small_mission / "orbital" / "ortho.tif"
    with rasterio.open(src) as ds:
        t = ds.transform
    turned = t * Affine.rotation(2.0)
    ortho = rewrite(src, tmp_path / "turned.tif", turned)
    config = build_config(small_mission, tmp_path / "ds", inputs={"ortho": str(ortho)})
    with pytest.raises(
        ConfigError, match=r"inputs\.ortho: .*turned\.tif: .*grid is rotated.*gdalwarp"
    ):
        run_build(config, progress=False)
    assert not (tmp_path / "ds" / "shards").exists() or not any((tmp_path / "ds").rglob("*.tar"))


def test_an_ortho_off_the_dem_gives_failure_rows_naming_it(small_mission, tmp_path):
    src = small_mission / "orbital" / "ortho.tif"
    with rasterio.open(src) as ds:
        t, width, height = ds.transform, ds.width, ds.height
    shift = 5000.0  # metres east: nowhere near the DEM (1 km square)
    ortho = rewrite(src, tmp_path / "elsewhere.tif", Affine.translation(shift, 0.0) * t)
    out = tmp_path / "ds"
    config = build_config(small_mission, out, inputs={"ortho": str(ortho)})
    summary = run_build(config, progress=False)
    assert summary.samples == 0 and summary.failures == 4
    left, top = t.c + shift, t.f
    right, bottom = left + t.a * width, top + t.e * height
    for row in failures_of(out):
        assert (row["stage"], row["error_type"]) == ("chips", "CoverageError")
        message = row["message"]
        assert message.startswith(f"{ortho}: the ortho chip has data on 0.0% of its pixels")
        assert f"the ortho covers x {left:.3f}..{right:.3f}, y {bottom:.3f}..{top:.3f}" in message
        assert "chip x " in message


def test_coverage_columns_count_the_chip_pixels_with_data(small_mission, north_build, tmp_path):
    rows = rows_of(north_build)
    assert [(r["ortho_coverage"], r["dem_coverage"]) for r in rows] == [(1.0, 1.0)] * 4
    # an ortho whose pixels west of a line through the first sample's chip are nodata (0)
    src = small_mission / "orbital" / "ortho.tif"
    with rasterio.open(src) as ds:
        t = ds.transform
        assert ds.nodata == 0
    first = rows[0]
    cut = first["easting"] + 9.7  # map x of the line: about a third of the chip east of it
    j = math.ceil((cut - t.c) / t.a)  # the first ortho column kept

    def blank_west(a: np.ndarray) -> np.ndarray:
        a = a.copy()
        a[:, :, :j] = 0
        return a

    ortho = rewrite(src, tmp_path / "half.tif", t, blank_west)
    out = tmp_path / "ds"
    config = build_config(
        small_mission, out, inputs={"ortho": str(ortho)}, chips={"min_coverage": 0.0}
    )
    run_build(config, progress=False)
    built = {r["key"]: r for r in rows_of(out)}
    failed = failures_of(out)
    assert first["key"] in built
    x_first = t.c + t.a * (j + 0.5)  # centre of the first column with data
    for row in rows:
        # independently: chip pixel centres (north-up chips) east of that centre have data
        # (bilinear needs both neighbours); the chip lies on the ortho's data otherwise
        xs = row["chip_xmin"] + (np.arange(SIZE_PX) + 0.5) * (SIZE_M / SIZE_PX)
        expected = float(np.mean(xs >= x_first))
        if expected == 0.0:
            assert any(f["error_type"] == "CoverageError" for f in failed)
            continue
        got = built[row["key"]]
        assert got["ortho_coverage"] == pytest.approx(expected, abs=1e-12)
        assert got["dem_coverage"] == 1.0
    assert 0.3 < built[first["key"]]["ortho_coverage"] < 0.4
    # the default minimum (0.5) refuses it
    out = tmp_path / "ds_default"
    run_build(build_config(small_mission, out, inputs={"ortho": str(ortho)}), progress=False)
    assert first["key"] not in {r["key"] for r in rows_of(out)}
    reasons = {f["path"]: f for f in failures_of(out)}
    row = reasons[str(small_mission / "labels" / first["label_path"])]  # the labels root
    assert (row["stage"], row["error_type"]) == ("chips", "CoverageError")
    assert row["message"].startswith(f"{ortho}: the ortho chip has data on ")
    assert "(below chips.min_coverage 0.5)" in row["message"]


def test_min_coverage_is_a_fraction(small_mission, tmp_path):
    assert build_config(small_mission, tmp_path).chips.min_coverage == 0.5
    for bad in (-0.1, 1.5, "half", True):
        with pytest.raises(ConfigError, match=r"chips\.min_coverage"):
            build_config(small_mission, tmp_path, chips={"min_coverage": bad})
    for good in (0, 0.25, 1):
        doc = {
            "inputs": {"labels": "x", "places": "p", "dem": "d", "ortho": "o"},
            "chips": {"min_coverage": good},
            "output": {"dir": "o"},
        }
        assert parse_config(doc, tmp_path).chips.min_coverage == float(good)
