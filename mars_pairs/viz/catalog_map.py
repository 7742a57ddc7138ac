"""The picture of a footprint catalogue folder (``mars-pairs catalog``): every visible
footprint over the downsampled ortho, coloured by sol or instrument, and the pairs of
``pairs.parquet`` as lines between the two camera centres, in the catalogue's map CRS (map
units). Left: the whole catalogue; right: a zoom on the camera with the most pairs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import shapely

from mars_pairs.errors import DatasetError, MarsPairsError
from mars_pairs.store.catalog import catalog_ortho
from mars_pairs.store.geoparquet import describe_crs
from mars_pairs.viz.common import OVERVIEW_SIZE, pyplot, sol_colours, split_colours
from mars_pairs.viz.map import draw_background, frame_panel, mark_zoom, quiet_corner, square

COLOUR_BY = ("sol", "instrument")
ZOOM_SIDE_M = 300.0  # the zoom panel's side before padding, map units
PAIR_RGB = (1.0, 0.9, 0.0)  # the pair lines: yellow, apart from the sol and instrument colours


def is_catalog(root: str | Path) -> bool:
    """Whether ``root`` is a footprint catalogue folder (it holds catalog.parquet)."""
    return (Path(root) / "catalog.parquet").is_file()


def _pair_lines(root: Path, index: dict[str, int], xy: np.ndarray) -> tuple[np.ndarray, Any]:
    """The pairs' segments (N, 2, 2: camera centre of ``key_a`` then ``key_b``, map units)
    and their IoU."""
    path = root / "pairs.parquet"
    if not path.is_file():
        return np.zeros((0, 2, 2)), np.zeros(0)
    pairs = pq.read_table(path, columns=["key_a", "key_b", "iou"])
    a = np.array([index[k] for k in pairs["key_a"].to_pylist()], dtype=np.int64)
    b = np.array([index[k] for k in pairs["key_b"].to_pylist()], dtype=np.int64)
    return np.stack([xy[a], xy[b]], axis=1), pairs["iou"].to_numpy()


def catalog_figure(
    root: str | Path,
    ortho_path: str | Path | None = None,
    colour_by: str = "sol",
    max_px: int = 1400,
) -> Any:
    """The matplotlib Figure of catalogue ``root`` on the map (its CRS, map units, named in
    the title): footprints filled and outlined in the colour of their sol (colour bar) or
    instrument (legend), pair lines between camera centres (more opaque for a higher IoU), camera
    centres as dots, over the ortho (``ortho_path``, default the config's)."""
    from matplotlib.collections import LineCollection

    if colour_by not in COLOUR_BY:
        raise MarsPairsError(
            f"colour_by must be one of {COLOUR_BY} for a catalogue, not {colour_by!r}"
        )
    plt = pyplot()
    root = Path(root)
    table = pq.read_table(root / "catalog.parquet")
    if table.num_rows == 0:
        raise DatasetError(root, None, "the catalogue has no images")
    geo = json.loads(table.schema.metadata[b"geo"])
    crs_name, unit = describe_crs(json.dumps(geo["columns"]["footprint"]["crs"]))
    ortho = Path(ortho_path) if ortho_path is not None else catalog_ortho(root)
    keys = table["key"].to_pylist()
    xy = np.column_stack([table["camera_x"].to_numpy(), table["camera_y"].to_numpy()])
    geoms = shapely.from_wkb(table["footprint"].to_numpy(zero_copy_only=False))
    drawn = [g for g in geoms if g is not None]
    segments, iou = _pair_lines(root, {k: i for i, k in enumerate(keys)}, xy)
    colour, key = _colours(plt, table.column(colour_by).to_pylist(), colour_by)

    cameras = list(np.asarray(shapely.points(xy)))
    everything = shapely.total_bounds([*drawn, *cameras])
    full = square(tuple(everything), pad=0.04, min_side=50.0)
    degree = np.bincount(
        np.concatenate([_rows_of(segments[:, 0], xy), _rows_of(segments[:, 1], xy)]),
        minlength=len(keys),
    ) if len(segments) else np.zeros(len(keys), dtype=np.int64)  # fmt: skip
    cx, cy = xy[int(np.argmax(degree))]
    half = ZOOM_SIDE_M / 2
    near = square((cx - half, cy - half, cx + half, cy + half), pad=0.0, min_side=ZOOM_SIDE_M)

    fig, (ax_full, ax_near) = plt.subplots(1, 2, figsize=OVERVIEW_SIZE, layout="constrained")
    order = sorted(range(len(keys)), key=lambda i: -(g.area if (g := geoms[i]) else 0.0))
    for ax, box, lw in ((ax_full, full, 0.5), (ax_near, near, 1.0)):
        background = draw_background(ax, ortho, box, max_px)
        for i in order:
            if geoms[i] is None:
                continue
            for poly in getattr(geoms[i], "geoms", [geoms[i]]):
                gx, gy = poly.exterior.xy
                ax.fill(gx, gy, color=colour[i], alpha=0.25, lw=0)
                ax.plot(gx, gy, color=colour[i], lw=lw)
        if len(segments):
            alphas = 0.25 + 0.75 * np.clip(iou, 0, 1)
            colours = [(*PAIR_RGB, float(a)) for a in alphas]
            ax.add_collection(LineCollection(list(segments), colors=colours, linewidths=lw))
        ax.scatter(xy[:, 0], xy[:, 1], s=6 if ax is ax_full else 14, c="white",
                   edgecolors="black", linewidths=0.4, zorder=3)  # fmt: skip
        busy = shapely.union_all(
            [*drawn, *(shapely.buffer(c, 0.02 * (box[2] - box[0])) for c in cameras)]
        )
        frame_panel(ax, box, unit, background, corner=quiet_corner(box, busy))
    zoomed = mark_zoom(ax_full, near, full)
    key(ax_full, ax_near)
    ax_full.plot([], [], color=PAIR_RGB, label=f"pair ({len(segments)}: more opaque = higher IoU)")
    ax_full.plot([], [], "o", ms=4, mfc="white", mec="black", label="camera centre")
    ax_full.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncols=4, fontsize=8,
                   frameon=False)  # fmt: skip
    ax_full.set_title(
        f"{len(keys)} images: visible footprints coloured by {colour_by}, pairs that saw the "
        "same ground (yellow)",
        fontsize=10,
    )
    where = " (cyan box on the left)" if zoomed else ""
    ax_near.set_title(f"around the camera with the most pairs ({int(degree.max())}){where}",
                      fontsize=10)  # fmt: skip
    fig.suptitle(f"footprint catalogue, map CRS: {crs_name}", fontsize=10)
    return fig


def _rows_of(points: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The row of ``xy`` each of ``points`` (map units) is (exact: taken from ``xy``)."""
    lookup = {(float(x), float(y)): i for i, (x, y) in enumerate(xy)}
    return np.array([lookup[(float(x), float(y))] for x, y in points], dtype=np.int64)


def _colours(plt: Any, values: list[Any], colour_by: str) -> tuple[list[Any], Any]:
    """A colour per image and a function drawing the key (colour bar for sol, legend for
    instrument) on the first axes, beside the second."""
    if colour_by == "sol":
        return sol_colours(plt, values)
    names = [str(v) for v in values]
    palette = split_colours(names)

    def legend(ax: Any, other: Any) -> None:
        for name, c in palette.items():
            other.plot([], [], "s", color=c, label=f"{name} ({names.count(name)})")
        other.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncols=4, fontsize=8,
                     title="instrument", title_fontsize=8, frameon=False)  # fmt: skip

    return [palette[n] for n in names], legend
