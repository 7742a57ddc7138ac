"""The pictures' geometry and labels: the camera wedge starts at the camera centre, the
panels carry scale bars, the overview names its CRS and axes and draws the held-out areas."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from mars_pairs.viz.common import SPLIT_COLOURS
from support.builds import cli_built_dataset
from support.members import metas

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory, small_mission: Path) -> Path:
    return cli_built_dataset(tmp_path_factory.getbasetemp(), small_mission)


def meta_json(root: Path, key: str) -> dict:
    return metas(root)[key]


def test_the_wedge_starts_at_the_camera_centre() -> None:
    from mars_pairs.viz.sample import invert_affine, wedge_apex, wedge_pixels, wedge_ring

    row = {"easting": 1000.0, "northing": 2000.0, "camera_center_map": [1000.6, 2000.7, -5.0]}
    assert wedge_apex(row) == (1000.6, 2000.7, True)
    assert wedge_apex({"easting": 1000.0, "northing": 2000.0}) == (1000.0, 2000.0, False)
    bad = {"easting": 1.0, "northing": 2.0, "camera_center_map": [float("nan"), 0.0, 0.0]}
    assert wedge_apex(bad) == (1.0, 2.0, False)
    x, y = wedge_ring((1000.6, 2000.7), azimuth_deg=90.0, hfov_deg=20.0, range_m=3.0, n=5)
    assert (x[0], y[0]) == (x[-1], y[-1]) == (1000.6, 2000.7)  # apex, arc, apex
    dist = np.hypot(x[1:-1] - 1000.6, y[1:-1] - 2000.7)
    np.testing.assert_allclose(dist, 3.0)
    azimuth = np.degrees(np.arctan2(x[1:-1] - 1000.6, y[1:-1] - 2000.7))  # clockwise from N
    np.testing.assert_allclose(azimuth, [80.0, 85.0, 90.0, 95.0, 100.0])
    # in chip pixels (a north-up chip of 0.5 m pixels): the ring's first point is the centre
    transform = [0.5, 0.0, 990.0, 0.0, -0.5, 2010.0]
    row |= {"azimuth_deg": 90.0, "hfov_deg": 20.0, "max_visible_range_m": 3.0}
    col, line = wedge_pixels(row, invert_affine(transform))
    assert (col[0], line[0]) == pytest.approx(((1000.6 - 990.0) / 0.5, (2010.0 - 2000.7) / 0.5))


def test_show_reads_the_camera_centre_from_meta_json(dataset: Path) -> None:
    from mars_pairs.report.meta import camera_centres

    rows = pq.read_table(dataset / "manifest.parquet").to_pylist()
    centres = camera_centres(dataset, [r["key"] for r in rows] + ["no_such_key"])
    assert centres["no_such_key"] is None
    for row in rows:
        want = meta_json(dataset, row["key"])["camera_center_map"]
        got = centres[row["key"]]
        assert got == want
        # the camera centre is where the wedge starts, not the rover origin (~1 m away)
        off = np.hypot(got[0] - row["easting"], got[1] - row["northing"])
        assert 0.3 < off < 3.0


def test_the_sample_figure_has_scale_bars_and_names_the_wedge_apex(dataset: Path) -> None:
    from mars_pairs.report.meta import camera_centres
    from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset
    from mars_pairs.viz.common import pyplot
    from mars_pairs.viz.sample import invert_affine, wedge_pixels

    with MarsPairsDataset(dataset, fields=ALL_FIELDS) as ds:
        sample = ds[0]
        key = sample["meta"]["key"]
        sample["meta"]["camera_center_map"] = camera_centres(dataset, [key])[key]
        fig = ds.plot(sample)
    try:
        ortho_ax = fig.axes[1]
        assert "from the camera centre" in ortho_ax.get_title()
        bars = [t.get_text() for a in fig.axes for t in a.texts if t.get_text().endswith(" m")]
        assert len(bars) >= 2, bars  # the ortho and DEM panels (and the zoom when drawn)
        # the wedge line of the ortho panel starts at the camera centre, in chip pixels
        transform = [float(v) for v in np.asarray(sample["transform"])[:6]]
        apex = wedge_pixels(sample["meta"], invert_affine(transform))
        orange = [
            ln for ln in ortho_ax.lines if ln.get_color() == "orange" and len(ln.get_xdata()) > 3
        ]
        assert orange and orange[0].get_xdata()[0] == pytest.approx(apex[0][0])
        assert orange[0].get_ydata()[0] == pytest.approx(apex[1][0])
    finally:
        pyplot().close(fig)


def test_overview_labels_its_axes_crs_and_draws_the_held_out_area(dataset: Path) -> None:
    from matplotlib.colors import to_hex
    from matplotlib.patches import Polygon

    from mars_pairs.viz.common import pyplot
    from mars_pairs.viz.overview import overview_figure

    fig = overview_figure(dataset, colour_by="split")
    try:
        full, near = fig.axes[:2]
        for ax in (full, near):
            assert ax.get_xlabel() == "easting (m)" and ax.get_ylabel() == "northing (m)"
            hatched = [p for p in ax.patches if isinstance(p, Polygon) and p.get_hatch() == "///"]
            assert len(hatched) == 1  # the one held-out box
            assert to_hex(hatched[0].get_edgecolor()) == SPLIT_COLOURS["test"]
            texts = [t.get_text() for t in ax.texts]
            assert "test (held out)" in texts and "buffer zone" in texts
            assert any(t.endswith(" m") for t in texts)  # the scale bar
        assert "Equidistant Cylindrical" in fig._suptitle.get_text()
        legends = [
            t.get_text()
            for ax in (full, near)
            if ax.get_legend()
            for t in ax.get_legend().get_texts()
        ]
        assert "held-out area: test" in legends and "buffer (2)" in legends
        # the buffer footprints are pink, drawn opaque enough to be seen
        pink = [
            p for p in full.patches
            if not isinstance(p, Polygon) or p.get_hatch() != "///"
            if to_hex(p.get_facecolor()) == SPLIT_COLOURS["buffer"] == "#e377c2"
        ]  # fmt: skip
        assert len(pink) >= 2 and all(p.get_alpha() >= 0.3 for p in pink)
    finally:
        pyplot().close(fig)


def _extents(fig: Any, texts: list) -> list:
    renderer = fig.canvas.get_renderer()
    return [t.get_window_extent(renderer) for t in texts]


def test_overview_labels_never_overlap_and_stay_in_their_panel(dataset: Path) -> None:
    """Every text on the map panels (sol labels, held-out and buffer names, the scale bar's)
    lies inside its panel and overlaps no other; the keys sit below the panels; the title
    names a zoom box only when one is drawn."""
    from mars_pairs.viz.common import pyplot
    from mars_pairs.viz.overview import overview_figure

    fig = overview_figure(dataset, colour_by="split")
    try:
        fig.canvas.draw()
        full, near = fig.axes[:2]
        assert any(t.get_text().startswith("sol ") for t in near.texts)
        for ax in (full, near):
            frame = ax.get_window_extent()
            boxes = _extents(fig, [t for t in ax.texts if t.get_visible() and t.get_text()])
            for i, a in enumerate(boxes):
                assert frame.x0 <= a.x0 and a.x1 <= frame.x1, ax.texts[i].get_text()
                assert frame.y0 <= a.y0 and a.y1 <= frame.y1, ax.texts[i].get_text()
                for b in boxes[i + 1 :]:
                    assert not a.overlaps(b), (a, b)
            legend = ax.get_legend()
            if legend is not None:  # below the panel, over none of the map
                assert legend.get_window_extent().y1 <= frame.y0
        cyan = [ln for ln in full.lines if ln.get_color() == "cyan"]
        assert ("cyan" in near.get_title()) == bool(cyan)
    finally:
        pyplot().close(fig)


def test_the_scale_bar_goes_to_a_corner_the_data_leave_free() -> None:
    import shapely

    from mars_pairs.viz.map import quiet_corner

    box = (0.0, 0.0, 100.0, 100.0)
    assert quiet_corner(box, shapely.box(0, 0, 20, 20)) != "lower left"
    busy = shapely.union_all([shapely.box(0, 0, 20, 20), shapely.box(80, 0, 100, 20)])
    assert quiet_corner(box, busy) in ("upper left", "upper right")
    assert quiet_corner(box, shapely.Polygon()) == "lower left"


def test_overview_and_report_take_a_dpi(dataset: Path, tmp_path: Path) -> None:
    from PIL import Image

    from mars_pairs.cli.main import main
    from mars_pairs.viz.common import OVERVIEW_SIZE

    out = tmp_path / "o.png"
    assert main(["overview", str(dataset), "--out", str(out), "--dpi", "40"]) == 0
    with Image.open(out) as im:
        assert im.size == (round(OVERVIEW_SIZE[0] * 40), round(OVERVIEW_SIZE[1] * 40))
    page = tmp_path / "r.html"
    assert main(["report", str(dataset), "--out", str(page), "--samples", "0", "--dpi", "30"]) == 0
    small = page.stat().st_size
    assert main(["report", str(dataset), "--out", str(page), "--samples", "0", "--dpi", "90"]) == 0
    assert page.stat().st_size > small
