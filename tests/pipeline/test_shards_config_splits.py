"""Shards (offsets, atomicity), config validation, spatial splits and chip grids."""

from __future__ import annotations

import tarfile
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from mars_pairs.errors import ConfigError
from mars_pairs.geometry.frames import MSL_PLACES_CRS
from mars_pairs.pipeline.config import load_config, parse_config
from mars_pairs.raster.chips import ChipGrid, read_chip, resample_array
from mars_pairs.store.shards import MemberLocation, ShardWriter, read_member
from mars_pairs.store.splits import assign_splits, block_ids, hilbert_index


# -- shards ---------------------------------------------------------------------------------------
def test_every_offset_reads_back_what_tarfile_extracts(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    locations: dict[str, MemberLocation] = {}
    with ShardWriter(tmp_path, "shards/shard-000000.tar") as shard:
        for i in range(5):
            members = {f: rng.bytes(int(rng.integers(0, 3000))) for f in ("a.bin", "b.npy")}
            for f, loc in shard.add(f"key{i}", members).items():
                locations[f"key{i}.{f}"] = loc
    with tarfile.open(tmp_path / "shards/shard-000000.tar") as tar:
        names = tar.getnames()
        assert names == list(locations)
        for name in names:
            extracted = tar.extractfile(name)
            assert extracted is not None
            assert read_member(tmp_path, locations[name]) == extracted.read()


def test_a_failed_shard_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), ShardWriter(tmp_path, "s.tar") as shard:
        shard.add("k", {"x.bin": b"1234"})
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_keys_with_dots_are_refused(tmp_path: Path) -> None:
    with ShardWriter(tmp_path, "s.tar") as shard, pytest.raises(ValueError):
        shard.add("a.b", {"x": b""})


# -- config -----------------------------------------------------------------------------------
BASE = {
    "inputs": {"labels": "labels/*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"},
    "output": {"dir": "out"},
}


def test_defaults_and_relative_paths(tmp_path: Path) -> None:
    cfg = parse_config(BASE, tmp_path)
    assert cfg.inputs.dem == (tmp_path / "d.tif").resolve()
    assert cfg.geometry.viewshed == "both" and cfg.chips.orientation == "north-up"
    assert abs(sum(cfg.splits.ratios.values()) - 1) < 1e-9


@pytest.mark.parametrize(
    ("patch", "key"),
    [
        ({"geometry": {"radius": "far"}}, "geometry.radius"),
        ({"geometry": {"radius": -5}}, "geometry.radius"),
        ({"geometry": {"viewshed": "cone"}}, "geometry.viewshed"),
        ({"chips": {"size_px": 2.5}}, "chips.size_px"),
        ({"chips": {"orientation": "south-up"}}, "chips.orientation"),
        ({"splits": {"ratios": {"train": 0.5}}}, "splits.ratios"),
        ({"output": {"dir": "o", "shard_size": 0}}, "output.shard_size"),
        ({"output": {"dir": "o", "colour": 1}}, "output.colour"),
        ({"inputs": {"labels": []}}, "inputs.labels"),
        ({"inputs": {"labels": "x", "places": "p", "dem": "d"}}, "inputs.ortho"),
    ],
)
def test_errors_name_the_key(tmp_path: Path, patch: dict, key: str) -> None:
    data = {**BASE, **patch}
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        parse_config(data, tmp_path)


def test_bad_yaml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("inputs: [unclosed\n")
    with pytest.raises(ConfigError, match=r"c\.yaml"):
        load_config(path)


def test_shipped_configs_validate() -> None:
    root = Path(__file__).resolve().parents[2] / "configs"
    for path in sorted(root.glob("*.yaml")):
        cfg = load_config(path)
        assert cfg.output.dir.is_absolute()


# -- splits ---------------------------------------------------------------------------------------
def test_blocks_never_straddle_splits() -> None:
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 5000, 4000), rng.uniform(0, 5000, 4000)
    ratios = {"train": 0.7, "val": 0.2, "test": 0.1}
    splits = np.asarray(assign_splits(x, y, 250.0, ratios, seed=3))
    blocks = block_ids(x, y, 250.0)
    for b in np.unique(blocks, axis=0):
        inside = np.all(blocks == b, axis=1)
        assert len(set(splits[inside])) == 1
    frac = {s: float(np.mean(splits == s)) for s in ratios}
    assert frac["train"] > 0.5 and frac["test"] > 0.03
    assert list(splits) == assign_splits(x, y, 250.0, ratios, seed=3)  # deterministic
    assert list(splits) != assign_splits(x, y, 250.0, ratios, seed=4)


def test_hilbert_neighbours_are_adjacent_cells() -> None:
    xs, ys = np.meshgrid(np.arange(16), np.arange(16))
    d = hilbert_index(xs.ravel(), ys.ravel(), (0, 0, 15, 15), order=4)
    assert sorted(d) == list(range(256))
    cells = np.stack([xs.ravel(), ys.ravel()], axis=-1)[np.argsort(d)]
    assert np.all(np.abs(np.diff(cells, axis=0)).sum(axis=1) == 1)


def test_hilbert_order_1_and_shapes() -> None:
    """Order 1 visits (0, 0), (0, 1), (1, 1), (1, 0); the index keeps the input's shape."""
    d = hilbert_index([0, 0, 1, 1], [0, 1, 1, 0], (0, 0, 1, 1), order=1)
    assert d.tolist() == [0, 1, 2, 3] and d.dtype == np.int64
    assert hilbert_index(0.0, 1.0, (0, 0, 1, 1), order=1).shape == ()
    assert hilbert_index(np.zeros((2, 3)), np.zeros((2, 3)), (0, 0, 1, 1)).shape == (2, 3)


# -- chips ------------------------------------------------------------------------------------
@pytest.fixture()
def ramp(tmp_path: Path) -> tuple[Path, float, float]:
    """Band 1 is x - x0, band 2 is y0 - y: each pixel says where it is (Gale CRS, 1 m)."""
    x0, y0, n = 8141000.0, -272000.0, 300
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    path = tmp_path / "ramp.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=2,
        dtype="float32",
        crs=MSL_PLACES_CRS,
        transform=from_origin(x0, y0, 1, 1),
        nodata=-9999,
    ) as dst:
        dst.write(np.stack([cols, rows]).astype("float32"))
    return path, x0, y0


@pytest.mark.parametrize("rotation", [0.0, 30.0, 90.0, 200.0])
def test_chip_samples_the_right_place(ramp: tuple[Path, float, float], rotation: float) -> None:
    path, x0, y0 = ramp
    grid = ChipGrid.around(x0 + 150, y0 - 150, 80.0, 40, MSL_PLACES_CRS, rotation_deg=rotation)
    east, south = read_chip(str(path), grid, band=1), read_chip(str(path), grid, band=2)
    cols, rows = np.meshgrid(np.arange(5, 35) + 0.5, np.arange(5, 35) + 0.5)
    x, y = grid.transform @ (cols, rows)
    # every chip pixel samples its own map position, to a tenth of a source pixel
    np.testing.assert_allclose(east[5:35, 5:35], x - x0, atol=0.1)
    np.testing.assert_allclose(south[5:35, 5:35], y0 - y, atol=0.1)
    # the chip's up direction is the requested azimuth
    top = np.array(grid.transform @ (20, 0)) - [x0 + 150, y0 - 150]
    az = np.degrees(np.arctan2(top[0], top[1])) % 360
    assert az == pytest.approx(rotation % 360, abs=1e-6)
    np.testing.assert_allclose(grid.to_pixel(*(grid.transform @ (3.5, 7.25))), [3.5, 7.25])


def test_chip_off_the_raster_is_nan(ramp: tuple[Path, float, float]) -> None:
    path, x0, y0 = ramp
    chip = read_chip(str(path), ChipGrid.around(x0, y0, 100.0, 20, MSL_PLACES_CRS))
    assert np.isnan(chip[0, 0]) and np.isfinite(chip[-1, -1])


def test_chip_in_another_crs_is_warped(ramp: tuple[Path, float, float]) -> None:
    """A chip asked in a lat_ts = 10 CRS samples the same ground as in the raster's CRS."""
    from mars_pairs.geometry.frames import map_to_map

    path, x0, y0 = ramp
    other = MSL_PLACES_CRS.replace("+lat_ts=0", "+lat_ts=10")
    cx, cy = map_to_map(x0 + 150, y0 - 150, MSL_PLACES_CRS, other)
    grid = ChipGrid.around(float(cx), float(cy), 60.0, 30, other)
    east = read_chip(str(path), grid, band=1)
    x, _ = map_to_map(*(grid.transform @ (15.5, 15.5)), other, MSL_PLACES_CRS)
    assert east[15, 15] == pytest.approx(float(x) - x0, abs=0.2)


def test_resampled_mask_keeps_its_cells() -> None:
    from affine import Affine

    mask = np.zeros((100, 100), dtype=np.uint8)
    mask[40:60, 10:30] = 1
    transform = Affine(1.0, 0, 1000.0, 0, -1.0, 2000.0)
    grid = ChipGrid.around(1050.0, 1950.0, 100.0, 50, MSL_PLACES_CRS)
    chip = resample_array(mask, transform, MSL_PLACES_CRS, grid, nearest=True)
    assert chip.sum() == pytest.approx(20 * 20 / 4, abs=20)
    assert chip[25, 10] == 1 and chip[25, 40] == 0
