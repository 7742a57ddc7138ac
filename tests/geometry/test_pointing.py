"""Pointing that means what it says: the manifest's azimuth/elevation is the ray through the
image centre (SITE_FRAME, from the camera model), the label's own pointing kept beside it.

Measured on the real labels in ../shared/pds-samples: a full-frame Mastcam-Z label's SITE_FRAME
``instrument_azimuth``/``_elevation`` is the ray through the sensor centre (to 0.003 deg); a
Curiosity Mastcam label's ``FIXED_INSTRUMENT_AZIMUTH``/``_ELEVATION`` is the camera axis A
(to 0.002 deg), 0.04 deg from the image centre of the 1344 x 1200 frames of sol 1429. For a
subframe the label keeps the camera's pointing: a 1280 x 720 subframe at (1, 1) of the
1648 x 1200 sensor looks 1.16 deg off it at 110 mm, 2.7 deg at 48 mm.
The expected angles here come from the CAHV vectors with numpy, not the package's functions.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from mars_pairs.geometry.attitude import image_centre_pointing_deg
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import Observation
from mars_pairs.pds import read_observation
from support.configs import build_config

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s

SENSOR = (1648, 1200)  # Mastcam-Z detector samples x lines


def _ned(az_deg: float, el_deg: float) -> np.ndarray:
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])


def _between_deg(u: np.ndarray, v: np.ndarray) -> float:
    cos = float(u @ v) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def _cahv_ray(cam: CameraModel, x: float, y: float) -> np.ndarray:
    """The CAHV ray through pixel (x, y): (V - yA) x (H - xA), towards +A (no distortion)."""
    u = np.cross(cam.v - y * cam.a, cam.h - x * cam.a)
    return u if u @ cam.a > 0 else -u


def _label_angle_deg(obs: Observation, camera: CameraModel, width: int, height: int) -> float:
    """Angle between the package's image-centre pointing and the label's pointing."""
    az, el = image_centre_pointing_deg(camera, width, height, obs.rover_quaternion)
    return _between_deg(_ned(az, el), _ned(obs.azimuth_deg, obs.elevation_deg))


def _subframe(cam: CameraModel, first_sample: int, first_line: int) -> CameraModel:
    """The model of a subframe starting at 1-based (first_sample, first_line) of the sensor:
    pixel x' = x - (first_sample - 1), so H' = H - x0 A, V' = V - y0 A."""
    x0, y0 = first_sample - 1, first_line - 1
    return replace(cam, h=cam.h - x0 * cam.a, v=cam.v - y0 * cam.a)


def _zoomed_cahv(cam: CameraModel, factor: float) -> CameraModel:
    """The same camera as a CAHV model with its focal length (pixels) times ``factor``."""
    hc, vc = float(cam.h @ cam.a), float(cam.v @ cam.a)
    h = hc * cam.a + factor * (cam.h - hc * cam.a)
    v = vc * cam.a + factor * (cam.v - vc * cam.a)
    return CameraModel("CAHV", cam.c, cam.a, h, v)


def _m2020(samples_dir: Path) -> list[Observation]:
    obs = [read_observation(p) for p in sorted((samples_dir / "m2020").glob("Z*.xml"))]
    assert len(obs) == 2 and all((o.width, o.height) == SENSOR for o in obs)
    return obs


def test_full_frame_mastcam_z_label_pointing_is_the_image_centre(samples_dir: Path) -> None:
    for obs in _m2020(samples_dir):
        assert _label_angle_deg(obs, obs.camera, obs.width, obs.height) < 0.01


def test_curiosity_label_pointing_is_the_camera_axis(samples_dir: Path) -> None:
    labels = sorted((samples_dir / "msl").glob("1429MR*.LBL"))
    assert len(labels) == 4
    for label in labels:
        obs = read_observation(label)
        cam = obs.camera
        q = obs.rover_quaternion
        s, x, y, z = np.asarray(q) / np.linalg.norm(q)
        rot = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
            [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
            [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)],
        ])  # fmt: skip
        label_dir = _ned(obs.azimuth_deg, obs.elevation_deg)
        assert _between_deg(rot @ cam.a, label_dir) < 0.01
        centre = _cahv_ray(cam, (obs.width - 1) / 2, (obs.height - 1) / 2)
        expected = _between_deg(centre, cam.a)
        assert 0.02 < expected < 0.1
        assert _label_angle_deg(obs, cam, obs.width, obs.height) == pytest.approx(
            expected, abs=0.005
        )


@pytest.mark.parametrize(("focal_factor", "low", "high"), [(1.0, 1.0, 1.3), (48 / 110, 2.4, 3.0)])
def test_a_subframe_centre_is_off_the_label_pointing(
    samples_dir: Path, focal_factor: float, low: float, high: float
) -> None:
    """1280 x 720 at (1, 1): the label's pointing is the sensor centre's; the manifest's is
    the subframe's own centre, the expected angle away (at 110 mm: the real models; at 48 mm:
    the same cameras zoomed out)."""
    for obs in _m2020(samples_dir):
        full = obs.camera if focal_factor == 1.0 else _zoomed_cahv(obs.camera, focal_factor)
        sub = _subframe(full, 1, 1)
        expected = _between_deg(
            _cahv_ray(full, (SENSOR[0] - 1) / 2, (SENSOR[1] - 1) / 2),
            _cahv_ray(full, (1280 - 1) / 2, (720 - 1) / 2),
        )
        assert low < expected < high
        # the label describes the full sensor's centre ray: equal to this model's (< 0.01 deg)
        # when the focal length is the label's own
        az, el = image_centre_pointing_deg(full, *SENSOR, obs.rover_quaternion)
        sensor_dir = _ned(az, el)
        az, el = image_centre_pointing_deg(sub, 1280, 720, obs.rover_quaternion)
        assert _between_deg(_ned(az, el), sensor_dir) == pytest.approx(expected, abs=0.01)
        if focal_factor == 1.0:
            assert _label_angle_deg(obs, sub, 1280, 720) == pytest.approx(expected, abs=0.01)
            # a subframe centred on the sensor looks where the label says
            centred = _subframe(full, 1 + (SENSOR[0] - 1280) // 2, 1 + (SENSOR[1] - 720) // 2)
            assert _label_angle_deg(obs, centred, 1280, 720) < 0.01


# -- the manifest ---------------------------------------------------------------------------------
def test_manifest_pointing_is_the_centre_ray_and_keeps_the_labels(
    small_mission: Path, tmp_path: Path
) -> None:
    """A label whose SITE_FRAME pointing is 20 degrees off its camera: the manifest's
    azimuth is still the image centre's (the mission's truth), the label's value beside it."""
    from mars_pairs.pipeline.builder.run import run_build

    labels = tmp_path / "labels"
    shutil.copytree(small_mission / "labels", labels)
    edited = sorted(labels.glob("*.xml"))[0]
    obs = read_observation(edited)
    text = edited.read_text()
    old = f">{obs.azimuth_deg!r}</geom:instrument_azimuth>"
    assert text.count(old) == 1, "the SITE_FRAME azimuth is written once"
    edited.write_text(text.replace(old, f">{(obs.azimuth_deg + 20.0) % 360.0!r}</geom:"
                                   "instrument_azimuth>"))  # fmt: skip
    assert read_observation(edited).azimuth_deg == pytest.approx((obs.azimuth_deg + 20) % 360)
    config = build_config(small_mission, tmp_path / "ds", base=tmp_path, labels=labels / "*.xml")
    assert run_build(config, workers=1, progress=False).failures == 0
    rows = pq.read_table(tmp_path / "ds" / "manifest.parquet").to_pylist()
    truth = {t["product_id"]: t for t in pq.read_table(small_mission / "truth.parquet").to_pylist()}
    assert len(rows) == 4
    for row in rows:
        t = truth[row["product_id"]]
        got = _ned(row["azimuth_deg"], row["elevation_deg"])
        want = _ned(t["azimuth_deg"], t["elevation_deg"])  # the synthetic camera's centre ray
        assert _between_deg(got, want) < 0.01
        shift = 20.0 if row["product_id"] == obs.product_id else 0.0
        assert row["label_azimuth_deg"] == pytest.approx((t["azimuth_deg"] + shift) % 360.0)
        assert row["label_elevation_deg"] == pytest.approx(t["elevation_deg"])
        # the synthetic table has one row per (site, drive) (pose -1), the labels no pose
        assert (row["places_pose"], row["places_match"]) == (-1, "site-drive")
