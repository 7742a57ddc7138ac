"""rover_px, camera_px and heading_deg stay right through every chip transform: checked on
the transformed orbital raster itself (marks painted at the rover and ahead of the camera
must be found where the moved targets point)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mars_pairs.torch.transforms import (
    Compose,
    Crop,
    Flip,
    NorthUp,
    RandomCrop,
    RandomFlip,
    RandomRotate,
    Resize,
    Rotate,
)

N = 96
AHEAD = 24.0  # pixels from the camera along the heading


def _sample() -> dict:
    rover = np.array([40.5, 52.5])
    camera = np.array([41.0, 51.0])
    heading = 63.0
    ortho = torch.zeros((1, N, N), dtype=torch.float32)
    viewshed = torch.zeros((1, N, N), dtype=torch.uint8)
    r, c = int(rover[1]), int(rover[0])
    ortho[0, r - 1 : r + 2, c - 1 : c + 2] = 255.0
    ahead = camera + AHEAD * np.array([math.sin(math.radians(heading)),
                                       -math.cos(math.radians(heading))])  # fmt: skip
    viewshed[0, int(ahead[1]) - 1 : int(ahead[1]) + 2, int(ahead[0]) - 1 : int(ahead[0]) + 2] = 255
    transform = torch.tensor([0.5, 0.0, 1000.0, 0.0, -0.5, 2000.0], dtype=torch.float64)
    return {
        "ortho": ortho,
        "viewshed": viewshed,
        "transform": transform,
        "bounds": torch.tensor([1000.0, 1952.0, 1048.0, 2000.0], dtype=torch.float64),
        "rotation": torch.tensor(0.0, dtype=torch.float64),
        "rover_px": torch.tensor(rover, dtype=torch.float64),
        "camera_px": torch.tensor(camera, dtype=torch.float64),
        "heading_deg": torch.tensor(heading, dtype=torch.float64),
    }


def _centroid(image: torch.Tensor) -> np.ndarray:
    w = image[0].double().numpy()
    rows, cols = np.nonzero(w > 0.5 * w.max())
    return np.array([cols.mean() + 0.5, rows.mean() + 0.5])


TRANSFORMS = {
    "flip-h": Flip("horizontal", target="chip"),
    "flip-v": Flip("vertical", target="chip"),
    "rot90": Rotate(90.0),
    "rot30": Rotate(30.0),
    "crop": Crop(10, 5, 80, 84, target="chip"),
    "resize": Resize(chip=144),
    "random": Compose(
        [
            RandomRotate(generator=torch.Generator().manual_seed(3)),
            RandomFlip(p=1.0, axis="vertical", target="chip"),
            RandomCrop(88, target="chip", generator=torch.Generator().manual_seed(4)),
        ]
    ),
    "north-up": Compose([Rotate(-41.0), NorthUp()]),
}


@pytest.mark.parametrize("name", list(TRANSFORMS))
def test_targets_follow_the_chip(name: str) -> None:
    out = TRANSFORMS[name](_sample())
    rover = out["rover_px"].numpy()
    assert np.hypot(*(_centroid(out["ortho"]) - rover)) <= 1.0, (name, rover)
    scale = out["ortho"].shape[-1] / N if name == "resize" else 1.0
    h = math.radians(float(out["heading_deg"]))
    ahead = out["camera_px"].numpy() + AHEAD * scale * np.array([math.sin(h), -math.cos(h)])
    assert np.hypot(*(_centroid(out["viewshed"]) - ahead)) <= 1.0 * scale, (name, ahead)


def test_heading_turns_with_the_chip_rotation() -> None:
    """heading_deg + rotation is the camera's map azimuth: unchanged by any rotation."""
    out = Rotate(90.0)(_sample())  # content turns counterclockwise: up turns clockwise on map
    assert float(out["rotation"]) == pytest.approx(90.0)
    assert float(out["heading_deg"]) == pytest.approx((63.0 - 90.0) % 360.0)
    out = Rotate(-41.0)(_sample())
    total = (float(out["heading_deg"]) + float(out["rotation"])) % 360.0
    assert total == pytest.approx(63.0)
