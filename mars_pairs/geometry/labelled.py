"""What geometry needs of a labelled image: a structural type, so ``geometry`` never imports
the label readers.

``mars_pairs.observation.Observation`` (built by ``mars_pairs.pds``) satisfies it; so does
any object with these read-only attributes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from mars_pairs.geometry.camera import CameraModel


class RoverCounter(Protocol):
    """The rover motion counter of an image: site, drive and pose indices."""

    @property
    def site(self) -> int: ...

    @property
    def drive(self) -> int: ...

    @property
    def pose(self) -> int | None: ...


class LabelledImage(Protocol):
    """An image with its label's geometry.

    Frames and units: ``camera`` in ROVER_NAV_FRAME (x forward, y right, z down, metres; H and
    V in pixels of the image's own grid, ``width`` x ``height``); ``rover_offset_m`` the rover
    frame origin in SITE_FRAME (x north, y east, z down, metres); ``rover_quaternion`` (s, v1,
    v2, v3) rotates ROVER_NAV_FRAME vectors into SITE_FRAME; ``mission`` "msl" or "m2020".
    """

    @property
    def label_path(self) -> Path: ...

    @property
    def mission(self) -> str: ...

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    @property
    def camera(self) -> CameraModel: ...

    @property
    def rmc(self) -> RoverCounter: ...

    @property
    def rover_offset_m(self) -> np.ndarray | None: ...

    @property
    def rover_quaternion(self) -> np.ndarray | None: ...
