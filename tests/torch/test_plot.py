"""MarsPairsDataset.plot returns a matplotlib Figure of any sample, transformed or partial."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset, MarsPairsIterableDataset
from mars_pairs.torch.transforms import Compose, Flip, Resize, Rotate, ToFloat

matplotlib = pytest.importorskip("matplotlib")


def pixels(fig: object) -> np.ndarray:
    fig.canvas.draw()  # type: ignore[attr-defined]
    return np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]


def all_text(fig: object) -> str:
    return "\n".join(t.get_text() for a in fig.axes for t in a.texts)  # type: ignore[attr-defined]


def test_plot_returns_a_figure_of_the_sample(dataset_dir: Path) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from mars_pairs.viz.common import SHOW_SIZE

    with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as ds:
        s = ds[2]
        plain = ds.plot(s)
        turned = ds.plot(
            Compose([Resize(ground=(150, 206), chip=96), Rotate(30), Flip(), ToFloat()])(s)
        )
    for fig in (plain, turned):
        assert isinstance(fig, Figure) and tuple(fig.get_size_inches()) == SHOW_SIZE
        # ground, ortho, DEM, two keypoint panels, the info strip, the legend, the colourbar
        assert len(fig.axes) == 8
        assert fig.axes[-1].get_ylabel() == "elevation (m)"
        assert fig.axes[6].get_legend() is not None
    title = plain.axes[0].get_title()
    assert s["meta"]["product_id"] in title
    info = all_text(plain)
    assert s["meta"]["instrument"] in info and "rotation 0°" in info
    assert "rotation 30°" in all_text(turned)
    # the rotated chip panel differs from the plain one (it is drawn, not copied)
    a, b = pixels(plain), pixels(turned)
    assert a.shape == b.shape and np.mean(a != b) > 0.05
    plt.close(plain)
    plt.close(turned)


def test_plot_of_a_partial_sample(dataset_dir: Path) -> None:
    import matplotlib.pyplot as plt

    with MarsPairsIterableDataset(dataset_dir, fields=("ground", "ortho")) as stream:
        s = next(iter(stream))
        fig = stream.plot(s, title="just two fields")
    assert fig.axes[0].get_title() == "just two fields"
    assert "not in the sample" in fig.axes[2].texts[0].get_text()  # no DEM chip
    assert "no keypoints" in all_text(fig)
    assert len(fig.axes) == 5  # one row of three panels, the info strip, the legend
    plt.close(fig)
