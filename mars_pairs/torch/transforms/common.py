"""Dtype conversion, composition, and the keypoints of a sample."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import ClassVar

import numpy as np
import torch

from mars_pairs.torch.transforms.geometric import CHIP_FIELDS, Sample, chip_hw, ground_hw


class ToFloat:
    """uint8 images to float32: ground and ortho in [0, 1], viewshed {0, 1} (numpy's division,
    bit for bit what ``image_dtype=torch.float32`` gives)."""

    DIVISORS: ClassVar[dict[str, float]] = {
        "ground": 255.0, "ortho": 255.0, "viewshed": 1.0, "ortho_view": 255.0,
        "ground_on_map": 255.0, "view_valid": 1.0, "ground_on_map_cover": 1.0,
    }  # fmt: skip

    def __call__(self, sample: Sample) -> Sample:
        out = dict(sample)
        for name, divisor in self.DIVISORS.items():
            value = sample.get(name)
            if isinstance(value, torch.Tensor) and value.dtype == torch.uint8:
                values = np.empty(tuple(value.shape), dtype=np.float32)
                np.divide(value.numpy(), np.float32(divisor), out=values)
                out[name] = torch.from_numpy(values)
        return out


class Compose:
    """Apply ``transforms`` in order."""

    def __init__(self, transforms: Sequence[Callable[[Sample], Sample]]) -> None:
        self.transforms = list(transforms)

    def __call__(self, sample: Sample) -> Sample:
        for t in self.transforms:
            sample = t(sample)
        return sample


def keypoints(sample: Sample, inside: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """The keypoints of a sample: ground (x, y) [N, 2] and chip (column, row) [N, 2], pixel-edge
    coordinates, for every ray that hit the terrain (and, with ``inside``, whose points lie
    inside both the ground image and the chip)."""
    ground = sample["corr_ground"].reshape(2, -1).T
    chip = sample["corr"].reshape(2, -1).T
    keep = torch.isfinite(ground).all(dim=1) & torch.isfinite(chip).all(dim=1)
    if inside:
        gh, gw = ground_hw(sample) if "ground" in sample else (math.inf, math.inf)
        ch, cw = chip_hw(sample) if any(f in sample for f in CHIP_FIELDS) else (math.inf, math.inf)
        keep &= (ground[:, 0] >= 0) & (ground[:, 0] <= gw) & (ground[:, 1] >= 0)
        keep &= (ground[:, 1] <= gh) & (chip[:, 0] >= 0) & (chip[:, 0] <= cw)
        keep &= (chip[:, 1] >= 0) & (chip[:, 1] <= ch)
    return ground[keep], chip[keep]
