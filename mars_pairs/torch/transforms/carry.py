"""Carry a raster between the ground image and the chip inside a sample, occlusion honoured
(``mars_pairs.raster.transfer`` on the sample's dense members)."""

from __future__ import annotations

import math

import numpy as np
import torch

from mars_pairs.errors import ArgumentError
from mars_pairs.raster.transfer import chip_to_image, image_to_chip
from mars_pairs.torch.transforms.geometric import Sample


def _need(sample: Sample, *names: str) -> None:
    missing = [n for n in names if n not in sample]
    if missing:
        raise ArgumentError(f"carrying a raster needs the sample field(s) {missing}")


def _hwc(t: torch.Tensor) -> np.ndarray:
    return np.asarray(t.numpy().transpose(1, 2, 0))


def _chw(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a.reshape(*a.shape[:2], -1).transpose(2, 0, 1)))


class CarryToChip:
    """``sample[field]`` ([C, H, W] on the ground image's grid, as ``ground``) laid on the
    chip grid through ``ground_px``: ``sample[out]`` [C, S, S] and ``sample[out + "_valid"]``
    bool [S, S] (visible chip pixels whose image point lies on the raster). ``nearest`` for
    labels (the raster's dtype kept, ``fill`` elsewhere), else bilinear float32 (NaN
    elsewhere). Place it before any ground or chip transform that would resample the image
    it reads, or after: ``ground_px`` moves with both."""

    def __init__(
        self, field: str, out: str, *, nearest: bool = True, fill: float = math.nan
    ) -> None:
        self.field, self.out, self.nearest, self.fill = field, out, bool(nearest), fill

    def __call__(self, sample: Sample) -> Sample:
        _need(sample, self.field, "ground_px")
        raster = sample[self.field]
        px = _hwc(sample["ground_px"].double())
        values, valid = image_to_chip(_hwc(raster), px, nearest=self.nearest, fill=self.fill)
        out = dict(sample)
        out[self.out] = _chw(values)
        out[self.out + "_valid"] = torch.from_numpy(valid)
        return out


class CarryToImage:
    """``sample[field]`` ([C, S, S] on the chip grid) carried to the ground image's dense
    grid through each ray's first terrain hit (``hits``, map x, y) and the chip's
    ``transform``: ``sample[out]`` [C, H', W'] and ``sample[out + "_valid"]`` bool [H', W']
    (a hit on the chip with a value there). ``nearest`` for labels, else bilinear."""

    def __init__(
        self, field: str, out: str, *, nearest: bool = True, fill: float = math.nan
    ) -> None:
        self.field, self.out, self.nearest, self.fill = field, out, bool(nearest), fill

    def __call__(self, sample: Sample) -> Sample:
        _need(sample, self.field, "hits", "transform")
        a, b, c, d, e, f = (float(v) for v in sample["transform"])
        det = a * e - b * d
        hits = sample["hits"].double().numpy()
        x, y = hits[0] - c, hits[1] - f
        col = (e * x - b * y) / det
        row = (-d * x + a * y) / det
        chip_px = np.stack([col, row], axis=-1)
        values, valid = chip_to_image(
            _hwc(sample[self.field]), chip_px, nearest=self.nearest, fill=self.fill
        )
        out = dict(sample)
        out[self.out] = _chw(values)
        out[self.out + "_valid"] = torch.from_numpy(valid)
        return out
