"""Reading one class mask (and its exclusion masks) for one ground image, checked.

Every failure is a ``TerrainLabelError`` naming the file: a mask that is not a single-band
8-bit PNG, whose size is not the image's, that holds a value its class table does not know,
or an exclusion mask (rover ``mxy``, range ``rng-30m``) holding anything but 0 and 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from mars_pairs.errors import TerrainLabelError
from mars_pairs.terrain_labels.classes import NO_LABEL, ClassTable


@dataclass(frozen=True)
class TerrainLabel:
    """A ground image's terrain classes: ``classes`` (H, W) uint8 on the image's pixel grid
    (class values of ``table``, ``NO_LABEL`` where unlabelled, ignored, on the rover or past
    the range limit), the files it came from, and ``max_range_m``: the label's range limit
    (metres from the camera; None: none), which the carry onto the map enforces too."""

    product_id: str
    classes: np.ndarray
    table: ClassTable
    mask_path: Path
    rover_mask: Path | None = None
    range_mask: Path | None = None
    max_range_m: float | None = None

    def counts(self) -> dict[int, int]:
        """Pixels of each class value."""
        hist = np.bincount(self.classes.ravel(), minlength=256)
        return {v: int(hist[v]) for v in self.table.values}


def _read_png(path: Path, what: str) -> np.ndarray:
    """The single-band 8-bit pixels of ``path`` (mode L, or P read as its indices)."""
    try:
        with Image.open(path) as im:
            if im.mode not in ("L", "P"):
                raise TerrainLabelError(
                    f"{path}: {what} must be a single-band 8-bit image, got mode {im.mode}"
                )
            im.load()
            return np.array(im, dtype=np.uint8)  # a writable copy
    except FileNotFoundError:
        raise TerrainLabelError(f"{path}: {what} not found") from None
    except (OSError, SyntaxError, ValueError) as exc:
        raise TerrainLabelError(f"{path}: {what} unreadable: {exc}") from None


def _check_size(arr: np.ndarray, path: Path, what: str, size: tuple[int, int]) -> None:
    """``size`` = (width, height) of the ground image."""
    if (arr.shape[1], arr.shape[0]) != tuple(size):
        raise TerrainLabelError(
            f"{path}: {what} is {arr.shape[1]} x {arr.shape[0]} pixels, its image "
            f"{size[0]} x {size[1]}"
        )


def read_classes(path: Path, table: ClassTable, size: tuple[int, int]) -> np.ndarray:
    """The class mask at ``path`` for an image of ``size`` (width, height): (H, W) uint8 with
    ``table.ignore`` values turned into ``NO_LABEL``."""
    arr = _read_png(path, "terrain mask")
    _check_size(arr, path, "terrain mask", size)
    known = np.zeros(256, dtype=bool)
    known[list(table.values)] = True
    known[NO_LABEL] = True
    known[list(table.ignore)] = True
    present = np.flatnonzero(np.bincount(arr.ravel(), minlength=256))
    unknown = [int(v) for v in present if not known[v]]
    if unknown:
        raise TerrainLabelError(
            f"{path}: mask value(s) {unknown[:8]} not in the class table "
            f"{dict(table.names)} (no label: {NO_LABEL}, ignored: {list(table.ignore)})"
        )
    if table.ignore:
        arr[np.isin(arr, table.ignore)] = NO_LABEL
    return arr


def read_exclusion(path: Path, what: str, size: tuple[int, int]) -> np.ndarray:
    """An exclusion mask (1 = excluded, 0 = kept) as bool (H, W)."""
    arr = _read_png(path, what)
    _check_size(arr, path, what, size)
    if int(arr.max(initial=0)) > 1:
        bad = np.flatnonzero(np.bincount(arr.ravel(), minlength=256)[2:]) + 2
        raise TerrainLabelError(f"{path}: {what} holds {bad[:8].tolist()}; expected 0 and 1")
    return np.asarray(arr == 1)
