"""Synthetic Mastcam labels at the real sol-1051 pose of ``../shared/real-gale`` (site 48, drive
2470), their images rendered from the real ortho over the real DEM; the DEM and PLACES rows read
for the real-Gale build tests. Map frame: the real-gale rasters' CRS (metres)."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np
import rasterio
from PIL import Image
from rasterio.warp import Resampling, reproject

from mars_pairs.geometry.frames import MSL_PLACES_CRS, quaternion_to_matrix
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Places
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.synth.cameras import build_camera, centre_pointing_site, mission_cameras
from mars_pairs.synth.labels import write_pds3_label
from mars_pairs.synth.render import DemGrid, block_ranges, render_view
from support.real_samples import SHARED

GALE = SHARED / "real-gale"
SITE, DRIVE, SOL = 48, 2470, 1051


def gale_row(places_csv: Path, site: int, drive: int) -> dict[str, float]:
    """The ROVER row of ``places_csv`` at (site, drive)."""
    import pyarrow.csv as pacsv

    t = pacsv.read_csv(places_csv).to_pylist()
    return next(r for r in t if r["frame"] == "ROVER" and r["site"] == site and r["drive"] == drive)


def read_dem(path: Path) -> tuple[np.ndarray, rasterio.Affine]:
    """The DEM (float64 metres, nodata as NaN) and its transform (map CRS of the file)."""
    with rasterio.open(path) as ds:
        z = ds.read(1).astype(np.float64)
        z[z == ds.nodata] = np.nan
        return z, ds.transform


def ortho_on_dem_grid(path: Path, dem_shape, dem_tr, factor: int) -> np.ndarray:
    """The ortho's first band resampled onto the DEM grid at ``factor`` pixels per cell."""
    out = np.zeros((dem_shape[0] * factor, dem_shape[1] * factor), np.uint8)
    tr = dem_tr * rasterio.Affine.scale(1.0 / factor)
    with rasterio.open(path) as ds:
        reproject(rasterio.band(ds, 1), out, dst_transform=tr, dst_crs=ds.crs,
                  resampling=Resampling.bilinear, dst_nodata=0)  # fmt: skip
    return out


def make_gale_labels(gale: Path, out: Path) -> list[Path]:
    """Four synthetic Mastcam views from the real sol-1051 pose, rendered over the real map."""
    places = Places.from_csv(gale / "rover_positions.csv")
    row = gale_row(gale / "rover_positions.csv", SITE, DRIVE)
    q = np.array([row["quat_s"], row["quat_v1"], row["quat_v2"], row["quat_v3"]])
    rot = quaternion_to_matrix(q)
    z, tr = read_dem(gale / "dem.tif")
    grid, blocks = DemGrid(z, tr), block_ranges(z)
    ortho = ortho_on_dem_grid(gale / "ortho.tif", z.shape, tr, 2)
    rng = np.random.default_rng(1051)
    labels = []
    for j, (az, el) in enumerate(((20.0, -9.0), (110.0, -10.0), (200.0, -8.0), (290.0, -11.0))):
        spec = mission_cameras("msl", "small")[j % 2]
        hfov = spec.hfov_choices[0] if j % 2 == 0 else 15.0
        camera = build_camera(rng, spec, rot, az, el, hfov, "CAHVOR" if j % 2 else "CAHV")
        pid = f"{SOL:04d}M{spec.eye}{48000 + j:06d}{j + 1:03d}{702000 + j:07d}E01_DRCL"
        label = out / f"{pid}.LBL"
        hfov_m, vfov_m = camera.fov_deg(spec.width, spec.height)
        az_c, el_c = centre_pointing_site(camera, spec.width, spec.height, rot)
        obs = Observation(
            label_path=label, mission="msl", product_id=pid, instrument=spec.instrument,
            sol=SOL, rmc=MotionCounter(SITE, DRIVE, None), width=spec.width,
            height=spec.height, camera=camera, rover_offset_m=np.zeros(3),
            rover_quaternion=q, azimuth_deg=float(az_c), elevation_deg=float(el_c),
            hfov_deg=hfov_m, vfov_deg=vfov_m, start_time=datetime(2015, 7, 21, 12, j),
            image_path=label.with_suffix(".jpg"),
        )  # fmt: skip
        pose = places.locate(obs)
        assert pose.source == "places"
        rgb = render_view(MapCamera.from_observation(obs, pose, MSL_PLACES_CRS), grid, blocks,
                          ortho, 2)[0]  # fmt: skip
        Image.fromarray(rgb).save(obs.image_path, quality=95)
        write_pds3_label(obs, label)
        labels.append(label)
    return labels
