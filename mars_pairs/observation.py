"""The Observation: what one mast-camera product's label says, in typed form.

The contract between the label readers (``mars_pairs.pds``, which build it) and everything
that uses a label (``geometry``, ``pipeline``): a module of its own, so neither package
imports the other's internals (``pds`` uses ``geometry.camera``; ``geometry`` uses this)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from mars_pairs.geometry.camera import CameraModel


@dataclass(frozen=True)
class MotionCounter:
    """Rover motion counter (RMC): the site, drive and pose indices of the rover's position."""

    site: int
    drive: int
    pose: int | None = None


@dataclass(frozen=True)
class Observation:
    """One mast-camera image as described by its PDS label.

    Frames and units:
    - ``camera``: the label's camera model; vectors in ``camera.frame`` (ROVER_NAV_FRAME: x
      forward, y right, z down, metres; H and V in pixels of the product's own grid).
    - ``rover_offset_m``: the rover frame origin in SITE_FRAME (x north, y east, z down),
      metres, from telemetry; ``rover_quaternion`` (s, v1, v2, v3) rotates ROVER_NAV_FRAME
      vectors into SITE_FRAME (v_site = R(q) v_rover).
    - ``azimuth_deg`` / ``elevation_deg``: the label's derived instrument pointing in SITE_FRAME,
      azimuth clockwise from north, elevation up from the horizon, degrees.
    - ``hfov_deg`` / ``vfov_deg``: the label's field of view, degrees.
    """

    label_path: Path
    mission: str  # "msl" or "m2020"
    product_id: str
    instrument: str
    sol: int
    rmc: MotionCounter
    width: int  # samples of the product's image
    height: int  # lines of the product's image
    camera: CameraModel
    rover_offset_m: np.ndarray | None = None
    rover_quaternion: np.ndarray | None = None
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    hfov_deg: float | None = None
    vfov_deg: float | None = None
    start_time: datetime | None = None
    image_path: Path | None = None
    lmst: str | None = None  # local mean solar time of day at the start, "HH:MM:SS[.fff]"

    @property
    def site(self) -> int:
        """Site index of the rover motion counter."""
        return self.rmc.site

    @property
    def drive(self) -> int:
        """Drive index of the rover motion counter."""
        return self.rmc.drive
