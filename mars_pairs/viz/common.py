"""Shared pieces of the pictures: matplotlib on demand, manifest rows, members, hillshade.

matplotlib is imported here only, inside the functions (the ``viz`` extra), so a build, a
query or ``import mars_pairs.cli`` needs no plotting stack."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mars_pairs.errors import MarsPairsError
from mars_pairs.store.manifest import Manifest

DPI = 90


SHOW_SIZE = (16.0, 10.0)  # inches: show_sample writes SHOW_SIZE * DPI pixels


OVERVIEW_SIZE = (16.0, 8.0)  # inches: overview writes OVERVIEW_SIZE * DPI pixels


SPLIT_COLOURS = {"train": "#1f77b4", "val": "#ff7f0e", "test": "#2ca02c", "buffer": "#9e9e9e"}


def pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise MarsPairsError("pictures need matplotlib: pip install 'mars-pairs[viz]'") from exc
    return plt


def manifest_rows(root: Path) -> list[dict[str, Any]]:
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    return Manifest.open(root).require().to_table().to_pylist()


def hillshade(
    dem: np.ndarray, res: float, azimuth: float = 315.0, altitude: float = 35.0
) -> np.ndarray:
    """Hillshade in [0, 1] of an elevation grid (metres, ``res`` metres per pixel; NaN kept).

    ``azimuth`` is the light's direction clockwise from the grid's up (row 0) direction.
    """
    finite = np.isfinite(dem)
    z = np.where(finite, dem, np.nanmedian(dem) if finite.any() else 0.0)
    gy, gx = np.gradient(z, res)  # gy: d z / d row (rows go down the grid)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)  # the downhill direction, clockwise from up
    az, alt = np.radians(azimuth), np.radians(altitude)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.where(finite, np.clip(shade, 0, 1), np.nan)
