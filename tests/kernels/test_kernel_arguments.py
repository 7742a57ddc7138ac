"""Bad arguments to the kernels are ArgumentErrors naming the argument: a MarsPairsError (the
CLI's exit 2) and still a ValueError (what earlier callers catch)."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from mars_pairs import ArgumentError, MarsPairsError, compute_viewshed
from mars_pairs.kernels.grid import as_grid
from mars_pairs.kernels.raycast import cast_rays

DEM = np.zeros((21, 21), dtype=np.float32)
TR = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 21.0)  # 1 m cells, x 0..21, y 0..21


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"radius": 0.0}, "radius must be positive and finite, got 0.0"),
        ({"radius": float("inf")}, "radius must be positive and finite"),
        ({"oversample": 0}, "oversample must be >= 1, got 0"),
        ({"x": 500.0}, "observer x=500.0, y=10.5 lies outside the DEM window"),
        ({"el_band": (10.0, -10.0)}, "elevation band must satisfy"),
        ({"az_band": (float("nan"), 10.0)}, "azimuth band must be finite"),
    ],
)
def test_bad_viewshed_arguments(kwargs: dict[str, object], match: str) -> None:
    call: dict[str, object] = {"x": 10.5, "y": 10.5, "height": 2.0, "radius": 8.0} | kwargs
    with pytest.raises(ArgumentError, match=match) as err:
        compute_viewshed((DEM, TR), **call)  # type: ignore[arg-type]  # the values vary by case
    assert isinstance(err.value, ValueError) and isinstance(err.value, MarsPairsError)


@pytest.mark.parametrize(
    ("window", "transform", "match"),
    [
        (DEM, None, "needs its affine transform"),
        (DEM, Affine(1.0, 0.5, 0.0, 0.0, -1.0, 21.0), "rotated or sheared"),
        (DEM, Affine(0.0, 0.0, 0.0, 0.0, -1.0, 21.0), "zero pixel size"),
        (DEM[0], TR, "must be 2-D"),
        (DEM, (1.0, 0.0, 0.0), "needs 6 coefficients"),
    ],
)
def test_bad_grids(window: np.ndarray, transform: object, match: str) -> None:
    with pytest.raises(ArgumentError, match=match):
        as_grid(window, transform)  # type: ignore[arg-type]  # a wrong transform on purpose


def test_rays_of_mismatched_shapes() -> None:
    with pytest.raises(ArgumentError, match="differ in shape"):
        cast_rays(np.zeros((2, 3)), np.ones((3, 3)), (DEM, TR), max_range=10.0)
