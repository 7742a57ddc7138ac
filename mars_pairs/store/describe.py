"""The ``locate`` command's output: a plain-value summary of an observation and its pose."""

from __future__ import annotations

from typing import Any

from mars_pairs.geometry.attitude import image_centre_pointing_deg
from mars_pairs.geometry.locate import model_pointing_deg
from mars_pairs.geometry.places import Pose
from mars_pairs.observation import Observation


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None else round(float(value), digits)


def describe(obs: Observation, pose: Pose | None = None) -> dict[str, Any]:
    """A JSON-ready summary of an observation (and its pose, when located), with the manifest's
    names: ``azimuth_deg``/``elevation_deg`` the ray through the image centre (SITE_FRAME,
    degrees; attitude from the pose, else the label), ``label_azimuth_deg``/
    ``label_elevation_deg`` the label's derived pointing, ``model_azimuth_deg``/
    ``model_elevation_deg`` the model's ray for the label's convention (``model_pointing_deg``).
    """
    hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
    q = pose.quaternion if pose is not None and pose.quaternion is not None else None
    q = obs.rover_quaternion if q is None else q
    pointing = model_pointing_deg(obs, q)
    centre = None if q is None else image_centre_pointing_deg(obs.camera, obs.width, obs.height, q)
    out: dict[str, Any] = {
        "product_id": obs.product_id,
        "mission": obs.mission,
        "instrument": obs.instrument,
        "sol": obs.sol,
        "site": obs.rmc.site,
        "drive": obs.rmc.drive,
        "pose": obs.rmc.pose,
        "time": obs.start_time.isoformat() if obs.start_time else None,
        "azimuth_deg": _round(centre[0], 4) if centre else None,
        "elevation_deg": _round(centre[1], 4) if centre else None,
        "label_azimuth_deg": _round(obs.azimuth_deg, 4),
        "label_elevation_deg": _round(obs.elevation_deg, 4),
        "hfov_deg": _round(obs.hfov_deg if obs.hfov_deg is not None else hfov, 4),
        "vfov_deg": _round(obs.vfov_deg if obs.vfov_deg is not None else vfov, 4),
        "model_azimuth_deg": _round(pointing[0], 4) if pointing else None,
        "model_elevation_deg": _round(pointing[1], 4) if pointing else None,
        "model_hfov_deg": round(hfov, 4),
        "model_vfov_deg": round(vfov, 4),
        "width": obs.width,
        "height": obs.height,
        "camera_model_type": obs.camera.model_type,
        "camera_height_m": round(-float(obs.camera.c[2]), 4),
        "label_path": str(obs.label_path),
        "image_path": str(obs.image_path) if obs.image_path else None,
    }
    if pose is not None:
        out.update(
            easting=round(pose.easting, 3),
            northing=round(pose.northing, 3),
            latitude=round(pose.latitude, 9),
            longitude=round(pose.longitude, 9),
            elevation_m=round(pose.elevation_m, 3),
            localization=pose.source,
            attitude_source=pose.attitude_source,
            places_pose=pose.pose,
            places_match=pose.match,
            crs=pose.crs,
        )
    return out
