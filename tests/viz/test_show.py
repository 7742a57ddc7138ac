"""``show``: a legend, a DEM colourbar, a thin info strip, a note for a view that covers almost
nothing; ``--index``, ``--random``, ``--dpi``."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from PIL import Image

from mars_pairs.cli.main import main
from support.builds import cli_built_dataset

pytest.importorskip("matplotlib")


def synthetic(area_m2: float, elevation_deg: float) -> dict:
    """A sample with a 64 x 64 chip of 2 m pixels (16384 m²) whose viewshed is one cell."""
    n = 64
    vis = torch.zeros((1, n, n), dtype=torch.uint8)
    vis[0, 32, 33] = 1
    return {
        "ground": torch.full((3, 40, 50), 120, dtype=torch.uint8),
        "ortho": torch.full((1, n, n), 90, dtype=torch.uint8),
        "dem": torch.linspace(-10.0, -4.0, n * n).reshape(1, n, n),
        "viewshed": vis,
        "transform": torch.tensor([2.0, 0.0, 1000.0, 0.0, -2.0, 2128.0], dtype=torch.float64),
        "rotation": torch.tensor(0.0, dtype=torch.float64),
        "meta": {"easting": 1064.0, "northing": 2064.0, "azimuth_deg": 40.0, "hfov_deg": 20.0,
                 "elevation_deg": elevation_deg, "viewshed_area_m2": area_m2,
                 "max_visible_range_m": 1.8, "visible_cells": 1},
    }  # fmt: skip


def test_a_view_that_covers_almost_nothing_gets_a_note() -> None:
    from mars_pairs.viz.common import pyplot
    from mars_pairs.viz.sample import sample_figure, view_note

    chip = 64 * 64 * 4.0
    assert view_note({"viewshed_area_m2": 2000.0}, chip) is None
    down = view_note({"viewshed_area_m2": 4.0, "elevation_deg": -36.5,
                      "max_visible_range_m": 1.8}, chip)  # fmt: skip
    assert down is not None and "looks down (el -36.5°)" in down and "4 m²" in down
    sky = view_note({"viewshed_area_m2": 0.0, "elevation_deg": 2.4}, chip)
    assert sky is not None and "above the horizon" in sky
    fig = sample_figure(synthetic(4.0, -36.5))
    try:
        texts = [t.get_text() for a in fig.axes for t in a.texts]
        assert any("looks down" in t for t in texts)
        assert any("almost nothing" in t.get_text() for t in fig.axes[1].texts)  # the ortho
        # one row of panels and the strip: the info is not a panel of its own
        strip, panel = fig.axes[3].get_position(), fig.axes[0].get_position()
        assert strip.height < 0.4 * panel.height
        assert fig.axes[4].get_legend() is not None
        assert fig.axes[-1].get_ylabel() == "elevation (m)"  # the DEM colourbar
    finally:
        pyplot().close(fig)
    plain = sample_figure(synthetic(3000.0, -5.0))
    try:
        assert not any("almost nothing" in t.get_text() for a in plain.axes for t in a.texts)
    finally:
        pyplot().close(plain)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory, small_mission: Path) -> Path:
    return cli_built_dataset(tmp_path_factory.getbasetemp(), small_mission)


def test_show_picks_by_index_or_at_random_at_a_dpi(
    dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import pyarrow.parquet as pq

    keys = pq.read_table(dataset / "manifest.parquet", columns=["key"])["key"].to_pylist()
    assert main(["show", str(dataset), "--index", "1", "--out", str(tmp_path / "i.png"),
                 "--dpi", "40"]) == 0  # fmt: skip
    with Image.open(tmp_path / "i.png") as im:
        assert im.size == (16 * 40, 10 * 40)  # SHOW_SIZE at 40 dpi (the sample has corr)
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    drawn = []
    for _ in range(2):  # the same seed, the same sample (written as KEY.png)
        assert main(["show", str(dataset), "--random", "--seed", "3", "--dpi", "30"]) == 0
        drawn.append(Path(capsys.readouterr().out.strip()).stem)
    assert drawn[0] == drawn[1] and drawn[0] in keys and (tmp_path / f"{drawn[0]}.png").exists()
    # the default is the first sample; bad choices exit 2 with one line
    assert main(["show", str(dataset), "--out", str(tmp_path / "d.png"), "--dpi", "30"]) == 0
    assert main(["show", str(dataset), "--index", str(len(keys)), "--out", "x.png"]) == 2
    assert "out of range" in capsys.readouterr().err
    assert main(["show", str(dataset), "--dpi", "0"]) == 2
    with pytest.raises(SystemExit):
        main(["show", str(dataset), "--index", "0", "--random"])
