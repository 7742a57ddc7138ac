"""The build and ``mars-pairs viewshed --label`` anchor a camera on the DEM with one function;
the view is built once (frozen); the view's stages are named and timed by the build alone."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio

from mars_pairs.errors import StageError, TerrainError
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.sample.build_sample import build_sample, view_stages
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.view import View, label_view
from support.configs import build_config

RADIUS_M = 150.0


def _labels(mission: Path) -> list[Path]:
    return sorted((mission / "labels").glob("*.xml"))


@pytest.mark.parametrize("observer_height", [None, 2.5])
def test_the_build_and_viewshed_label_anchor_the_same_camera_at_the_same_height(
    small_mission: Path, tmp_path: Path, observer_height: float | None
) -> None:
    geometry = {"radius": RADIUS_M, "viewshed": "wedge", "observer_height": observer_height}
    ctx = SampleContext.open(build_config(small_mission, tmp_path / "out", geometry=geometry))
    try:
        for label in _labels(small_mission):
            sample = build_sample(label, ctx)  # the build's path, as a worker runs it
            meta = json.loads(sample.members["meta.json"])
            obs = read_observation(label)
            pose = ctx.places.locate(obs)
            view = label_view(obs, pose, ctx.terrain, RADIUS_M, observer_height)  # the CLI's
            assert meta["camera_center_map"] == [float(v) for v in view.camera.center_map]
            assert meta["observer_height_m"] == view.height
            assert sample.row["dem_offset_m"] == view.dem_offset_m
            if observer_height is not None:
                assert view.height == pytest.approx(observer_height, abs=1e-6)
            # the two DEM windows differ (the build's is snapped and shared by a stop) but
            # both hold the radius, and the cells in view are the same on the shared cells
            camera = MapCamera.from_observation(obs, pose, ctx.crs_wkt)
            built = view_stages(pose, camera, ctx, Stages())
            np.testing.assert_array_equal(built.camera.center_map, view.camera.center_map)
            assert built.bands == view.bands
            assert view.mask.sum() > 0
            assert _mask_on(view, built).tolist() == view.mask.astype(bool).tolist()
    finally:
        ctx.close()


def _mask_on(view: View, other: View) -> np.ndarray:
    """``other``'s mask read at ``view``'s cell centres (the same DEM grid, another window)."""
    rows, cols = np.indices(view.mask.shape)
    x, y = view.window.colrow_to_xy(cols.ravel(), rows.ravel())
    c, r = other.window.xy_to_colrow(x, y)
    c, r = np.rint(c).astype(int), np.rint(r).astype(int)
    ok = (c >= 0) & (r >= 0) & (c < other.mask.shape[1]) & (r < other.mask.shape[0])
    out = np.zeros(c.shape, dtype=bool)
    out[ok] = other.mask[r[ok], c[ok]] > 0
    return out.reshape(view.mask.shape)


def test_the_view_is_frozen(small_mission: Path, tmp_path: Path) -> None:
    ctx = SampleContext.open(build_config(small_mission, tmp_path / "out"))
    try:
        label = _labels(small_mission)[0]
        obs = read_observation(label)
        pose = ctx.places.locate(obs)
        view = label_view(obs, pose, ctx.terrain, RADIUS_M)
    finally:
        ctx.close()
    with pytest.raises(dataclasses.FrozenInstanceError):
        view.mask = np.zeros_like(view.mask)  # type: ignore[misc]
    assert view.los.shape == view.mask.shape == view.window.data.shape


@pytest.mark.parametrize(
    ("method", "stages"),
    [("wedge", {"terrain", "viewshed"}), ("raycast", {"terrain", "raycast"}),
     ("both", {"terrain", "viewshed", "raycast"})],
)  # fmt: skip
def test_the_build_times_the_view_stages_by_name(
    small_mission: Path, tmp_path: Path, method: str, stages: set[str]
) -> None:
    geometry = {"radius": RADIUS_M, "viewshed": method}
    ctx = SampleContext.open(build_config(small_mission, tmp_path / "out", geometry=geometry))
    try:
        sample = build_sample(_labels(small_mission)[0], ctx)
    finally:
        ctx.close()
    assert set(sample.seconds) == {"label", "image", "locate", "chips", "encode"} | stages
    assert all(s >= 0.0 for s in sample.seconds.values())


def test_a_rover_over_dem_nodata_is_a_terrain_error_on_both_paths(
    small_mission: Path, tmp_path: Path
) -> None:
    mission = tmp_path / "mission"
    shutil.copytree(small_mission, mission)
    label = _labels(mission)[0]
    ctx = SampleContext.open(build_config(mission, tmp_path / "out"))
    obs = read_observation(label)
    pose = ctx.places.locate(obs)
    ox, oy = MapCamera.from_observation(obs, pose, ctx.crs_wkt).origin_map[:2]
    ctx.close()
    with rasterio.open(mission / "orbital" / "dem.tif", "r+") as dem:
        z = dem.read(1)
        row, col = dem.index(ox, oy)
        z[row - 3 : row + 4, col - 3 : col + 4] = dem.nodata if dem.nodata is not None else np.nan
        dem.write(z, 1)
    ctx = SampleContext.open(build_config(mission, tmp_path / "out"))
    try:
        with pytest.raises(StageError) as failed:
            build_sample(label, ctx)
        assert failed.value.stage == "terrain"
        assert type(failed.value.error) is TerrainError
        with pytest.raises(TerrainError, match=r"dem\.tif"):
            label_view(obs, pose, ctx.terrain, RADIUS_M)
    finally:
        ctx.close()
