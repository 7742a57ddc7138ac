"""Bad arguments to the geometry are ArgumentErrors naming the argument: a MarsPairsError (the
CLI's exit 2) and still a ValueError (what earlier callers catch)."""

from __future__ import annotations

import numpy as np
import pytest

from mars_pairs import ArgumentError, CameraModel, MarsPairsError
from mars_pairs.geometry import cahvore

C, A, H, V = [0.0, 0.0, -2.0], [1.0, 0.0, 0.0], [800.0, 500.0, 0.0], [500.0, 0.0, 800.0]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"model_type": "PINHOLE"}, "unsupported camera model type 'PINHOLE'"),
        ({"model_type": "CAHVOR"}, "CAHVOR model needs O and R"),
        ({"model_type": "CAHV", "c": [np.nan, 0.0, 0.0]}, "C has non-finite components"),
        (
            {"model_type": "CAHVORE", "o": A, "r": [0, 0, 0], "e": [0, 0, 0], "mtype": 7},
            "model type must be 1, 2 or 3, got 7",
        ),
    ],
)
def test_a_bad_camera_model_is_an_argument_error(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"c": C, "a": A, "h": H, "v": V} | kwargs
    with pytest.raises(ArgumentError, match=match) as err:
        CameraModel(**args)  # type: ignore[arg-type]  # the fields' types vary by case
    assert isinstance(err.value, ValueError) and isinstance(err.value, MarsPairsError)


def test_cahvore_linearity_of_an_unknown_type() -> None:
    with pytest.raises(ArgumentError, match="got 0"):
        cahvore.linearity(0, 0.0)
