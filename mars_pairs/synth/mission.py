"""``generate_mission``: a synthetic Mars mission with exact ground truth.

Layout written for one mission (``OUT`` directly, or ``OUT/m2020`` and ``OUT/msl`` for
"both"):

    orbital/dem.tif     float32 DEM, 1 m/px, mission map CRS, nodata -3.4028235e38
    orbital/ortho.tif   uint8 ortho (0.25 m/px small, 0.5 m/px default and demo), nodata 0
    places/best_interp.csv | places/localized_interp.csv   PLACES table
    labels/<product>.xml|.LBL and labels/<product>.jpg     labels, each with its image
    truth.parquet       one row per image: pose, camera, pointing (the exact truth)
    with terrain_labels: orbital/terrain_classes.tif (uint8 true classes, ortho grid, nodata
    255) and ai4mars/ (every image's class, rover and range masks in the AI4Mars layout)

Frames and units follow ``mars_pairs.geometry.frames`` (map CRS metres, SITE_FRAME NED,
ROVER_NAV_FRAME).
The same seed gives the same bytes in every file.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import rasterio
from affine import Affine
from PIL import Image
from rasterio.crs import CRS as RioCRS
from tqdm import tqdm

from mars_pairs.errors import ArgumentError, WorkerDiedError
from mars_pairs.geometry.frames import M2020_PLACES_CRS, MSL_PLACES_CRS, quaternion_to_matrix
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Pose
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.synth.ai4mars_truth import (
    AI4MARS_DIR,
    CLASSES_NAME,
    TruthMasks,
    truth_masks,
    write_ai4mars_truth,
)
from mars_pairs.synth.cameras import (
    ZOOM_STOP_WEIGHTS,
    ZOOM_STOPS_MM,
    CameraSpec,
    build_camera,
    centre_pointing_site,
    m2020_product_id,
    mission_cameras,
    msl_product_id,
    navcam_product_id,
    wide_camera,
    zoom_focal_mm,
    zoom_hfov_deg,
)
from mars_pairs.synth.ortho import fill_nodata, make_ortho
from mars_pairs.synth.render import BLOCK, DemGrid, block_ranges, render_view, render_view_hits
from mars_pairs.synth.terrain import Boulders, make_dem
from mars_pairs.synth.terrain_classes import terrain_classes
from mars_pairs.synth.traverse import (
    DemSampler,
    RoverState,
    SiteOrigin,
    Traverse,
    euler_zyx_deg,
    make_traverse,
    write_places_csv,
)

DEM_NODATA = -3.4028235e38
RENDER_THREADS = 2
MISSIONS = ("m2020", "msl")
_SCLK_EPOCH = datetime(2000, 1, 1, 11, 58, 55, 816000)  # SCLK 0 (J2000), UTC


@dataclass(frozen=True)
class MissionSpec:
    """Where and how a mission is generated."""

    name: str
    crs: str
    centre_xy: tuple[float, float]  # map metres, inside the real DEM extent
    base_elevation_m: float
    places_name: str
    label_suffix: str
    first_site: int
    first_sol: int
    sclk_sol0: int  # spacecraft clock at the start of sol 0


@dataclass(frozen=True)
class SizeSpec:
    """Raster sizes and default counts for a ``size`` preset."""

    dem_cells: int  # DEM is dem_cells x dem_cells at 1 m
    ortho_factor: int  # ortho pixels per DEM cell
    stops: int
    images_per_stop: int
    survey: bool = False  # pointing: False, ``_grid_stop``; True, ``_survey_stop``
    directed: bool = False  # traverse: False, wanders about the centre; True, heads across
    margin_m: float | None = None  # traverse keeps this far inside the DEM; None: a quarter
    stop_spacing_m: tuple[float, float] = (15.0, 35.0)  # between stops along the path
    # images show the DEM within this many metres (east and north) of the camera, as if the
    # DEM ended there (None: all of it); rendering time grows with the terrain in view
    render_window_m: float | None = None


SPECS = {
    "m2020": MissionSpec("m2020", M2020_PLACES_CRS, (4353445.0, 1093485.0), -2570.0,
                         "best_interp.csv", ".xml", 3, 52, 666910000),
    "msl": MissionSpec("msl", MSL_PLACES_CRS, (8144406.0, -277128.0), -4500.0,
                       "localized_interp.csv", ".LBL", 56, 1429, 397450000),
}  # fmt: skip
# default: a 2 km DEM (the traverse keeps to its central kilometre, so every view still reaches
# 500 m or more of terrain) and 8 x 4 full-size images: about a minute on 2 cores
# demo: a 3 km DEM with a 0.5 m ortho, a ~3 km traverse heading across it, 90 stops of 3 images
# (a Navcam-like wide image and two Mastcam-Z frames, quarter size) pointed as the mission
# points them: a dataset worth training on, in ~65 s of CPU (~45 s on 2 cores)
SIZES = {
    "small": SizeSpec(1024, 4, 3, 4),
    "default": SizeSpec(2048, 2, 8, 4),
    "demo": SizeSpec(3072, 2, 90, 3, survey=True, directed=True, margin_m=200.0,
                     stop_spacing_m=(30.0, 45.0), render_window_m=600.0),
}  # fmt: skip
DEM_RES_M = 1.0


def generate_mission(
    out_dir: str | Path,
    *,
    seed: int = 0,
    mission: str = "m2020",
    stops: int | None = None,
    images_per_stop: int | None = None,
    size: str = "small",
    log: Callable[[str], None] | None = None,
    terrain_labels: bool = False,
    workers: int = 1,
) -> dict[str, Any]:
    """Generate a synthetic mission ("m2020", "msl" or "both") under ``out_dir``.

    ``terrain_labels``: also write the true terrain classes (``orbital/terrain_classes.tif``,
    ``synth.terrain_classes``) and every image's class mask, rover mask and 30 m range mask
    in the AI4Mars layout under ``ai4mars/`` (``synth.ai4mars_truth``); the other files keep
    their bytes.
    ``stops`` / ``images_per_stop`` default to the size preset (small: 3 x 4, default:
    8 x 4, demo: 90 x 3). ``log``: called with a line per phase (terrain, traverse,
    rendering), and a tqdm bar counts the rendered images; None: silent.
    ``workers``: processes rendering the images (1: this process); the files' bytes are the
    same for any number.
    Returns {"out_dir", "missions": {name: {paths..., counts...}}, "images"}.
    """
    if mission not in (*MISSIONS, "both"):
        raise ArgumentError(f"mission must be 'm2020', 'msl' or 'both', got {mission!r}")
    if size not in SIZES:
        raise ArgumentError(f"size must be one of {', '.join(SIZES)}, got {size!r}")
    preset = SIZES[size]
    k = preset.stops if stops is None else int(stops)
    m = preset.images_per_stop if images_per_stop is None else int(images_per_stop)
    if k < 1 or m < 1:
        raise ArgumentError("stops and images_per_stop must be >= 1")
    if workers < 1:
        raise ArgumentError(f"workers must be >= 1, got {workers}")
    out = Path(out_dir)
    names = MISSIONS if mission == "both" else (mission,)
    result: dict[str, Any] = {"out_dir": str(out), "missions": {}}
    for name in names:
        target = out / name if mission == "both" else out
        rng = np.random.default_rng([int(seed), MISSIONS.index(name)])
        result["missions"][name] = _generate_one(target, rng, SPECS[name], size, k, m, log,
                                                 terrain_labels, workers)  # fmt: skip
    result["images"] = sum(v["images"] for v in result["missions"].values())
    return result


# -- rasters -------------------------------------------------------------------------------------
def _write_geotiff(path: Path, data: np.ndarray, transform: Affine, crs: str, nodata: float,
                   predictor: int) -> None:  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    profile = {
        "driver": "GTiff", "width": data.shape[1], "height": data.shape[0], "count": 1,
        "dtype": data.dtype.name, "crs": RioCRS.from_user_input(crs), "transform": transform,
        "nodata": nodata, "tiled": True, "blockxsize": 256, "blockysize": 256,
        "compress": "deflate", "predictor": predictor, "zlevel": 6, "num_threads": 1,
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)


def _terrain(
    rng: np.random.Generator, spec: MissionSpec, size: SizeSpec
) -> tuple[np.ndarray, Affine, np.ndarray, Affine, Boulders, np.ndarray]:
    """DEM (float32 with NaN nodata), its transform, ortho (uint8), ortho transform, the
    boulders drawn on it and the DEM as float64 with its nodata filled by its mean (what the
    ortho and the traverse read)."""
    n = size.dem_cells
    z, boulders = make_dem(rng, n, DEM_RES_M, spec.base_elevation_m)
    # a nodata notch at the north-west corner, as real DTMs have ragged edges
    ii, jj = np.ogrid[0:n, 0:n]
    z[ii + jj < n // 64] = np.nan
    dem32 = z.astype(np.float32)
    left = round(spec.centre_xy[0] - n * DEM_RES_M / 2)
    top = round(spec.centre_xy[1] + n * DEM_RES_M / 2)
    transform = Affine(DEM_RES_M, 0.0, left, 0.0, -DEM_RES_M, top)
    dem64 = dem32.astype(np.float64)
    filled = fill_nodata(dem64)
    ortho = make_ortho(rng, dem64, DEM_RES_M, size.ortho_factor, boulders, filled=filled)
    res_o = DEM_RES_M / size.ortho_factor
    ortho_tr = Affine(res_o, 0.0, left, 0.0, -res_o, top)
    return dem32, transform, ortho, ortho_tr, boulders, filled


# -- images --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Shot:
    """One planned image: the stop, the camera, its pointing and names."""

    stop: RoverState
    index: int  # image index within the mission
    obs: Observation
    pose: Pose
    sclk: int


def _pose(state: RoverState, crs: str, site: SiteOrigin) -> Pose:
    return Pose(
        site=state.site, drive=state.drive, easting=state.x, northing=state.y, crs=crs,
        latitude=state.lat, longitude=state.lon, elevation_m=state.z,
        quaternion=state.quaternion.copy(), source="places", attitude_source="places",
        site_lonlat=(site.lon, site.lat),
    )  # fmt: skip


def render_bar(total: int, name: str, disable: bool) -> Any:
    """The rendering progress bar, opened after the first of ``total`` images: it starts at 1,
    and its rate (and ETA) counts the images after it only."""
    return tqdm(total=total, initial=1, desc=f"{name}: rendering", unit="img", disable=disable)


def _plan_shots(rng: np.random.Generator, spec: MissionSpec, size: str, trav: Traverse,
                per_stop: int, label_dir: Path) -> list[Shot]:  # fmt: skip
    """Cameras, pointings and product names of every image (deterministic in ``rng``)."""
    cams = mission_cameras(spec.name, size)
    wide = wide_camera(spec.name, size)
    shots: list[Shot] = []
    index = 0
    sites = {s.site: s for s in trav.sites}
    for k, stop in enumerate(trav.stops):
        rot = quaternion_to_matrix(stop.quaternion)
        if SIZES[size].survey:
            point = _survey_stop(rng, stop.heading_deg, cams, wide)
        else:
            point = _grid_stop(rng, per_stop, cams)
        for j in range(per_stop):
            cam_spec, az, el, hfov = point(j, index)
            vfov = hfov * cam_spec.height / cam_spec.width
            el = min(el, 0.5 * vfov - 1.5)  # keep some terrain at the bottom of every image
            model_type = "CAHVOR" if index % 2 == 0 else "CAHV"
            camera = build_camera(rng, cam_spec, rot, az, el, hfov, model_type)
            sclk = stop.sclk + 40 * j + int(rng.integers(0, 20))
            pid = _product_id(spec.name, cam_spec, stop, sclk, k, j, index, hfov,
                              int(rng.integers(0, 1000)))  # fmt: skip
            label = label_dir / f"{pid}{spec.label_suffix}"
            hfov_m, vfov_m = camera.fov_deg(cam_spec.width, cam_spec.height)
            az_c, el_c = centre_pointing_site(camera, cam_spec.width, cam_spec.height, rot)
            obs = Observation(
                label_path=label, mission=spec.name, product_id=pid,
                instrument=cam_spec.instrument, sol=stop.sol,
                rmc=MotionCounter(stop.site, stop.drive, None),
                width=cam_spec.width, height=cam_spec.height, camera=camera,
                rover_offset_m=np.asarray(stop.landing, dtype=np.float64).copy(),
                rover_quaternion=stop.quaternion.copy(),
                azimuth_deg=float(az_c), elevation_deg=float(el_c),
                hfov_deg=hfov_m, vfov_deg=vfov_m,
                start_time=_SCLK_EPOCH + timedelta(seconds=sclk),
                image_path=label.with_suffix(".jpg"),
            )  # fmt: skip
            shots.append(Shot(stop, index, obs, _pose(stop, spec.crs, sites[stop.site]), sclk))
            index += 1
    return shots


Pointing = Callable[[int, int], tuple[CameraSpec, float, float, float]]


def _grid_stop(rng: np.random.Generator, per_stop: int, cams: list[CameraSpec]) -> Pointing:
    """The small/default presets' pointing at one stop: the cameras in turn, azimuths spread
    round the circle, elevations in slots over -25..+5 degrees (SITE_FRAME), zoom uniform.
    Returns f(j, index) -> (camera, azimuth, elevation, hFOV) degrees for the stop's j-th
    image, the mission's index-th."""
    az0 = rng.uniform(0.0, 360.0)
    el_slots = rng.permutation(per_stop)

    def point(j: int, index: int) -> tuple[CameraSpec, float, float, float]:
        cam_spec = cams[index % len(cams)]
        if cam_spec.hfov_choices is None:
            hfov = float(rng.uniform(*cam_spec.hfov_range))
        else:
            hfov = float(cam_spec.hfov_choices[int(rng.integers(len(cam_spec.hfov_choices)))])
        az = (az0 + 360.0 * (j + rng.uniform(0.1, 0.9)) / per_stop) % 360.0
        el = -25.0 + 30.0 * (el_slots[j] + rng.uniform(0.1, 0.9)) / per_stop
        return cam_spec, az, el, hfov

    return point


#: What a stop's mast-camera frames do (the demo): a panorama row near the horizon, targeted
#: frames, or a look down at the ground near the rover; and how often.
STOP_KINDS = ("panorama", "targeted", "down")
STOP_KIND_WEIGHTS = (0.45, 0.4, 0.15)


def _survey_stop(rng: np.random.Generator, heading_deg: float, cams: list[CameraSpec],
                 wide: CameraSpec | None) -> Pointing:  # fmt: skip
    """The demo's pointing at one stop, after the real labels (Mastcam sol 1429: elevations
    3..15 degrees; sol 2663: a panorama sweeping azimuth 218..246 in 4.6 degree steps at
    elevations 5..0; Mastcam-Z sols 52/79: -2.9 and -37 degrees). The first image is the
    wide camera's (if any): azimuth within 90 degrees of the drive direction, elevation
    -25..-5. The mast frames (eyes in turn, Mastcam-Z zoom stops mostly wide) follow the
    stop's kind: a panorama (one row at elevation -8..0, azimuth stepping by 0.85 of the
    FOV), targeted frames (random azimuth, elevation ~ N(-4, 5) within -15..+5), or down
    (elevation -40..-20). Angles SITE_FRAME degrees (azimuth clockwise from north)."""
    kind = STOP_KINDS[int(rng.choice(len(STOP_KINDS), p=STOP_KIND_WEIGHTS))]
    az0 = float(rng.uniform(0.0, 360.0))
    pano_el = float(rng.uniform(-8.0, 0.0))
    pano_focal = (34, 48)[int(rng.integers(2))]
    first_mast = 0 if wide is None else 1

    def mast_hfov(cam_spec: CameraSpec, focal: float | None) -> float:
        if cam_spec.hfov_choices is not None:  # fixed-focus Mastcam eyes
            return float(cam_spec.hfov_choices[0])
        if focal is None:
            focal = ZOOM_STOPS_MM[int(rng.choice(len(ZOOM_STOPS_MM), p=ZOOM_STOP_WEIGHTS))]
        return zoom_hfov_deg(focal)

    def point(j: int, index: int) -> tuple[CameraSpec, float, float, float]:
        if wide is not None and j == 0:
            assert wide.hfov_choices is not None  # the wide camera has one fixed FOV
            az = heading_deg + float(rng.uniform(-90.0, 90.0))
            return wide, az % 360.0, float(rng.uniform(-25.0, -5.0)), wide.hfov_choices[0]
        cam_spec = cams[index % len(cams)]
        if kind == "panorama":
            hfov = mast_hfov(cam_spec, pano_focal)
            az = az0 + (j - first_mast) * 0.85 * hfov
            el = pano_el + float(rng.normal(0.0, 0.3))
        elif kind == "targeted":
            hfov = mast_hfov(cam_spec, None)
            az = float(rng.uniform(0.0, 360.0))
            el = float(np.clip(rng.normal(-4.0, 5.0), -15.0, 5.0))
        else:
            hfov = mast_hfov(cam_spec, (26, 34)[int(rng.integers(2))])
            az = float(rng.uniform(0.0, 360.0))
            el = float(rng.uniform(-40.0, -20.0))
        return cam_spec, az % 360.0, el, hfov

    return point


def _product_id(mission: str, cam: CameraSpec, stop: RoverState, sclk: int, k: int, j: int,
                index: int, hfov: float, msec: int) -> str:  # fmt: skip
    if mission == "m2020":
        if cam.instrument.startswith("NAVCAM"):
            return navcam_product_id(cam.eye, stop.sol, sclk, msec, stop.site, stop.drive,
                                     500 + k)  # fmt: skip
        return m2020_product_id(cam.eye, stop.sol, sclk, msec, stop.site, stop.drive,
                                5000 + 7 * k, zoom_focal_mm(hfov))  # fmt: skip
    return msl_product_id(cam.eye, stop.sol, 7000 + k, j + 1, 702000 + index)


def _write_label(obs: Observation) -> None:
    from mars_pairs.synth.labels import write_pds3_label, write_pds4_label

    if obs.mission == "m2020":
        write_pds4_label(obs, obs.label_path)
    else:
        write_pds3_label(obs, obs.label_path)


# -- truth ---------------------------------------------------------------------------------------
def _truth_table(shots: list[Shot], root: Path, crs: str) -> pa.Table:
    rows: dict[str, list[Any]] = {}

    def add(key: str, value: Any) -> None:
        rows.setdefault(key, []).append(value)

    for s in shots:
        o, st, cam = s.obs, s.stop, s.obs.camera
        roll, pitch, yaw = euler_zyx_deg(st.rotation)
        for key, value in (
            ("product_id", o.product_id), ("mission", o.mission), ("instrument", o.instrument),
            ("label_path", o.label_path.relative_to(root).as_posix()),
            ("image_path", o.image_path.relative_to(root).as_posix() if o.image_path else None),
            ("sol", o.sol), ("sclk", s.sclk), ("site", st.site), ("drive", st.drive),
            ("stop", st.stop), ("easting", st.x), ("northing", st.y), ("elevation", st.z),
            ("longitude", st.lon), ("latitude", st.lat),
            ("site_offset_ned", [float(v) for v in st.landing]),
            ("quaternion", [float(v) for v in st.quaternion]),
            ("heading_deg", yaw), ("roll_deg", roll), ("pitch_deg", pitch),
            ("camera_model_type", cam.model_type), ("camera_frame", cam.frame),
            ("camera_c", cam.c.tolist()), ("camera_a", cam.a.tolist()),
            ("camera_h", cam.h.tolist()), ("camera_v", cam.v.tolist()),
            ("camera_o", None if cam.o is None else cam.o.tolist()),
            ("camera_r", None if cam.r is None else cam.r.tolist()),
            ("width", o.width), ("height", o.height),
            ("azimuth_deg", o.azimuth_deg), ("elevation_deg", o.elevation_deg),
            ("hfov_deg", o.hfov_deg), ("vfov_deg", o.vfov_deg), ("crs", crs),
        ):  # fmt: skip
            add(key, value)
    vec = pa.list_(pa.float64())
    types = {k: vec for k in ("site_offset_ned", "quaternion", "camera_c", "camera_a",
                              "camera_h", "camera_v", "camera_o", "camera_r")}  # fmt: skip
    return pa.table({k: pa.array(v, type=types.get(k)) for k, v in rows.items()})


def _save_shot(shot: Shot, rgb: np.ndarray) -> None:
    """Write one image (JPEG) and its label."""
    assert shot.obs.image_path is not None
    # quality 95 without chroma subsampling: far terrain is foreshortened into 1-2 pixel
    # rows of fine texture, which quality 90 smears by up to tens of DN
    Image.fromarray(rgb).save(shot.obs.image_path, format="JPEG", quality=95, subsampling=0)
    _write_label(shot.obs)


Blocks = tuple[np.ndarray, np.ndarray]


def _window(
    grid: DemGrid, blocks: Blocks, ortho: np.ndarray, factor: int, centre_map: np.ndarray,
    half_m: float, classes: np.ndarray | None = None,
) -> tuple[DemGrid, Blocks, np.ndarray, np.ndarray | None]:  # fmt: skip
    """The DEM within about ``half_m`` metres east and north of ``centre_map`` (map x, y
    metres), cut on culling-block edges: a DemGrid with its own transform, its blocks'
    (``block_ranges``) z ranges (a slice of ``blocks``, the whole DEM's) and its ortho
    (``factor`` pixels per DEM cell), and the same window of ``classes`` (the ortho's grid)."""
    col, row = ~grid.transform * (float(centre_map[0]), float(centre_map[1]))
    half = half_m / grid.res
    rows, cols = grid.z.shape
    bi0, bj0 = max(0, int(row - half) // BLOCK), max(0, int(col - half) // BLOCK)
    i0, j0 = bi0 * BLOCK, bj0 * BLOCK
    i1 = min(rows, (int(row + half) // BLOCK + 1) * BLOCK + 1)
    j1 = min(cols, (int(col + half) // BLOCK + 1) * BLOCK + 1)
    nbi, nbj = -(-(i1 - i0 - 1) // BLOCK), -(-(j1 - j0 - 1) // BLOCK)
    z = np.ascontiguousarray(grid.z[i0:i1, j0:j1])
    sub = DemGrid(z, grid.transform * Affine.translation(j0, i0))
    lo, hi = (np.ascontiguousarray(b[bi0 : bi0 + nbi, bj0 : bj0 + nbj]) for b in blocks)
    cut = (slice(i0 * factor, i1 * factor), slice(j0 * factor, j1 * factor))
    return sub, (lo, hi), ortho[cut], None if classes is None else classes[cut]


def _traverse(rng: np.random.Generator, spec: MissionSpec, preset: SizeSpec, stops: int,
              filled: np.ndarray, dem_tr: Affine) -> Traverse:  # fmt: skip
    """The traverse of ``stops`` stops over the DEM (``filled``: float64, nodata filled,
    ``fill_nodata``; map CRS, 1 m cells), inside the preset's margin."""
    sampler = DemSampler(filled, dem_tr)
    n = preset.dem_cells
    margin = 0.25 * n * DEM_RES_M if preset.margin_m is None else preset.margin_m
    left, top = dem_tr.c, dem_tr.f
    inner = (left + margin, top - n * DEM_RES_M + margin, left + n * DEM_RES_M - margin,
             top - margin)  # fmt: skip
    return make_traverse(rng, sampler, spec.crs, inner, stops, spec.first_site,
                         spec.first_sol, spec.sclk_sol0, spacing_m=preset.stop_spacing_m,
                         directed=preset.directed)  # fmt: skip


def mission_traverse(seed: int, mission: str, size: str, stops: int | None = None) -> Traverse:
    """The traverse ``generate_mission`` makes for one mission ("m2020" or "msl") with these
    arguments, without writing or rendering anything (the terrain is generated: the traverse
    follows it). Map CRS metres."""
    preset = SIZES[size]
    rng = np.random.default_rng([int(seed), MISSIONS.index(mission)])
    _, dem_tr, _, _, _, filled = _terrain(rng, SPECS[mission], preset)
    k = preset.stops if stops is None else int(stops)
    return _traverse(rng, SPECS[mission], preset, k, filled, dem_tr)


# -- rendering ----------------------------------------------------------------------------------
class Scene:
    """What every image of a mission is rendered from: the DEM (``dem32``: float32, NaN
    nodata; map CRS, transform ``dem_tr``), its ortho (``factor`` pixels per DEM cell), the
    true classes on the ortho's grid (or None), the render window (``SizeSpec``) and the
    folder of the AI4Mars-layout truth. Pickled as its inputs (a render worker's copy)."""

    def __init__(self, dem32: np.ndarray, dem_tr: Affine, ortho: np.ndarray,
                 classes: np.ndarray | None, factor: int, window_m: float | None,
                 ai4mars_dir: Path) -> None:  # fmt: skip
        self._args = (dem32, dem_tr, ortho, classes, factor, window_m, ai4mars_dir)
        self.ortho, self.classes, self.factor = ortho, classes, factor
        self.window_m, self.ai4mars_dir = window_m, ai4mars_dir

    # made on the first render: the process that only hands the scene to render workers
    # never spends their ~0.5 s
    @cached_property
    def grid(self) -> DemGrid:
        """The DEM as float64 (``DemGrid``: the renderer's)."""
        dem32, dem_tr = self._args[0], self._args[1]
        return DemGrid(dem32.astype(np.float64), dem_tr)

    @cached_property
    def blocks(self) -> Blocks:
        """The DEM's culling blocks' z ranges (``block_ranges``)."""
        return block_ranges(self.grid.z)

    def __reduce__(self) -> tuple[type[Scene], tuple[Any, ...]]:
        return Scene, self._args

    def render(self, mc: MapCamera) -> tuple[np.ndarray, TruthMasks | None]:
        """``mc``'s image (height, width, 3 uint8) and, with classes, its truth masks."""
        g, b, o, c = self.grid, self.blocks, self.ortho, self.classes
        if self.window_m is not None:
            g, b, o, c = _window(g, b, o, self.factor, mc.origin_map, self.window_m, c)
        if c is None:
            return render_view(mc, g, b, o, self.factor)[0], None
        rgb, zbuf, hc, hr = render_view_hits(mc, g, b, o, self.factor)
        return rgb, truth_masks(hc, hr, zbuf, c, self.factor)

    def save(self, shot: Shot, rgb: np.ndarray, masks: TruthMasks | None) -> None:
        """Write ``shot``'s image, label and (with masks) AI4Mars-layout truth."""
        _save_shot(shot, rgb)
        if masks is not None:
            write_ai4mars_truth(self.ai4mars_dir, shot.obs.mission, shot.obs.product_id, masks,
                                shot.obs.instrument)  # fmt: skip


def _render_all(scene: Scene, shots: list[Shot], cams: list[MapCamera],
                workers: int) -> Iterator[None]:  # fmt: skip
    """Render and write every shot (``cams[i]`` is ``shots[i]``'s camera); yields once per
    image, in order. ``workers`` 1: in this process, ``RENDER_THREADS`` threads rendering
    (the numba kernels release the GIL) and this one writing; more: that many processes,
    each rendering and writing its images, forked from the build's fork server (never from
    this process, which may run numba's OpenMP threads)."""
    if workers <= 1:
        with ThreadPoolExecutor(max_workers=RENDER_THREADS) as threads:
            for shot, (rgb, masks) in zip(shots, threads.map(scene.render, cams), strict=True):
                scene.save(shot, rgb, masks)
                yield
        return
    import mars_pairs.runtime as runtime
    from mars_pairs.pipeline.builder.local_pool import started_context

    ctx = started_context(preload=[__name__])
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_start_render_worker,
                             initargs=(scene, runtime.build_settings())) as pool:  # fmt: skip
        futures = [pool.submit(_render_one, shot, mc) for shot, mc in zip(shots, cams, strict=True)]
        try:
            for shot, future in zip(shots, futures, strict=True):
                try:
                    future.result()
                except BrokenProcessPool:
                    raise WorkerDiedError(
                        f"a render worker process died (killed, out of memory or crashed) "
                        f"while {shot.obs.image_path} or an image near it was in flight"
                    ) from None
                yield
        except BaseException:
            for future in futures:
                future.cancel()
            raise


_WORKER_SCENE: list[Scene] = []  # a render worker's scene (set once, when it starts)


def _start_render_worker(scene: Scene, settings: dict[str, str]) -> None:
    from mars_pairs.pipeline.builder.local_pool import start_worker_process

    start_worker_process(settings)
    _WORKER_SCENE.append(scene)


def _render_one(shot: Shot, mc: MapCamera) -> None:
    scene = _WORKER_SCENE[0]
    scene.save(shot, *scene.render(mc))


# -- one mission ---------------------------------------------------------------------------------
def _generate_one(out: Path, rng: np.random.Generator, spec: MissionSpec, size: str,
                  stops: int, per_stop: int, log: Callable[[str], None] | None = None,
                  terrain_labels: bool = False, workers: int = 1) -> dict[str, Any]:  # fmt: skip
    preset = SIZES[size]
    say = log or (lambda _line: None)
    t0 = time.perf_counter()
    n = preset.dem_cells
    say(f"{spec.name}: terrain: {n} x {n} m DEM at {DEM_RES_M:g} m, ortho at "
        f"{DEM_RES_M / preset.ortho_factor:g} m ...")  # fmt: skip
    if workers > 1:  # the render workers' fork server imports its modules beside the terrain
        from mars_pairs.pipeline.builder.local_pool import started_context

        started_context(preload=[__name__])
    dem32, dem_tr, ortho, ortho_tr, boulders, filled = _terrain(rng, spec, preset)
    # the rasters are written on a thread of their own (GDAL compresses without the GIL) while
    # the traverse is drawn and the images rendered; every write is done before this returns
    with ThreadPoolExecutor(1) as writer:
        dem_path, ortho_path = out / "orbital" / "dem.tif", out / "orbital" / "ortho.tif"
        writes = [
            writer.submit(_write_geotiff, dem_path,
                          np.where(np.isfinite(dem32), dem32, np.float32(DEM_NODATA)), dem_tr,
                          spec.crs, DEM_NODATA, predictor=3),
            writer.submit(_write_geotiff, ortho_path, ortho, ortho_tr, spec.crs, 0, predictor=2),
        ]  # fmt: skip
        classes = None
        if terrain_labels:
            classes = terrain_classes(dem32.astype(np.float64), DEM_RES_M, preset.ortho_factor,
                                      boulders)  # fmt: skip
            writes.append(writer.submit(_write_geotiff, out / "orbital" / CLASSES_NAME, classes,
                                        ortho_tr, spec.crs, 255, predictor=1))  # fmt: skip

        trav = _traverse(rng, spec, preset, stops, filled, dem_tr)
        places_path = out / "places" / spec.places_name
        write_places_csv(places_path, trav, dem_tr, ortho_tr)
        xy = np.array([(r.x, r.y) for r in trav.rovers])
        length_km = float(np.hypot(*np.diff(xy, axis=0).T).sum()) / 1000.0
        say(f"{spec.name}: traverse: {len(trav.stops)} stops, {len(trav.sites)} sites, "
            f"{length_km:.1f} km ({time.perf_counter() - t0:.1f} s)")  # fmt: skip

        label_dir = out / "labels"
        label_dir.mkdir(parents=True, exist_ok=True)
        shots = _plan_shots(rng, spec, size, trav, per_stop, label_dir)
        # cameras are placed here (pyproj is not thread-safe); each image's files are its own,
        # so their bytes do not depend on the order, the threads or the processes rendering them
        cams = [MapCamera.from_observation(s.obs, s.pose, spec.crs) for s in shots]
        scene = Scene(dem32, dem_tr, ortho, classes, preset.ortho_factor, preset.render_window_m,
                      out / AI4MARS_DIR)  # fmt: skip
        # the bar opens after the first image: that one's time is mostly the renderer's compile
        # (numba, first run), and a rate measured on it gives an ETA of hours
        t_render = time.perf_counter()
        bar = None
        try:
            for _ in _render_all(scene, shots, cams, workers):
                if bar is None:
                    first = time.perf_counter() - t_render
                    say(f"{spec.name}: first image rendered ({first:.1f} s)")
                    bar = render_bar(len(shots), spec.name, disable=log is None)
                else:
                    bar.update()
        finally:
            if bar is not None:
                bar.close()
        truth_path = out / "truth.parquet"
        pq.write_table(_truth_table(shots, out, spec.crs), truth_path, compression="zstd")
        for write in writes:
            write.result()  # (a failed write raises here)
        return {
            "dir": str(out),
            "dem": str(dem_path),
            "ortho": str(ortho_path),
            "places": str(places_path),
            "truth": str(truth_path),
            "labels": [str(s.obs.label_path) for s in shots],
            "image_files": [str(s.obs.image_path) for s in shots],
            "stops": len(trav.stops),
            "sites": len(trav.sites),
            "places_rows": len(trav.sites) + len(trav.rovers),
            "images": len(shots),
            **(
                {
                    "terrain_classes": str(out / "orbital" / CLASSES_NAME),
                    "ai4mars": str(out / AI4MARS_DIR),
                }
                if terrain_labels
                else {}
            ),
        }
