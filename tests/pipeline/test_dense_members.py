"""Dense geometry members (``output.members``) on the synthetic mission, checked by closure
(its images are rendered from its ortho over its DEM), against the independent ray march of
``independent_truth`` (numpy + pyproj from the label fields), and with a terrain-class raster
rendered into the images by the mission's forward-projection renderer."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from affine import Affine
from PIL import Image

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.store.manifest import MANIFEST_SCHEMA
from support import independent_truth as truth
from support.configs import build_config
from support.members import rows_by_key, sample_members, tiff_array

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

STRIDE = 8
RADIUS_M = 300.0
CHIP = {"size_m": 128, "size_px": 512}  # 0.25 m: the ortho's own resolution


def _build(mission: Path, out: Path, **sections: Any) -> Path:
    config = build_config(
        mission, out, geometry={"radius": RADIUS_M, "ray_stride": STRIDE},
        **{"splits": None, **sections, "chips": {**CHIP, **sections.get("chips", {})}},
    )  # fmt: skip
    result = run_build(config)
    assert result.failures == 0
    return out


def _img(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)))


def _grey(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64).mean(axis=-1) if rgb.ndim == 3 else rgb.astype(np.float64)


@pytest.fixture(scope="module")
def dense(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _build(small_mission, tmp_path_factory.mktemp("dense"), output={"members": "all"})


@pytest.fixture(scope="module")
def plain(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _build(small_mission, tmp_path_factory.mktemp("plain"))


def test_members_written_located_and_checksummed(dense: Path) -> None:
    table = pq.read_table(dense / "manifest.parquet")
    rows = table.to_pylist()
    assert rows
    for field in ("range", "depth", "hits", "ortho_view", "view_valid", "dem_view",
                  "ground_on_map", "ground_on_map_cover", "ground_px"):  # fmt: skip
        for row in rows:
            assert row[f"{field}_size"] > 0 and row[f"{field}_crc32c"] is not None
    samples = sample_members(dense)
    for m in samples.values():
        meta = json.loads(m["meta.json"])
        h, w = (len(range(0, meta["height"], STRIDE)), len(range(0, meta["width"], STRIDE)))
        grids = {f: tiff_array(m[f"{f}.tif"]) for f in ("range", "depth", "hits", "dem_view")}
        assert grids["range"].shape == (h, w) and grids["range"].dtype == np.float32
        assert grids["depth"].dtype == grids["dem_view"].dtype == np.float32
        assert grids["hits"].shape == (h, w, 3) and grids["hits"].dtype == np.float64
        assert tiff_array(m["ground_px.tif"]).shape == (CHIP["size_px"], CHIP["size_px"], 2)
        assert meta["dense_stride"] == STRIDE and set(meta["dense_members"]) >= {"range"}
        # range >= depth > 0 where the ray hit
        r, d = tiff_array(m["range.tif"]), tiff_array(m["depth.tif"])
        ok = np.isfinite(r)
        assert ok.sum() > 100 and np.all(r[ok] >= d[ok] - 1e-3) and np.all(d[ok] > 0)


def test_default_build_is_unchanged_and_members_leave_the_rest_alone(
    dense: Path, plain: Path
) -> None:
    assert pq.read_schema(plain / "manifest.parquet").remove_metadata() == MANIFEST_SCHEMA
    doc = json.loads((plain / "dataset.json").read_text())
    assert "members" not in doc["config"]["output"] and "offset_m" not in doc["config"]["chips"]
    a, b = sample_members(plain), sample_members(dense)
    assert a.keys() == b.keys()
    for key in a:
        assert set(a[key]) == {n for n in b[key] if "." in n and n.split(".")[0] in
                               ("ground", "ortho", "dem", "viewshed", "corr", "meta")}  # fmt: skip
        assert "rover_px" not in json.loads(a[key]["meta.json"])
        for name in a[key]:
            if name != "meta.json":
                assert a[key][name] == b[key][name], (key, name)


def test_closure_ground_on_map_and_map_from_rover(dense: Path) -> None:
    """The ground image laid on the map reproduces the ortho; the map seen from the rover
    reproduces the ground image (the images are rendered from that ortho) over every valid
    pixel, and is valid wherever a ray hits the map within the radius, off the chip too."""
    checked_map = checked_view = 0
    beyond_chip = 0
    for key, m in sample_members(dense).items():
        ortho = _img(m["ortho.png"]).astype(np.float64)
        cover = tiff_array(m["ground_on_map_cover.tif"]) > 0
        on_map = _grey(tiff_array(m["ground_on_map.tif"]))
        if cover.sum() >= 500:
            r = np.corrcoef(on_map[cover], ortho[cover])[0, 1]
            assert r >= 0.95, (key, r, cover.sum())
            checked_map += 1
        ground = _grey(_img(m["ground.jpg"]))[::STRIDE, ::STRIDE]
        valid = tiff_array(m["view_valid.tif"]) > 0
        seen = tiff_array(m["ortho_view.tif"]).astype(np.float64)
        dem_view = tiff_array(m["dem_view.tif"])
        hits = tiff_array(m["hits.tif"])
        hit = np.isfinite(tiff_array(m["range.tif"]))
        # every hit within the radius is on the (gap-free) map: all valid, and only they
        assert np.array_equal(valid, hit), (key, valid.sum(), hit.sum())
        assert np.array_equal(np.isfinite(dem_view), valid)
        # the DEM seen from the rover is the terrain the ray met (z of the hit, less the
        # curvature drop: millimetres at this range)
        assert np.nanmax(np.abs(dem_view[valid] - hits[valid][:, 2])) < 0.05
        meta = json.loads(m["meta.json"])
        col_row = ~Affine(*meta["chip_transform"]) * (hits[..., 0], hits[..., 1])
        on_chip = np.all([(v >= 0) & (v <= CHIP["size_px"]) for v in col_row], axis=0)
        beyond_chip += int((valid & ~on_chip).sum())
        if valid.sum() >= 500:  # every valid pixel, grazing and far ones too
            r = np.corrcoef(seen[valid], ground[valid])[0, 1]
            assert r >= 0.95, (key, r, valid.sum())
            checked_view += 1
    assert checked_map >= 2 and checked_view >= 4
    assert beyond_chip >= 500  # the radius (300 m) reaches past the 128 m chips


def _truth_range_depth(label: Path, mission: Path, pixels: np.ndarray) -> tuple[Any, Any]:
    lab = truth.read_label_fields(label)
    places = next((mission / "places").glob("*.csv"))
    dem = mission / "orbital" / "dem.tif"
    cam = truth.place_camera(lab, places, dem)
    hits = truth.ground_hits(lab, places, dem, radius_m=RADIUS_M, step_m=0.5, pixels=pixels)
    ok = np.isfinite(hits[:, 0])
    rel = np.full((len(hits), 3), np.nan)
    rel[ok] = cam.enu.from_map(hits[ok]) - cam.centre_enu
    axis = cam.rot @ (lab.a / np.linalg.norm(lab.a))
    return np.linalg.norm(rel, axis=1), rel @ axis


def _label(dataset: Path, row: dict) -> Path:
    """The label of a manifest row: ``label_path`` is relative to dataset.json's labels_root."""
    root = json.loads((dataset / "dataset.json").read_text())["labels_root"]
    return (dataset / root / row["label_path"]).resolve()


def test_range_and_depth_match_the_independent_march(dense: Path, small_mission: Path) -> None:
    errors_r, errors_d = [], []
    rows = rows_by_key(dense)
    for key, m in list(sample_members(dense).items())[:2]:
        r, d = tiff_array(m["range.tif"]), tiff_array(m["depth.tif"])
        h, w = r.shape
        lines, samples = np.meshgrid(np.arange(h)[::2], np.arange(w)[::2], indexing="ij")
        pixels = np.column_stack([samples.ravel() * STRIDE, lines.ravel() * STRIDE]).astype(float)
        tr, td = _truth_range_depth(_label(dense, rows[key]), small_mission, pixels)
        ours_r = r[lines.ravel(), samples.ravel()].astype(np.float64)
        ours_d = d[lines.ravel(), samples.ravel()].astype(np.float64)
        both = np.isfinite(ours_r) & np.isfinite(tr) & (tr < 0.9 * RADIUS_M)
        assert both.sum() >= 0.9 * (np.isfinite(tr) & (tr < 0.9 * RADIUS_M)).sum() - 5
        errors_r.append(np.abs(ours_r[both] - tr[both]))
        errors_d.append(np.abs(ours_d[both] - td[both]))
    er, ed = np.concatenate(errors_r), np.concatenate(errors_d)
    assert len(er) > 300
    assert np.median(er) <= 0.05, np.median(er)
    assert np.median(ed) <= 0.05, np.median(ed)


def test_offset_chips_rover_px_camera_px_heading(small_mission: Path, tmp_path: Path) -> None:
    out = _build(small_mission, tmp_path / "a", chips={"offset_m": 20.0})
    again = _build(small_mission, tmp_path / "b", chips={"offset_m": 20.0})
    assert sample_members(out) == sample_members(again)  # seeded per sample
    res = CHIP["size_m"] / CHIP["size_px"]
    shifts = []
    for key, m in sample_members(out).items():
        meta = json.loads(m["meta.json"])
        tr = Affine(*meta["chip_transform"])
        col, row = ~tr * (meta["easting"], meta["northing"])
        assert np.allclose(meta["rover_px"], [col, row], atol=1e-6)
        shift = np.subtract(meta["rover_px"], CHIP["size_px"] / 2) * res
        assert np.all(np.abs(shift) <= 20.0 + 1e-6)
        shifts.append(shift)
        cx, cy = meta["camera_center_map"][:2]
        assert np.allclose(meta["camera_px"], ~tr * (cx, cy), atol=1e-6)
        # the viewshed chip's visible pixels lie ahead of the camera along heading_deg
        vis = _img(m["viewshed.png"]) > 0
        rows_, cols_ = np.nonzero(vis)
        if len(rows_) < 50:
            continue
        dx = cols_ + 0.5 - meta["camera_px"][0]
        dy = rows_ + 0.5 - meta["camera_px"][1]
        bearing = np.degrees(np.arctan2(dx, -dy)) % 360.0
        off = (bearing - meta["heading_deg"] + 180.0) % 360.0 - 180.0
        assert np.median(np.abs(off)) <= meta["hfov_deg"] / 2 + 5.0, (key, np.median(off))
    assert np.max(np.abs(shifts)) > 1.0  # really shifted


# -- terrain classes ------------------------------------------------------------------------------
LEVELS = np.array([40, 100, 160, 220])


def _class_mission(small_mission: Path, out: Path) -> tuple[Path, Affine, np.ndarray]:
    """classes.tif on the ortho's grid: 4 classes in 12 m patches (uint8 codes LEVELS)."""
    with rasterio.open(small_mission / "orbital" / "ortho.tif") as src:
        profile, tr, shape = src.profile, src.transform, src.shape
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    x, y = tr * (cols + 0.5, rows + 0.5)
    rng = np.random.default_rng(5)
    table = rng.integers(0, 4, size=(512, 512))
    classes = table[(np.floor(x / 12.0) % 512).astype(int), (np.floor(y / 12.0) % 512).astype(int)]
    path = out / "classes.tif"
    profile.update(nodata=None)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(LEVELS[classes].astype(np.uint8), 1)
    return path, tr, LEVELS[classes].astype(np.uint8)


def _render_classes(label: Path, mission: Path, codes: np.ndarray) -> np.ndarray:
    """The class of each image pixel (-1: sky), rendered like the mission's images (forward
    projection with a depth buffer, no ray casting)."""
    from mars_pairs.geometry.mapcam import MapCamera
    from mars_pairs.geometry.places import Places
    from mars_pairs.pds import read_observation
    from mars_pairs.synth.render import TERRAIN_TINT, DemGrid, block_ranges, render_view

    with rasterio.open(mission / "orbital" / "dem.tif") as src:
        z = src.read(1, masked=True).astype(np.float64).filled(np.nan)
        dem_tr, crs = src.transform, src.crs.to_wkt()
    obs = read_observation(label)
    pose = Places.from_csv(next((mission / "places").glob("*.csv"))).locate(obs)
    mc = MapCamera.from_observation(obs, pose, crs)
    factor = round(codes.shape[0] / z.shape[0])
    rgb, depth = render_view(mc, DemGrid(z, dem_tr), block_ranges(z), codes, factor)
    green = rgb[..., 1].astype(np.float64) / TERRAIN_TINT[1]
    cls = np.abs(green[..., None] - LEVELS).argmin(axis=-1)
    return np.where(np.isfinite(depth), cls, -1)


def test_classes_move_between_image_and_chip(
    dense: Path, small_mission: Path, tmp_path: Path
) -> None:
    from mars_pairs.raster.chips import ChipGrid, read_chip
    from mars_pairs.raster.transfer import chip_to_image, image_to_chip

    path, _, codes = _class_mission(small_mission, tmp_path)
    rows = rows_by_key(dense)
    checked = checked_back = 0
    for key, m in sample_members(dense).items():
        meta = json.loads(m["meta.json"])
        n = CHIP["size_px"]
        grid = ChipGrid(Affine(*meta["chip_transform"]), meta["crs"], n, 0.0, 0.0, CHIP["size_m"])
        chip_cls = np.abs(read_chip(str(path), grid, nearest=True)[..., None] - LEVELS).argmin(-1)
        image_cls = _render_classes(_label(dense, rows[key]), small_mission, codes)
        # image -> chip
        moved, cover = image_to_chip(image_cls.astype(np.int16), tiff_array(m["ground_px.tif"]),
                                     nearest=True, fill=-1)  # fmt: skip
        cover &= moved >= 0
        if cover.sum() >= 200:
            agree = (moved[cover] == chip_cls[cover]).mean()
            assert agree >= 0.98, (key, agree, cover.sum())
            checked += 1
        # chip -> image through the hits at the dense stride
        hits = tiff_array(m["hits.tif"])
        chip_px = grid.to_pixel(hits[..., 0], hits[..., 1])
        back, valid = chip_to_image(chip_cls.astype(np.int16), chip_px, nearest=True, fill=-1)
        truth_cls = image_cls[::STRIDE, ::STRIDE]
        valid &= truth_cls >= 0
        if valid.sum() >= 100:
            agree = (back[valid] == truth_cls[valid]).mean()
            assert agree >= 0.98, (key, agree, valid.sum())
            checked_back += 1
    assert checked >= 2 and checked_back >= 2


def test_verify_checks_the_dense_members(dense: Path, tmp_path: Path) -> None:
    import shutil

    from mars_pairs.store.verify import verify_dataset

    report = verify_dataset(dense)
    rows = pq.read_table(dense / "manifest.parquet").to_pylist()
    assert not report.damage and report.members == len(rows) * 15
    copy = tmp_path / "copy"
    shutil.copytree(dense, copy)
    row = rows[0]
    shard = copy / row["depth_shard"]
    data = bytearray(shard.read_bytes())
    data[row["depth_offset"] + 200] ^= 0xFF
    shard.write_bytes(bytes(data))
    damage = verify_dataset(copy).damage
    assert len(damage) == 1 and "depth" in str(damage[0]), damage


def _chip_bearing_of_axis(label: Path, mission: Path, chip_transform: list[float]) -> float:
    """The camera axis's bearing on the chip (degrees clockwise from the chip's up, row 0),
    derived independently of the package: the label's A placed by ``independent_truth``
    (numpy + pyproj), a point 10 m ahead along its horizontal part taken to the map and
    through the chip's affine."""
    lab = truth.read_label_fields(label)
    places = next((mission / "places").glob("*.csv"))
    cam = truth.place_camera(lab, places, mission / "orbital" / "dem.tif")
    axis = cam.rot @ (lab.a / np.linalg.norm(lab.a))  # ENU
    ahead = cam.centre_enu + 10.0 * np.array([axis[0], axis[1], 0.0]) / np.hypot(*axis[:2])
    (x0, y0, _), (x1, y1, _) = cam.enu.to_map(np.stack([cam.centre_enu, ahead]))
    inv = ~Affine(*chip_transform)
    (c0, r0), (c1, r1) = inv * (x0, y0), inv * (x1, y1)
    return float(np.degrees(np.arctan2(c1 - c0, -(r1 - r0))) % 360.0)


def _angle(a: float, b: float) -> float:
    """|a - b| in degrees, across 360."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_heading_up_chips_point_the_camera_up(small_mission: Path, tmp_path: Path) -> None:
    """Heading-up chips turn the camera's axis to the chip's up (heading 0), checked against
    the axis derived from the label without the package; north-up chips keep it at its
    map bearing (heading_deg, the same derivation)."""
    out = _build(
        small_mission, tmp_path / "h", chips={"offset_m": 10.0, "orientation": "heading-up"}
    )
    north = _build(small_mission, tmp_path / "n", chips={"offset_m": 10.0})
    rows = rows_by_key(out)
    north_meta = {k: json.loads(m["meta.json"]) for k, m in sample_members(north).items()}
    bearings = []
    for key, m in sample_members(out).items():
        meta = json.loads(m["meta.json"])
        label = _label(out, rows[key])
        bearing = _chip_bearing_of_axis(label, small_mission, meta["chip_transform"])
        assert _angle(bearing, 0.0) < 0.01, (key, bearing)
        assert _angle(meta["heading_deg"], bearing) < 0.01, (key, meta["heading_deg"], bearing)
        tr = Affine(*meta["chip_transform"])
        assert np.allclose(meta["rover_px"], ~tr * (meta["easting"], meta["northing"]))
        shift = np.subtract(meta["rover_px"], CHIP["size_px"] / 2)
        assert np.all(np.abs(shift) * CHIP["size_m"] / CHIP["size_px"] <= 10.0 + 1e-6)
        up = north_meta[key]
        north_bearing = _chip_bearing_of_axis(label, small_mission, up["chip_transform"])
        assert _angle(up["heading_deg"], north_bearing) < 0.01, (key, up["heading_deg"])
        bearings.append(north_bearing)
    # the cameras look different ways: a heading-up chip really turned
    assert max(_angle(b, 0.0) for b in bearings) > 30.0
