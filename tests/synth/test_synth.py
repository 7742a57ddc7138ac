"""The synthetic mission: determinism, rasters, PLACES, labels, and the rendered images.

The renderer projects terrain samples forward; these tests check it against an independent
ray caster (``mars_pairs.kernels.raycast.cast_rays``) and the labels against truth.parquet.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from PIL import Image

from mars_pairs.geometry.frames import (
    M2020_PLACES_CRS,
    MSL_PLACES_CRS,
    lonlat_to_map,
    map_to_lonlat,
    quaternion_to_matrix,
)
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Places
from mars_pairs.pds import read_observation
from mars_pairs.synth import generate_mission
from mars_pairs.synth.render import SKY_RGB, camera_params

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s

RUN = {"seed": 7, "stops": 2, "images_per_stop": 3, "size": "small"}
EXTENTS = {  # real map extents (DESIGN.md) the synthetic DEMs must lie in
    "m2020": (4351200, 1091760, 4355690, 1095210),
    "msl": (8141036, -282743, 8147777, -271512),
}
CRS = {"m2020": M2020_PLACES_CRS, "msl": MSL_PLACES_CRS}
PLACES_NAME = {"m2020": "best_interp.csv", "msl": "localized_interp.csv"}


@pytest.fixture(scope="module")
def both(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "both"
    generate_mission(out, mission="both", **RUN)
    return out


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def _truth(root: Path) -> list[dict]:
    return pq.read_table(root / "truth.parquet").to_pylist()


def _read_raster(path: Path) -> tuple[np.ndarray, rasterio.Affine, object]:
    with rasterio.open(path) as src:
        data = src.read(1, masked=True)
        return data.astype(np.float64).filled(np.nan), src.transform, src.crs


def test_same_seed_same_bytes(both: Path, tmp_path: Path) -> None:
    result = generate_mission(tmp_path / "again", mission="m2020", **RUN)
    assert result["images"] == 6
    first, second = _files(both / "m2020"), _files(tmp_path / "again")
    assert sorted(first) == sorted(second)
    assert {k for k in first if first[k] != second[k]} == set()
    # a single-mission run writes straight into OUT
    assert (tmp_path / "again" / "orbital" / "dem.tif").is_file()


@pytest.mark.parametrize("mission", ["m2020", "msl"])
def test_rasters_crs_and_bounds(both: Path, mission: str) -> None:
    root = both / mission
    with rasterio.open(root / "orbital" / "dem.tif") as dem, \
            rasterio.open(root / "orbital" / "ortho.tif") as ortho:  # fmt: skip
        assert dem.dtypes[0] == "float32" and dem.nodata is not None
        assert ortho.dtypes[0] == "uint8" and ortho.count == 1
        assert dem.res == (1.0, 1.0) and ortho.res == (0.25, 0.25)
        assert tuple(dem.bounds) == tuple(ortho.bounds)
        assert dem.profile["tiled"] and dem.profile["compress"] == "deflate"
        left, bottom, right, top = dem.bounds
        x0, y0, x1, y1 = EXTENTS[mission]
        assert x0 <= left < right <= x1 and y0 <= bottom < top <= y1
        # the files' CRS is the mission's map CRS: same lon/lat -> same map x, y
        lon, lat = map_to_lonlat(0.5 * (left + right), 0.5 * (bottom + top), CRS[mission])
        for crs in (dem.crs, ortho.crs):
            x, y = lonlat_to_map(lon, lat, crs.to_wkt())
            assert abs(x - 0.5 * (left + right)) < 1e-3 and abs(y - 0.5 * (bottom + top)) < 1e-3
        z = dem.read(1, masked=True)
        base = -2570.0 if mission == "m2020" else -4500.0
        assert abs(float(z.mean()) - base) < 60.0
        assert 0 < int(z.mask.sum()) < 0.02 * z.size  # a few nodata cells at an edge


@pytest.mark.parametrize("mission", ["m2020", "msl"])
def test_labels_and_places_give_the_true_pose_and_camera(both: Path, mission: str) -> None:
    root = both / mission
    places = Places.from_csv(root / "places" / PLACES_NAME[mission])
    header = (root / "places" / PLACES_NAME[mission]).read_text().splitlines()[0]
    assert header.startswith("frame,site,drive,pose,landing_x") and header.endswith("sclk,sol")
    rows = _truth(root)
    assert len(rows) == 6
    for t in rows:
        obs = read_observation(root / t["label_path"])
        assert obs.product_id == t["product_id"] and obs.mission == mission
        assert (obs.site, obs.drive, obs.sol) == (t["site"], t["drive"], t["sol"])
        assert (obs.width, obs.height) == (t["width"], t["height"])
        assert obs.image_path is not None and obs.image_path == root / t["image_path"]
        cam = obs.camera
        assert cam.model_type == t["camera_model_type"] and cam.frame == "ROVER_NAV_FRAME"
        for name in ("c", "a", "h", "v", "o", "r"):
            want = t[f"camera_{name}"]
            got = getattr(cam, name)
            if want is None:
                assert got is None
            else:
                np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(obs.rover_quaternion, t["quaternion"], atol=1e-9)
        np.testing.assert_allclose(obs.rover_offset_m, t["site_offset_ned"], atol=1e-6)
        assert obs.azimuth_deg == pytest.approx(t["azimuth_deg"], abs=1e-6)
        assert obs.elevation_deg == pytest.approx(t["elevation_deg"], abs=1e-6)
        assert obs.hfov_deg == pytest.approx(t["hfov_deg"], abs=1e-6)
        assert 5.0 <= t["hfov_deg"] <= 21.0 and -26.0 <= t["elevation_deg"] <= 6.0
        pose = places.locate(obs)
        assert pose.source == "places"
        assert pose.easting == pytest.approx(t["easting"], abs=1e-3)
        assert pose.northing == pytest.approx(t["northing"], abs=1e-3)
        assert pose.elevation_m == pytest.approx(t["elevation"], abs=1e-3)
        assert pose.longitude == pytest.approx(t["longitude"], abs=1e-8)
        assert pose.latitude == pytest.approx(t["latitude"], abs=1e-8)
        np.testing.assert_allclose(pose.quaternion, t["quaternion"], atol=1e-8)
        # the label's SITE_FRAME pointing is the image-centre ray rotated by the quaternion
        rot = quaternion_to_matrix(obs.rover_quaternion)
        _, ray = cam.unproject(np.array([[(obs.width - 1) / 2, (obs.height - 1) / 2]]))
        n, e, _d = rot @ ray[0]
        assert math.degrees(math.atan2(e, n)) % 360 == pytest.approx(obs.azimuth_deg, abs=1e-6)
        # the rover stands on the DEM
        dem, tr, _ = _read_raster(root / "orbital" / "dem.tif")
        col, row = ~tr * (pose.easting, pose.northing)
        assert abs(dem[int(row), int(col)] - pose.elevation_m) < 1.0
        # the label's offset from the SITE origin agrees with the PLACES position
        fallback = places.site_origin(obs.site)
        assert fallback is not None


def _is_sky(rgb: np.ndarray) -> np.ndarray:
    return np.abs(rgb.astype(int) - np.array(SKY_RGB)).max(axis=-1) <= 6


def test_sky_above_terrain_below(both: Path) -> None:
    root = both / "m2020"
    rows = _truth(root)
    up = max(rows, key=lambda t: t["elevation_deg"] + t["vfov_deg"] / 2)
    down = min(rows, key=lambda t: t["elevation_deg"])
    assert up["elevation_deg"] + up["vfov_deg"] / 2 > 3.0 and down["elevation_deg"] < -10.0
    up_img = np.asarray(Image.open(root / up["image_path"]))
    down_img = np.asarray(Image.open(root / down["image_path"]))
    assert _is_sky(up_img[:5]).mean() > 0.8
    assert _is_sky(down_img[:5]).mean() == 0.0
    for t in rows:
        img = np.asarray(Image.open(root / t["image_path"]))
        assert img.shape == (t["height"], t["width"], 3)
        assert _is_sky(img[-5:]).mean() < 0.05  # terrain at the bottom of every image


def test_kernel_projection_matches_mapcam(both: Path) -> None:
    """The renderer's numba projection equals MapCamera.project_map (curvature switched off)."""
    from mars_pairs.synth.render import _point

    root = both / "msl"
    places = Places.from_csv(root / "places" / PLACES_NAME["msl"])
    for t in _truth(root)[:2]:
        obs = read_observation(root / t["label_path"])
        mc = MapCamera.from_observation(obs, places.locate(obs), places.crs)
        p, jinv = camera_params(mc)
        p[20] = 0.0
        _, dirs = mc.camera.unproject(np.array([[10.0, 20.0], [300.0, 200.0]]))
        for ray in dirs:
            local = mc.camera.c + 40.0 * ray
            pm = mc.origin_map + mc.jacobian @ local
            want = mc.project_map(pm[None])[0]
            n, e = jinv @ (pm[:2] - mc.origin_map[:2])
            x, y, _, _ = _point(n, e, pm[2], p)
            assert x == pytest.approx(want[0], abs=1e-6) and y == pytest.approx(want[1], abs=1e-6)


def _bilinear(img: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear sample, cell centres at integer (col, row)."""
    h, w = img.shape
    j = np.clip(np.floor(col).astype(int), 0, w - 2)
    i = np.clip(np.floor(row).astype(int), 0, h - 2)
    tx, ty = col - j, row - i
    top = img[i, j] * (1 - tx) + img[i, j + 1] * tx
    return top * (1 - ty) + (img[i + 1, j] * (1 - tx) + img[i + 1, j + 1] * tx) * ty


@pytest.mark.parametrize("mission", ["m2020", "msl"])
def test_rendering_agrees_with_ray_casting(both: Path, mission: str) -> None:
    cast_rays = pytest.importorskip("mars_pairs.kernels.raycast").cast_rays
    root = both / mission
    places = Places.from_csv(root / "places" / PLACES_NAME[mission])
    dem, dem_tr, _ = _read_raster(root / "orbital" / "dem.tif")
    ortho, ortho_tr, _ = _read_raster(root / "orbital" / "ortho.tif")
    for t in _truth(root):
        obs = read_observation(root / t["label_path"])
        mc = MapCamera.from_observation(obs, places.locate(obs), places.crs)
        pix = mc.pixel_grid(stride=7)
        origins, dirs = mc.pixel_rays(pix)
        hits, _ = cast_rays(origins, dirs, (dem.astype(np.float32), dem_tr), max_range=5000.0,
                            observer_xy=tuple(mc.center_map[:2]))  # fmt: skip
        img = np.asarray(Image.open(obs.image_path)).astype(np.float64)
        px = img[pix[:, 1].astype(int), pix[:, 0].astype(int)]
        sky = _is_sky(px.astype(np.uint8))
        hit = np.isfinite(hits[:, 0])
        assert (sky == hit).mean() < 0.02, t["product_id"]
        both_ok = hit & ~sky
        assert both_ok.sum() > 200
        col, row = ~ortho_tr * (hits[both_ok, 0], hits[both_ok, 1])
        want = _bilinear(ortho, np.asarray(col) - 0.5, np.asarray(row) - 0.5)
        lum = px[both_ok] @ np.array([0.299, 0.587, 0.114])
        corr = np.corrcoef(want, lum)[0, 1]
        assert corr >= 0.95, (t["product_id"], corr)


# -- more checks: seeds, CRS identity, camera models, ortho texture, timing -----------------------
def test_other_seed_other_bytes_and_msl_reproducible(both: Path, tmp_path: Path) -> None:
    """msl alone with the same seed repeats the "both" run's msl bytes; another seed gives
    other rasters, PLACES, truth and images (m2020)."""
    import time

    start = time.perf_counter()
    generate_mission(tmp_path / "same", mission="msl", **RUN)
    seconds = time.perf_counter() - start
    print(f"\nsynth msl {RUN}: {seconds:.2f} s")  # measured, not asserted
    same, ref = _files(tmp_path / "same"), _files(both / "msl")
    assert sorted(same) == sorted(ref)
    assert [k for k in ref if ref[k] != same[k]] == []
    generate_mission(tmp_path / "other", mission="m2020", **{**RUN, "seed": RUN["seed"] + 1})
    other, ref = _files(tmp_path / "other"), _files(both / "m2020")
    for name in ("orbital/dem.tif", "orbital/ortho.tif", "places/best_interp.csv",
                 "truth.parquet"):  # fmt: skip
        assert other[name] != ref[name], name
    ref_jpgs = {v for k, v in ref.items() if k.endswith(".jpg")}
    assert not ref_jpgs & {v for k, v in other.items() if k.endswith(".jpg")}


@pytest.mark.parametrize("mission", ["m2020", "msl"])
def test_raster_crs_equals_mission_crs(both: Path, mission: str) -> None:
    """DEM and ortho carry the mission's PLACES CRS (pyproj equality), 1 m DEM, 0.25-0.5 m
    ortho, nodata set on both, the DEM's nodata cells and the ortho's zeros coincide."""
    from pyproj import CRS as ProjCRS

    want = ProjCRS.from_user_input(CRS[mission])
    root = both / mission
    with rasterio.open(root / "orbital" / "dem.tif") as dem, \
            rasterio.open(root / "orbital" / "ortho.tif") as ortho:  # fmt: skip
        for src in (dem, ortho):
            assert ProjCRS.from_wkt(src.crs.to_wkt()).equals(want, ignore_axis_order=True)
        assert dem.nodata is not None and ortho.nodata == 0
        assert dem.res == (1.0, 1.0) and 0.25 <= ortho.res[0] == ortho.res[1] <= 0.5
        f = round(dem.res[0] / ortho.res[0])
        dem_bad = dem.read_masks(1) == 0
        ortho_bad = ortho.read(1) == 0
        assert dem_bad.any()
        assert np.array_equal(np.repeat(np.repeat(dem_bad, f, 0), f, 1), ortho_bad)


@pytest.mark.parametrize("mission", ["m2020", "msl"])
def test_both_camera_models_occur(both: Path, mission: str) -> None:
    models = {t["camera_model_type"] for t in _truth(both / mission)}
    assert models == {"CAHV", "CAHVOR"}


def test_ortho_has_texture_at_pixel_scale(both: Path) -> None:
    """Rocks, ripples and grain: the ortho varies between neighbouring 0.25 m pixels and has
    dark and bright spots (shadows, lit rock faces) well away from its local mean."""
    ortho, _, _ = _read_raster(both / "m2020" / "orbital" / "ortho.tif")
    core = ortho[200:-200, 200:-200]
    assert np.nanstd(core) > 15.0
    fine = np.abs(np.diff(core, axis=1))
    assert np.nanmedian(fine) >= 1.0 and np.nanpercentile(fine, 99) > 12.0
    lo, mid, hi = np.nanpercentile(core, [0.5, 50, 99.5])
    assert lo < 0.55 * mid and hi > 1.4 * mid
