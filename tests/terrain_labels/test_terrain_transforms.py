"""The terrain members move with their grids under the geometric transforms: ``terrain``
with the ground image, ``terrain_on_map`` with the chips; nearest (classes stay classes) and
255 (no label) where nothing moved in."""

from __future__ import annotations

import torch

from mars_pairs.torch.transforms import Flip, Rotate


def _classes(h: int, w: int) -> torch.Tensor:
    return (torch.arange(h * w, dtype=torch.int64) % 4).to(torch.uint8).reshape(1, h, w)


def test_terrain_flips_with_the_ground_image() -> None:
    ground = torch.zeros(3, 4, 6, dtype=torch.uint8)
    terrain = _classes(4, 6)
    out = Flip("horizontal", target="ground")({"ground": ground, "terrain": terrain})
    assert torch.equal(out["terrain"], terrain.flip(-1))


def test_terrain_on_map_turns_with_the_chips() -> None:
    on_map = _classes(8, 8)
    chips = {"ortho": torch.zeros(1, 8, 8, dtype=torch.uint8), "terrain_on_map": on_map}
    out = Rotate(30.0, target="chip")(chips)
    moved = out["terrain_on_map"]
    assert moved.dtype == torch.uint8
    assert set(moved.unique().tolist()) <= {0, 1, 2, 3, 255}  # nearest: no blended classes
    assert (moved == 255).any()  # the corners turned in from outside carry no label
