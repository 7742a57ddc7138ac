"""The pointing a labelled image's camera model gives, for checking against the label's own."""

from __future__ import annotations

import numpy as np

from mars_pairs.geometry.frames import azimuth_elevation_deg, quaternion_to_matrix
from mars_pairs.geometry.labelled import LabelledImage


def model_pointing_deg(
    obs: LabelledImage, quaternion: np.ndarray | None = None, *, convention: str | None = None
) -> tuple[float, float] | None:
    """Azimuth/elevation (degrees, SITE_FRAME) of the ray the label's derived pointing
    describes, from the camera model.

    ``convention``, checked on the real labels: "centre" (Perseverance: the ray through the
    sensor centre, which is the image centre of a full frame only) or "axis" (Curiosity: the
    camera axis A, which for a subframe such as 2663ML's 1152 x 432 lies 50 px off the image
    centre). The default is the mission's. The ray is turned from the model frame
    (ROVER_NAV_FRAME) into SITE_FRAME by ``quaternion`` (default: the label's); None without.
    """
    q = obs.rover_quaternion if quaternion is None else quaternion
    if q is None:
        return None
    kind = convention or ("axis" if obs.mission == "msl" else "centre")
    if kind == "axis":
        ray = obs.camera.a
    else:
        centre = np.array([[(obs.width - 1) / 2.0, (obs.height - 1) / 2.0]])
        ray = obs.camera.unproject(centre)[1][0]
    az, el = azimuth_elevation_deg(quaternion_to_matrix(q) @ ray)
    return float(az), float(el)
