"""Value formatting shared by the synthetic PDS3 and PDS4 label writers."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mars_pairs.errors import ArgumentError
from mars_pairs.observation import Observation


def real_text(x: float) -> str:
    """A finite float as exact (round-trip) text with a decimal point (PDS3 and XML)."""
    x = float(x)
    if not math.isfinite(x):
        raise ArgumentError(f"cannot write non-finite value {x}")
    text = repr(x)
    mantissa, _, exponent = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return f"{mantissa}e{exponent}" if exponent else mantissa


def as_utc(t: datetime) -> datetime:
    """The time in UTC (naive times are taken as UTC)."""
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


def iso_time(t: datetime) -> str:
    """ISO time with microseconds, no zone suffix."""
    return as_utc(t).strftime("%Y-%m-%dT%H:%M:%S.%f")


def rover_angles(axis: np.ndarray) -> tuple[float, float]:
    """Azimuth (clockwise from +x) and elevation (up, z down) of a rover-frame direction."""
    a = axis / np.linalg.norm(axis)
    az = math.degrees(math.atan2(a[1], a[0])) % 360.0
    return az, math.degrees(math.asin(max(-1.0, min(1.0, -a[2]))))


def pointer_name(obs: Observation, label_path: Path, suffix: str) -> str:
    """The data file name the label points to: the Observation's image, else <stem><suffix>."""
    return obs.image_path.name if obs.image_path is not None else label_path.stem + suffix
