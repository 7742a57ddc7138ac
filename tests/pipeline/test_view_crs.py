"""The view covers the same ground on any projected Mars CRS, and bad CRSs are refused.

The same synthetic DEM is warped (GDAL, bilinear) to other projections; each image's view mask,
mapped back to the original grid by pyproj, must cover the same cells (IoU >= 0.8; GDAL's
half-pixel resampling alone costs ~0.15). Before true north and true metres were used, the
same check gave 0.75 in eqc lat_ts = 0, and 0.00 in sinusoidal and polar stereographic.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.warp import Resampling, calculate_default_transform, reproject

from mars_pairs.errors import TerrainError
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.sample.build_sample import view_stages
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.view import View
from mars_pairs.raster.terrain import Terrain
from support.configs import build_config
from support.missions import MissionCache

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s

SPHERE = "+R=3396190 +units=m +no_defs +type=crs"
TARGETS = {
    "eqc lat_ts=0": f"+proj=eqc +lat_ts=0 +lon_0=0 {SPHERE}",
    "sinusoidal": f"+proj=sinu +lon_0=0 {SPHERE}",
    "polar stereographic": f"+proj=stere +lat_0=90 +lat_ts=90 +lon_0=0 {SPHERE}",
}


@pytest.fixture(scope="module")
def mission(missions: MissionCache) -> Path:
    return missions(seed=5, stops=2, images_per_stop=3)


def _warp(src_path: Path, dst_path: Path, crs: str) -> None:
    """The DEM reprojected to ``crs`` at about its own resolution (bilinear, NaN nodata)."""
    with rasterio.open(src_path) as src:
        transform, width, height = calculate_default_transform(
            src.crs, crs, src.width, src.height, *src.bounds
        )
        profile = src.profile | {
            "crs": crs, "transform": transform, "width": width, "height": height,
            "dtype": "float32", "nodata": np.nan,
        }  # fmt: skip
        out = np.full((height, width), np.nan, dtype=np.float32)
        reproject(
            rasterio.band(src, 1), out, dst_transform=transform, dst_crs=crs,
            dst_nodata=np.nan, resampling=Resampling.bilinear,
        )  # fmt: skip
    with rasterio.open(dst_path, "w", **profile) as dst:
        dst.write(out, 1)


def _views(mission: Path, dem: Path, tmp: Path) -> dict[str, View]:
    config = build_config(
        mission, tmp / "unused", base=tmp, inputs={"dem": str(dem)},
        geometry={"radius": 400, "ray_stride": 32, "viewshed": "wedge"}, chips=None, splits=None,
    )  # fmt: skip
    ctx = SampleContext.open(config)
    views = {}
    try:
        for label in sorted((mission / "labels").glob("*.xml")):
            obs = read_observation(label)
            pose = ctx.places.locate(obs)
            camera = MapCamera.from_observation(obs, pose, ctx.terrain.crs)
            views[label.name] = view_stages(pose, camera, ctx, Stages())
    finally:
        ctx.close()
    return views


def _on_grid(view: View, reference: View) -> np.ndarray:
    """``view``'s mask (any CRS) resampled to ``reference``'s window grid (nearest cell).

    Each reference cell centre goes through pyproj into ``view``'s CRS and reads the cell it
    falls in, so coarser or sheared warped grids are compared fairly.
    """
    rows, cols = np.indices(reference.mask.shape)
    x, y = reference.window.colrow_to_xy(cols.ravel(), rows.ravel())
    to_view = Transformer.from_crs(reference.window.crs, view.window.crs, always_xy=True)
    vx, vy = to_view.transform(x, y)
    c, r = view.window.xy_to_colrow(vx, vy)
    c, r = np.rint(c).astype(int), np.rint(r).astype(int)
    ok = (c >= 0) & (r >= 0) & (c < view.mask.shape[1]) & (r < view.mask.shape[0])
    out = np.zeros(c.shape, dtype=bool)
    out[ok] = view.mask[r[ok], c[ok]] > 0
    return out.reshape(reference.mask.shape)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.mark.parametrize("name", list(TARGETS))
def test_the_same_image_covers_the_same_ground_in_any_projection(
    mission: Path, tmp_path: Path, name: str
) -> None:
    dem = mission / "orbital" / "dem.tif"
    warped = tmp_path / "dem_warped.tif"
    _warp(dem, warped, TARGETS[name])
    reference = _views(mission, dem, tmp_path)
    other = _views(mission, warped, tmp_path)
    ious = {
        key: _iou(_on_grid(other[key], ref), ref.mask.astype(bool))
        for key, ref in reference.items()
        if ref.mask.sum() >= 300  # a few-cell view (a zoom looking down) is all edge
    }
    assert ious, "no image sees enough ground to compare"
    assert min(ious.values()) >= 0.8, (name, ious)


def test_geographic_and_ellipsoid_rasters_are_refused(mission: Path, tmp_path: Path) -> None:
    dem = mission / "orbital" / "dem.tif"
    lonlat = tmp_path / "dem_lonlat.tif"
    _warp(dem, lonlat, "+proj=longlat +R=3396190 +no_defs +type=crs")
    with pytest.raises(TerrainError, match="geographic"):
        Terrain.open(lonlat)
    ellipsoid = tmp_path / "dem_ellipsoid.tif"
    _warp(dem, ellipsoid, "+proj=eqc +lat_ts=0 +a=3396190 +b=3376200 +units=m +no_defs +type=crs")
    with pytest.raises(TerrainError, match="ellipsoid"):
        Terrain.open(ellipsoid)
