"""Synthetic mast cameras (Mastcam-Z, Mastcam) as CAHV / CAHVOR models, and product ids.

Frames and units: models are built in ROVER_NAV_FRAME (x forward, y right, z down, metres);
H and V are in pixels of the product's grid (first pixel centre at (0, 0)). Pointing is given
in SITE_FRAME (azimuth clockwise from north, elevation up, degrees) and turned into a mast
pan/tilt in the rover frame, so the image is rolled with the rover as on the real mast.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.frames import azimuth_elevation_deg, direction_from_az_el

F64 = NDArray[np.float64]

#: Mast head pivot in ROVER_NAV_FRAME (metres); the camera centres sit ~1.97 m up.
MAST_PIVOT = np.array([0.78, 0.46, -1.90])


@dataclass(frozen=True)
class CameraSpec:
    """One mast camera: eye (L/R), stereo offset in the head frame, image size, FOV rules."""

    instrument: str
    eye: str  # "L" or "R"
    width: int
    height: int
    hfov_choices: tuple[float, ...] | None  # fixed FOVs (Mastcam); None = zoom range
    hfov_range: tuple[float, float] = (8.0, 20.0)
    radial_r1: tuple[float, float] = (0.0, 0.45)


#: Mastcam-Z zoom stops (mm) and how often a demo image uses them: mostly the wide end,
#: as the mission's panoramas and context images are (26 mm ~ 25.6 deg, 63 mm ~ 10.7 deg).
ZOOM_STOPS_MM = (26, 34, 48, 63)
ZOOM_STOP_WEIGHTS = (0.3, 0.35, 0.2, 0.15)
#: The demo's Navcam-like wide camera: hFOV (degrees), square image side (pixels).
NAVCAM_HFOV_DEG = 45.0
NAVCAM_SIDE_PX = 384


def mission_cameras(mission: str, size: str) -> list[CameraSpec]:
    """The mast cameras used for a mission ("m2020" or "msl") at a size ("small", "default"
    or "demo": quarter-size images; the wide camera is ``wide_camera``)."""
    big = size == "default"
    demo = size == "demo"
    if mission == "m2020":
        w, h = (1648, 1200) if big else (384, 280) if demo else (824, 600)
        return [
            CameraSpec("MCZ_LEFT", "L", w, h, None),
            CameraSpec("MCZ_RIGHT", "R", w, h, None),
        ]
    if demo:
        return [
            CameraSpec("MAST_LEFT", "L", 336, 300, (15.0,), radial_r1=(-0.14, -0.10)),
            CameraSpec("MAST_RIGHT", "R", 336, 300, (5.8,), radial_r1=(-0.01, 0.01)),
        ]
    w, h = (1344, 1200) if big else (672, 600)
    return [
        CameraSpec("MAST_LEFT", "L", w, h, (15.0,), radial_r1=(-0.14, -0.10)),
        CameraSpec("MAST_RIGHT", "R", w, h, (5.8,), radial_r1=(-0.01, 0.01)),
    ]


def wide_camera(mission: str, size: str) -> CameraSpec | None:
    """The Navcam-like wide camera beside the mast cameras (m2020 "demo" only, else None):
    45 degrees, 384 x 384, small radial distortion (an MSL-Navcam-like FOV on the M2020 mast;
    the real M2020 Navcam is 90 x 70 degrees)."""
    if mission != "m2020" or size != "demo":
        return None
    side = NAVCAM_SIDE_PX
    return CameraSpec("NAVCAM_LEFT", "L", side, side, (NAVCAM_HFOV_DEG,), radial_r1=(-0.02, 0.02))


def zoom_hfov_deg(focal_mm: float) -> float:
    """Mastcam-Z horizontal FOV (degrees) at a focal length (mm); inverse of zoom_focal_mm."""
    return 2.0 * math.degrees(math.atan(110.0 * math.tan(math.radians(3.1)) / focal_mm))


def _pan_tilt_basis(direction_rover: F64) -> F64:
    """Columns: camera axis, image-right and image-down unit vectors (rover frame)."""
    a = direction_rover / np.linalg.norm(direction_rover)
    pan = math.atan2(a[1], a[0])
    right = np.array([-math.sin(pan), math.cos(pan), 0.0])
    down = np.cross(a, right)
    return np.stack([a, right, down], axis=1)


def build_camera(
    rng: np.random.Generator,
    spec: CameraSpec,
    rover_to_site: F64,
    azimuth_deg: float,
    elevation_deg: float,
    hfov_deg: float,
    model_type: str,
) -> CameraModel:
    """A camera in ROVER_NAV_FRAME pointing at SITE_FRAME (azimuth, elevation), hFOV ~ given.

    ``rover_to_site``: 3 x 3 rotation ROVER_NAV_FRAME -> SITE_FRAME (the rover quaternion).
    CAHVOR models get a slightly tilted optical axis O and small radial terms R.
    """
    d_site = direction_from_az_el(azimuth_deg, elevation_deg)
    basis = _pan_tilt_basis(rover_to_site.T @ d_site)
    a, right, down = basis[:, 0], basis[:, 1], basis[:, 2]
    side = -1.0 if spec.eye == "L" else 1.0
    c = MAST_PIVOT + basis @ np.array([0.06, side * 0.12, -0.07])
    hs = 0.5 * spec.width / math.tan(math.radians(hfov_deg) / 2.0)
    vs = hs * rng.uniform(0.999, 1.001)
    hc = (spec.width - 1) / 2.0 + rng.uniform(-4.0, 4.0)
    vc = (spec.height - 1) / 2.0 + rng.uniform(-4.0, 4.0)
    h = hs * right + hc * a
    v = vs * down + vc * a
    if model_type == "CAHV":
        return CameraModel("CAHV", c, a, h, v)
    tilt = rng.normal(0.0, 0.002, 2)
    o = a + tilt[0] * right + tilt[1] * down
    o /= np.linalg.norm(o)
    r = np.array([rng.uniform(-2e-4, 2e-4), rng.uniform(*spec.radial_r1), rng.uniform(-0.05, 0.05)])
    return CameraModel("CAHVOR", c, a, h, v, o, r)


def centre_pointing_site(camera: CameraModel, width: int, height: int, rover_to_site: F64) -> F64:
    """(azimuth, elevation) degrees, SITE_FRAME, of the ray through the image centre."""
    _, ray = camera.unproject(np.array([[(width - 1) / 2.0, (height - 1) / 2.0]]))
    az, el = azimuth_elevation_deg(rover_to_site @ ray[0])
    return np.array([float(az), float(el)])


def m2020_product_id(eye: str, sol: int, sclk: int, msec: int, site: int, drive: int,
                     seq: int, focal_mm: int) -> str:  # fmt: skip
    """Mastcam-Z RAD product id, e.g. ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01."""
    return (
        f"Z{eye}F_{sol:04d}_{sclk:010d}_{msec:03d}RAD_N{site:03d}{drive:04d}"
        f"ZCAM{seq:05d}_{focal_mm:03d}085J01"
    )


def navcam_product_id(eye: str, sol: int, sclk: int, msec: int, site: int, drive: int,
                      seq: int) -> str:  # fmt: skip
    """Navcam RAD product id in the Mars 2020 grammar, the camera fields as in a real full
    frame (NLF_0100_0673158398_650ECM_N0060000NCAM00900_01_295J01, mars.nasa.gov raw images):
    e.g. NLF_0052_0671559321_081RAD_N0031950NCAM00500_01_295J01."""
    return (
        f"N{eye}F_{sol:04d}_{sclk:010d}_{msec:03d}RAD_N{site:03d}{drive:04d}NCAM{seq:05d}_01_295J01"
    )


def msl_product_id(eye: str, sol: int, seq: int, cmd: int, image_id: int) -> str:
    """Mastcam DRCL product id, e.g. 1429MR0070670010702567E01_DRCL."""
    return f"{sol:04d}M{eye}{seq:06d}{cmd:03d}{image_id:07d}E01_DRCL"


def zoom_focal_mm(hfov_deg: float) -> int:
    """Mastcam-Z focal length (mm) for a horizontal FOV: 110 mm ~ 6.2 deg, 26 mm ~ 25.6 deg."""
    return round(110.0 * math.tan(math.radians(3.1)) / math.tan(math.radians(hfov_deg / 2)))
