"""Nonsense rasters are refused when they are opened, naming the file (``raster.terrain``):
a DEM of complex numbers, a DEM whose elevations are no Mars surface (3e38 m everywhere), an
orthoimage in a geographic CRS (EPSG:4326), a truncated DEM; and a build refuses them before
any work, in one ConfigError naming the key (no failure row per sample, no GDAL error lines).
A DEM damaged where the open's check does not read fails at the sample's read, naming the file
in the error and in each failure row."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from rasterio.enums import Resampling

import mars_pairs.raster.terrain as terrain_module
from mars_pairs.errors import ConfigError, TerrainError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.raster.chips import ChipGrid, ChipReader
from mars_pairs.raster.terrain import Terrain
from support.builds import small_doc


def _copy(src_path: Path, dst: Path, *, dtype: str | None = None, fill: float | None = None,
          crs: str | None = None) -> Path:  # fmt: skip
    with rasterio.open(src_path) as src:
        profile = src.profile
        data = src.read()
        transform = src.transform
    if dtype is not None:
        profile["dtype"] = dtype
        data = data.astype(dtype)
    if fill is not None:
        data = np.full_like(data, fill)
    if crs is not None:
        from rasterio.transform import from_origin

        profile["crs"] = crs
        transform = from_origin(137.4, -4.6, 1e-5, 1e-5)
    profile.update(transform=transform, nodata=None)
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
    return dst


def _truncated(src_path: Path, dst: Path, keep: float = 0.6) -> Path:
    """A tiled, deflate-compressed copy of ``src_path`` cut to its first ``keep`` share of
    bytes (a download or copy that stopped)."""
    with rasterio.open(src_path) as src:
        profile, data = src.profile, src.read()
    profile.update(tiled=True, blockxsize=256, blockysize=256, compress="deflate")
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
    raw = dst.read_bytes()
    dst.write_bytes(raw[: int(len(raw) * keep)])
    return dst


def cases(mission: Path, tmp: Path) -> dict[str, tuple[str, Path, str]]:
    dem, ortho = mission / "orbital" / "dem.tif", mission / "orbital" / "ortho.tif"
    return {
        "complex64 DEM": ("dem", _copy(dem, tmp / "c.tif", dtype="complex64"), "complex64"),
        "3e38 m DEM": ("dem", _copy(dem, tmp / "h.tif", fill=3e38), "outside the Mars range"),
        "EPSG:4326 ortho": (
            "ortho",
            _copy(ortho, tmp / "o.tif", crs="EPSG:4326"),
            "CRS is geographic",
        ),
        "truncated DEM": ("dem", _truncated(dem, tmp / "t.tif"), "truncated or damaged"),
    }


@pytest.mark.parametrize(
    "case", ["complex64 DEM", "3e38 m DEM", "EPSG:4326 ortho", "truncated DEM"]
)
def test_a_nonsense_raster_is_refused_at_open_and_by_the_build(
    small_mission: Path, tmp_path: Path, case: str
) -> None:
    key, path, reason = cases(small_mission, tmp_path)[case]
    orbital = small_mission / "orbital"
    inputs = {"dem": orbital / "dem.tif", "ortho": orbital / "ortho.tif", key: path}
    with pytest.raises(TerrainError, match=reason) as err:
        Terrain.open(inputs["dem"], inputs["ortho"])
    assert str(path) in str(err.value)
    doc = small_doc(small_mission, tmp_path / "ds")
    doc["inputs"][key] = str(path)
    config = parse_config(doc, base=small_mission)
    with pytest.raises(ConfigError, match=f"inputs.{key}: {path}.*{reason}"):
        run_build(config, progress=False)
    assert not (tmp_path / "ds" / "manifest.parquet").exists()


def test_the_real_and_synthetic_dems_pass(small_mission: Path) -> None:
    orbital = small_mission / "orbital"
    Terrain.open(orbital / "dem.tif", orbital / "ortho.tif").close()


def _damaged_under_overview(src_path: Path, dst: Path) -> Path:
    """A tiled, deflate-compressed copy of ``src_path`` with a 4x overview (which the open's
    decimated check reads) and the full-resolution tiles' bytes zeroed (10 % to 50 % of the
    file): the damage shows only when a sample reads a window."""
    with rasterio.open(src_path) as src:
        profile, data = src.profile, src.read()
    profile.update(tiled=True, blockxsize=256, blockysize=256, compress="deflate")
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
        out.build_overviews([4], Resampling.average)
    raw = bytearray(dst.read_bytes())
    low, high = len(raw) // 10, len(raw) // 2
    raw[low:high] = bytes(high - low)
    dst.write_bytes(bytes(raw))
    return dst


def test_a_dem_damaged_past_the_open_check_names_the_file_at_read(
    small_mission: Path, tmp_path: Path
) -> None:
    """A read that fails after the open (tiles the open-time check did not need) is a
    TerrainError naming the DEM and GDAL's reason, not rasterio's "Read failed" alone."""
    path = _damaged_under_overview(small_mission / "orbital" / "dem.tif", tmp_path / "d.tif")
    with Terrain.open(path) as terrain:
        left, bottom, right, top = terrain.bounds
        with pytest.raises(TerrainError, match="truncated or damaged") as err:
            terrain.read_dem_window((left + right) / 2, (bottom + top) / 2, 300)
    assert str(path) in str(err.value)
    assert "Read failed" not in str(err.value)


@pytest.mark.slow  # a build
def test_a_build_over_a_dem_damaged_past_the_open_check_names_it_in_failure_rows(
    small_mission: Path, tmp_path: Path
) -> None:
    path = _damaged_under_overview(small_mission / "orbital" / "dem.tif", tmp_path / "d.tif")
    doc = small_doc(small_mission, tmp_path / "ds")
    doc["inputs"]["dem"] = str(path)
    summary = run_build(parse_config(doc, base=small_mission), progress=False)
    rows = pq.read_table(tmp_path / "ds" / "failures.parquet").to_pylist()
    assert summary.failures == len(rows) > 0
    for row in rows:
        assert str(path) in row["message"] and "Read failed" not in row["message"], row


def test_a_chip_read_from_a_damaged_raster_gives_gdals_reason(
    small_mission: Path, tmp_path: Path
) -> None:
    path = _damaged_under_overview(small_mission / "orbital" / "dem.tif", tmp_path / "d.tif")
    with ChipReader(path) as reader:
        left, bottom, right, top = reader.bounds
        grid = ChipGrid.around((left + right) / 2, (bottom + top) / 2, 64, 64, reader.crs_wkt)
        with pytest.raises(TerrainError, match="IReadBlock failed") as err:
            reader.read(grid)
    assert str(path) in str(err.value) and "Read failed" not in str(err.value)


def test_a_dem_of_huge_compressed_blocks_is_refused_at_open_and_by_the_build(
    small_mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A deflate DEM whose block decodes past the limit (a bomb: 1 MiB on disk, 1 GiB per
    block at 16384 x 16384 float32) is refused before any read. The limit is lowered to
    1 MiB here so that a 1024 x 1024 block (4 MiB decoded) stands in for the bomb."""
    monkeypatch.setattr(terrain_module, "MAX_BLOCK_BYTES", 1 << 20)
    with rasterio.open(small_mission / "orbital" / "dem.tif") as src:
        profile, data = src.profile, src.read()
    profile.update(tiled=True, blockxsize=1024, blockysize=1024, compress="deflate")
    path = tmp_path / "bomb.tif"
    with rasterio.open(path, "w", **profile) as out:
        out.write(data)
    with pytest.raises(TerrainError, match="decompression bomb") as err:
        Terrain.open(path)
    assert str(path) in str(err.value)
    doc = small_doc(small_mission, tmp_path / "ds")
    doc["inputs"]["dem"] = str(path)
    with pytest.raises(ConfigError, match=f"inputs.dem: {path}.*decompression bomb"):
        run_build(parse_config(doc, base=small_mission), progress=False)
