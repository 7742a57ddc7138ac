"""Terrain labels through a build, on the synthetic mission's AI4Mars-layout truth: the carried
classes agree with the true class raster (read by the test itself, on its own grid), nothing
is carried past the 30 m the range masks draw, the count columns add up, a missing mask is a
failure row naming it, and the merged map agrees with the truth."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from PIL import Image

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.torch import MarsPairsDataset
from support.configs import build_config

CHIP = {"size_m": 64, "size_px": 256}  # 0.25 m: the small mission's ortho resolution
PARAMS = {"seed": 3, "stops": 3, "images_per_stop": 4, "terrain_labels": True}
CLASS_COLUMNS = ("terrain_soil_px", "terrain_bedrock_px", "terrain_sand_px",
                 "terrain_big_rock_px")  # fmt: skip


def _build(mission: Path, out: Path, **inputs: Any) -> Path:
    terrain = {"format": "ai4mars", "root": str(mission / "ai4mars"), **inputs}
    config = build_config(
        mission, out, geometry={"radius": 100, "ray_stride": 16}, chips=CHIP,
        inputs={"terrain_labels": terrain}, splits={"block_m": 30},
    )  # fmt: skip
    run_build(config)
    return out


@pytest.fixture(scope="module")
def mission(missions: Any) -> Path:
    return missions(**PARAMS)


@pytest.fixture(scope="module")
def built(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _build(mission, tmp_path_factory.mktemp("terrain"))


def _truth_at(mission: Path, transform: np.ndarray, rows: np.ndarray,
              cols: np.ndarray) -> np.ndarray:  # fmt: skip
    """The true class (orbital/terrain_classes.tif) under chip pixel centres."""
    with rasterio.open(mission / "orbital" / "terrain_classes.tif") as src:
        truth, inv = src.read(1), ~src.transform
    t = transform
    x = t[0] * (cols + 0.5) + t[1] * (rows + 0.5) + t[2]
    y = t[3] * (cols + 0.5) + t[4] * (rows + 0.5) + t[5]
    c, r = inv * (x, y)
    return truth[np.floor(r).astype(int), np.floor(c).astype(int)]


def test_carried_classes_agree_with_the_truth(mission: Path, built: Path) -> None:
    covered = agree = 0
    with MarsPairsDataset(built, fields=("terrain_on_map", "terrain")) as ds:
        assert len(ds) == 12
        for i in range(len(ds)):
            sample = ds[i]
            assert sample["terrain_on_map"].dtype.is_floating_point is False
            on_map = sample["terrain_on_map"][0].numpy()
            rows, cols = np.nonzero(on_map != 255)
            truth = _truth_at(mission, sample["transform"].double().numpy(), rows, cols)
            covered += len(rows)
            agree += int((truth == on_map[rows, cols]).sum())
    assert covered > 1000
    assert agree / covered >= 0.98, f"{agree}/{covered}"


def test_nothing_carried_past_the_range_masks(mission: Path, built: Path) -> None:
    """The rover stands at its truth.parquet position: no carried chip pixel lies farther
    than 30 m (plus the camera's 2 m reach from the rover origin) horizontally from it, while
    the masks themselves label terrain well beyond 30 m (their range masks exclude it)."""
    truth = pq.read_table(mission / "truth.parquet").to_pandas().set_index("product_id")
    beyond_labelled = 0
    for path in (mission / "ai4mars" / "m2020" / "labels" / "NAV").glob("*.png"):
        classes = np.asarray(Image.open(path))
        stem = path.name.removesuffix("_merged3.png")
        rng = next((mission / "ai4mars/m2020/images/rng-30m").glob(
            stem.replace("RAD_", "RNG_") + "*.png"))  # fmt: skip
        beyond_labelled += int(((np.asarray(Image.open(rng)) == 1) & (classes != 255)).sum())
    assert beyond_labelled > 10000
    farthest = 0.0
    with MarsPairsDataset(built, fields=("terrain_on_map",)) as ds:
        for i in range(len(ds)):
            sample = ds[i]
            pid = sample["meta"]["product_id"]
            on_map = sample["terrain_on_map"][0].numpy()
            rows, cols = np.nonzero(on_map != 255)
            t = sample["transform"].double().numpy()
            x = t[0] * (cols + 0.5) + t[1] * (rows + 0.5) + t[2]
            y = t[3] * (cols + 0.5) + t[4] * (rows + 0.5) + t[5]
            d = np.hypot(x - truth.loc[pid, "easting"], y - truth.loc[pid, "northing"])
            farthest = max(farthest, float(d.max(initial=0.0)))
    assert 10.0 < farthest <= 32.0


def test_count_columns_add_up(built: Path) -> None:
    table = pq.read_table(built / "manifest.parquet")
    for column in CLASS_COLUMNS:
        assert column in table.column_names
    assert "terrain_on_map_offset" in table.column_names
    with MarsPairsDataset(built, fields=("terrain_on_map",)) as ds:
        for i in range(len(ds)):
            sample = ds[i]
            row = table.filter(table["key"].to_numpy(zero_copy_only=False) == sample["meta"]["key"])
            on_map = sample["terrain_on_map"][0].numpy()
            for value, column in enumerate(CLASS_COLUMNS):
                assert row[column][0].as_py() == int((on_map == value).sum())


def test_a_product_without_a_mask_is_a_failure_row(mission: Path, tmp_path: Path) -> None:
    copy = tmp_path / "m"
    shutil.copytree(mission, copy)
    gone = sorted((copy / "ai4mars/m2020/labels/NAV").glob("*.png"))[0]
    gone.unlink()
    out = _build(copy, tmp_path / "out")
    fails = pq.read_table(out / "failures.parquet").to_pylist()
    assert len(fails) == 1 and fails[0]["stage"] == "terrain_labels"
    assert gone.name.removesuffix("_merged3.png") in fails[0]["message"]


def test_terrain_map_majority_agrees_with_the_truth(mission: Path, built: Path,
                                                   tmp_path: Path) -> None:  # fmt: skip
    out = tmp_path / "map.tif"
    assert main(["terrain-map", str(built), "--out", str(out)]) == 0
    with rasterio.open(out) as src, rasterio.open(mission / "orbital/terrain_classes.tif") as t:
        assert src.count == 3 and src.nodata == 255
        bands = src.read()
        window = rasterio.windows.from_bounds(*src.bounds, transform=t.transform)
        truth = t.read(1, window=window.round_offsets().round_lengths())
    seen = bands[1] != 255
    assert seen.sum() > 1000
    assert (bands[0][seen] == truth[seen]).mean() >= 0.97
    assert (bands[2][seen] <= 100).all() and (bands[0][~seen] == 255).all()
    assert main(["terrain-map", str(built), "--out", str(out), "--each-split"]) == 0
    assert sorted(p.name for p in tmp_path.glob("map.*.tif"))


def test_plain_build_has_no_terrain_columns(small_mission: Path, tmp_path: Path) -> None:
    run_build(build_config(small_mission, tmp_path / "plain", chips=CHIP))
    names = pq.read_schema(tmp_path / "plain" / "manifest.parquet").names
    assert not [n for n in names if n.startswith("terrain")]
