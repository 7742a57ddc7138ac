"""The synthetic mission's terrain truth written as AI4Mars would ship it.

Per image (``terrain_labels.ai4mars``: names, values, folders): the class mask (the true
class, ``synth.terrain_classes``, of each pixel's terrain point; 255 sky; labelled at every
range, as the unmasked releases are), the rover mask (all 0: the renderer draws no rover)
and the 30 m range mask (1 where the pixel's terrain is farther than 30 m from the camera
centre, or sky). Curiosity Mastcam masks use 4 for no label and have no rover or range
masks, as in the release.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from mars_pairs.synth.render import classes_at
from mars_pairs.terrain_labels.ai4mars import RANGE_LIMIT_M, exclusion_relpath, mask_relpath
from mars_pairs.terrain_labels.classes import MASTCAM_IGNORE, NO_LABEL

AI4MARS_DIR = "ai4mars"
CLASSES_NAME = "terrain_classes.tif"


@dataclass(frozen=True)
class TruthMasks:
    """One image's truth: classes (H, W) uint8 and its range (H, W) metres (inf: sky)."""

    classes: np.ndarray
    range_m: np.ndarray


def truth_masks(hit_col: np.ndarray, hit_row: np.ndarray, range_m: np.ndarray,
                classes: np.ndarray, factor: int) -> TruthMasks:  # fmt: skip
    """The truth of an image from its terrain points (DEM column, row) and ranges."""
    return TruthMasks(classes_at(hit_col, hit_row, classes, factor, NO_LABEL), range_m)


def _png(path: Path, arr: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(arr, dtype=np.uint8), mode="L").save(path)


def write_ai4mars_truth(root: Path, mission: str, product_id: str, masks: TruthMasks,
                        instrument: str = "") -> None:  # fmt: skip
    """Write one image's masks under ``root`` in the AI4Mars layout."""
    rel = mask_relpath(mission, instrument, product_id)
    classes = masks.classes
    if rel.endswith("_15033_merged.png"):
        classes = np.where(classes == NO_LABEL, MASTCAM_IGNORE, classes)
        _png(root / rel, classes)
        return
    _png(root / rel, classes)
    for kind, values in (
        ("MXY", np.zeros(classes.shape, dtype=np.uint8)),
        ("RNG", (~(masks.range_m <= RANGE_LIMIT_M)).astype(np.uint8)),
    ):
        where = exclusion_relpath(mission, product_id, kind)
        if where is not None:
            _png(root / where, values)
