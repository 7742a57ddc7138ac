"""Random augmentations: crops, flips, rotations (geometric, pairing kept) and colour jitter."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from mars_pairs.torch.transforms.geometric import (
    Crop,
    Flip,
    Rotate,
    Sample,
    check_target,
    chip_hw,
    ground_hw,
    like_image,
    size_hw,
)


def _uniform(low: float, high: float, generator: torch.Generator | None) -> float:
    return low + (high - low) * float(torch.rand((), generator=generator, dtype=torch.float64))


class RandomCrop:
    """A crop of ``size`` ((H, W) or an int) at a uniformly random place."""

    def __init__(
        self, size: int | Sequence[int], target: str, generator: torch.Generator | None = None
    ) -> None:
        self.size = size_hw(size, "size")
        self.target = check_target(target, ("ground", "chip"))
        self.generator = generator

    def __call__(self, sample: Sample) -> Sample:
        hw = ground_hw(sample) if self.target == "ground" else chip_hw(sample)
        assert self.size is not None
        top = round(_uniform(0, max(hw[0] - self.size[0], 0), self.generator))
        left = round(_uniform(0, max(hw[1] - self.size[1], 0), self.generator))
        return Crop(top, left, *self.size, target=self.target)(sample)


class RandomFlip:
    """A flip (see :class:`Flip`) with probability ``p``."""

    def __init__(
        self,
        p: float = 0.5,
        axis: str = "horizontal",
        target: str = "ground",
        generator: torch.Generator | None = None,
    ) -> None:
        self.p, self.flip, self.generator = float(p), Flip(axis, target), generator

    def __call__(self, sample: Sample) -> Sample:
        if _uniform(0, 1, self.generator) < self.p:
            return self.flip(sample)
        return dict(sample)


class RandomRotate:
    """A rotation (see :class:`Rotate`) by a uniform angle in ``degrees`` (low, high), or
    by a random multiple of 90 degrees with ``quarter_turns=True`` (exact)."""

    def __init__(
        self,
        degrees: tuple[float, float] = (-180.0, 180.0),
        target: str = "chip",
        quarter_turns: bool = False,
        generator: torch.Generator | None = None,
    ) -> None:
        self.degrees = (float(degrees[0]), float(degrees[1]))
        self.target, self.quarter_turns = check_target(target), quarter_turns
        self.generator = generator

    def __call__(self, sample: Sample) -> Sample:
        if self.quarter_turns:
            angle = 90.0 * int(torch.randint(4, (), generator=self.generator))
        else:
            angle = _uniform(*self.degrees, self.generator)
        return Rotate(angle, target=self.target)(sample)


class ColorJitter:
    """Random brightness, contrast and saturation factors in [1 - x, 1 + x] applied to the
    ground image (``fields``), pixel values only: keypoints, chips and georeferencing stay."""

    def __init__(
        self,
        brightness: float = 0.2,
        contrast: float = 0.2,
        saturation: float = 0.2,
        fields: Sequence[str] = ("ground",),
        generator: torch.Generator | None = None,
    ) -> None:
        self.brightness, self.contrast, self.saturation = brightness, contrast, saturation
        self.fields, self.generator = tuple(fields), generator

    def __call__(self, sample: Sample) -> Sample:
        out = dict(sample)
        for name in self.fields:
            if name not in sample:
                continue
            image = sample[name]
            top = 255.0 if image.dtype == torch.uint8 else 1.0
            x = image.float()
            x = x * _uniform(1 - self.brightness, 1 + self.brightness, self.generator)
            mean = x.mean()
            x = (x - mean) * _uniform(1 - self.contrast, 1 + self.contrast, self.generator) + mean
            if x.shape[0] == 3:
                grey = (0.299 * x[0] + 0.587 * x[1] + 0.114 * x[2])[None]
                s = _uniform(1 - self.saturation, 1 + self.saturation, self.generator)
                x = (x - grey) * s + grey
            out[name] = like_image(x.clamp_(0, top), image)
        return out
