"""Comparing two ``Observation``s field by field (what a label reader must reproduce)."""

from __future__ import annotations

import numpy as np
import pytest

from mars_pairs.observation import Observation


def assert_same(got: Observation, want: Observation) -> None:
    """Every Observation field equal (vectors within 1e-9), label path and image aside."""
    for name in ("mission", "product_id", "instrument", "sol", "rmc", "width", "height"):
        assert getattr(got, name) == getattr(want, name), name
    assert got.start_time == want.start_time
    for name in ("azimuth_deg", "elevation_deg", "hfov_deg", "vfov_deg"):
        if getattr(want, name) is None:
            assert getattr(got, name) is None, name
        else:
            assert getattr(got, name) == pytest.approx(getattr(want, name), abs=1e-9), name
    for name in ("rover_offset_m", "rover_quaternion"):
        if getattr(want, name) is None:
            assert getattr(got, name) is None, name
        else:
            np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=1e-9)
    assert (got.camera.model_type, got.camera.frame) == (want.camera.model_type, want.camera.frame)
    assert (got.camera.mtype, got.camera.mparm) == (want.camera.mtype, want.camera.mparm)
    for name in ("c", "a", "h", "v", "o", "r", "e"):
        if getattr(want.camera, name) is None:
            assert getattr(got.camera, name) is None, name
        else:
            np.testing.assert_allclose(
                getattr(got.camera, name), getattr(want.camera, name), atol=1e-9
            )
