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
        assert len(fig.axes) == 6
    title = plain.axes[0].get_title()
    assert s["meta"]["product_id"] in title
    info = plain.axes[5].texts[0].get_text()
    assert s["meta"]["key"] in info and "rotation 0°" in info
    assert "rotation 30°" in turned.axes[5].texts[0].get_text()
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
    assert "no correspondence" in fig.axes[5].texts[0].get_text()
    plt.close(fig)
