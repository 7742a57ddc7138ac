"""Geometry checks on every real label: the camera model against the label's own numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mars_pairs.geometry.locate import model_pointing_deg
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Places
from mars_pairs.pds import read_observation
from support.real_samples import sample_labels

LABELS = sample_labels()
needs_samples = pytest.mark.skipif(not LABELS, reason="../shared/pds-samples is absent")


@needs_samples
@pytest.mark.parametrize("label", LABELS, ids=[p.name for p in LABELS])
def test_model_fov_matches_the_label_within_one_percent(label: Path) -> None:
    obs = read_observation(label)
    assert obs.hfov_deg is not None and obs.vfov_deg is not None
    hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
    assert hfov == pytest.approx(obs.hfov_deg, rel=0.01)
    assert vfov == pytest.approx(obs.vfov_deg, rel=0.01)


@needs_samples
@pytest.mark.parametrize("label", LABELS, ids=[p.name for p in LABELS])
def test_model_pointing_matches_the_label_derived_azimuth_elevation(label: Path) -> None:
    """The label's SITE_FRAME azimuth/elevation from the model + label quaternion.

    Perseverance labels give the image-centre ray, Curiosity labels the camera axis A; each
    matches to 0.2 degree (the 2663ML subframe's centre pixel is 0.51 degree off its axis).
    """
    obs = read_observation(label)
    assert obs.azimuth_deg is not None and obs.elevation_deg is not None
    pointing = model_pointing_deg(obs)
    assert pointing is not None
    az, el = pointing
    daz = (az - obs.azimuth_deg + 180.0) % 360.0 - 180.0
    assert abs(daz) < 0.2, (az, obs.azimuth_deg)
    assert abs(el - obs.elevation_deg) < 0.2, (el, obs.elevation_deg)
    # and the image-centre ray is within about half a degree in every product
    centre = model_pointing_deg(obs, convention="centre")
    assert centre is not None
    assert abs((centre[0] - obs.azimuth_deg + 180.0) % 360.0 - 180.0) < 0.55
    assert abs(centre[1] - obs.elevation_deg) < 0.55


@needs_samples
def test_m2020_camera_on_the_map(samples_dir: Path) -> None:
    label = samples_dir / "m2020" / "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
    obs = read_observation(label)
    pose = Places.from_csv(samples_dir / "m2020" / "best_interp.csv").locate(obs)
    cam = MapCamera.from_observation(obs, pose)
    centre = cam.center_map
    # the mast camera stands about 1.98 m above the rover origin, within a metre of it in plan
    assert centre[2] - pose.elevation_m == pytest.approx(1.98, abs=0.05)
    assert np.hypot(centre[0] - pose.easting, centre[1] - pose.northing) < 1.5
    # a point 100 m down the centre ray projects back onto the centre pixel
    mid = np.array([[(obs.width - 1) / 2, (obs.height - 1) / 2]])
    origins, dirs = cam.pixel_rays(mid)
    np.testing.assert_allclose(cam.project_map(origins + 100.0 * dirs), mid, atol=1e-6)
    az, _el = cam.pointing_az_el()
    assert (az - obs.azimuth_deg + 180) % 360 - 180 == pytest.approx(0.0, abs=0.6)
