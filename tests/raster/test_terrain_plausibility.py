"""Nonsense rasters are refused when they are opened, naming the file (``raster.terrain``):
a DEM of complex numbers, a DEM whose elevations are no Mars surface (3e38 m everywhere), an
orthoimage in a geographic CRS (EPSG:4326); and a build refuses them before any work, in one
ConfigError naming the key (no failure row per sample, no GDAL error lines)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from mars_pairs.errors import ConfigError, TerrainError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import parse_config
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
    }


@pytest.mark.parametrize("case", ["complex64 DEM", "3e38 m DEM", "EPSG:4326 ortho"])
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
