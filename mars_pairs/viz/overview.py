"""The picture of a dataset: every footprint over the downsampled ortho, the traverse and
the held-out areas, in the dataset CRS (map units)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import shapely

from mars_pairs.errors import MarsPairsError
from mars_pairs.store.beside import beside, outside
from mars_pairs.store.dataset_info import read_dataset_info
from mars_pairs.store.geoparquet import describe_crs
from mars_pairs.store.query import Manifest
from mars_pairs.viz.common import (
    DPI,
    OVERVIEW_SIZE,
    SPLIT_COLOURS,
    manifest_rows,
    pyplot,
    sol_colours,
    split_colours,
)
from mars_pairs.viz.map import (
    draw_background,
    draw_held_out,
    draw_traverse,
    frame_panel,
    held_out_legend,
    held_out_regions,
    label_stops_apart,
    mark_zoom,
    quiet_corner,
    square,
    traverse_stops,
)

OVERVIEW_SUFFIX = "overview.png"  # the default picture: <dataset>-overview.png beside the folder


def overview(
    root: str | Path,
    out: str | Path | None = None,
    ortho_path: str | Path | None = None,
    colour_by: str = "sol",
    max_px: int = 1400,
    dpi: int = DPI,
) -> Path:
    """All footprints over a downsampled ortho with the rover traverse and the held-out areas
    (:func:`overview_figure`; of a footprint catalogue folder, its footprints and pairs:
    ``catalog_map.catalog_figure``, ``colour_by`` sol or instrument), written to ``out``
    (default ``<root>-overview.png`` beside the folder: ``store.beside``; a path inside the
    folder is refused): a PNG of ``OVERVIEW_SIZE`` inches at ``dpi``."""
    from mars_pairs.viz.catalog_map import catalog_figure, is_catalog

    plt = pyplot()
    out = beside(root, OVERVIEW_SUFFIX) if out is None else outside(root, out, OVERVIEW_SUFFIX)
    draw = catalog_figure if is_catalog(root) else overview_figure
    fig = draw(root, ortho_path, colour_by=colour_by, max_px=max_px)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi)
    finally:
        plt.close(fig)
    return out


def overview_figure(
    root: str | Path,
    ortho_path: str | Path | None = None,
    colour_by: str = "sol",
    max_px: int = 1400,
) -> Any:
    """The matplotlib Figure of a dataset on the map (dataset CRS, map units; the CRS named
    in the title, axes labelled easting/northing): every footprint coloured by sol or split
    over the downsampled ortho (``ortho_path``, default the build's ``inputs.ortho``), the
    rover traverse, a scale bar, and the held-out areas of the build's split rule (hatched,
    named) with their buffer zones (dashed), as ``mars-pairs report`` draws them. Left: the
    whole dataset; right: a zoom on the traverse."""
    if colour_by not in ("sol", "split"):
        raise MarsPairsError(f"colour_by must be 'sol' or 'split', not {colour_by!r}")
    plt = pyplot()
    root = Path(root)
    rows = manifest_rows(root)
    if not rows:
        raise MarsPairsError(f"{root}: the dataset has no samples")
    info = read_dataset_info(root, required=False)
    crs_name, unit = describe_crs(info.crs or Manifest.open(root).crs)
    ortho = Path(ortho_path) if ortho_path is not None else info.build_input(root, "ortho")
    xs = np.array([r["easting"] for r in rows], dtype=np.float64)
    ys = np.array([r["northing"] for r in rows], dtype=np.float64)
    geoms = [shapely.from_wkb(r["footprint"]) if r["footprint"] is not None else None for r in rows]
    rovers = shapely.points(xs, ys)
    assert isinstance(rovers, np.ndarray)  # arrays of x, y: an array of points
    points = list(rovers)
    everything = shapely.total_bounds([g for g in geoms if g is not None] + points)
    full = square(tuple(everything), pad=0.06, min_side=50.0)
    near = square((xs.min(), ys.min(), xs.max(), ys.max()), pad=0.25, min_side=60.0)
    stops = traverse_stops(rows)

    colour, legend = _colours(plt, rows, colour_by)
    fig, (ax_full, ax_near) = plt.subplots(1, 2, figsize=OVERVIEW_SIZE, layout="constrained")
    held_handles: list[Any] = []
    drawn = [g for g in geoms if g is not None]
    for ax, box in ((ax_full, full), (ax_near, near)):
        background = draw_background(ax, ortho, box, max_px)
        order = sorted(range(len(rows)), key=lambda i: -(g.area if (g := geoms[i]) else 0.0))
        for i in order:
            if geoms[i] is None:
                continue
            for poly in getattr(geoms[i], "geoms", [geoms[i]]):
                gx, gy = poly.exterior.xy
                ax.fill(gx, gy, color=colour[i], alpha=0.3, lw=0)
                ax.plot(gx, gy, color=colour[i], lw=1.1)
        held = held_out_regions(info, box)
        found = draw_held_out(
            ax, held, SPLIT_COLOURS, label=_few_regions(held.regions, box), box=box
        )
        held_handles = held_handles or found
        draw_traverse(ax, stops, zorder=None)
        # the scale bar in the corner the footprints, positions and held-out areas leave free
        busy = shapely.union_all(
            [*drawn, *(shapely.buffer(p, 0.02 * (box[2] - box[0])) for p in points),
             *(c for cells in held.regions.values() for c in cells)]
        )  # fmt: skip
        frame_panel(ax, box, unit, background, corner=quiet_corner(box, busy))
    zoomed = mark_zoom(ax_full, near, full)
    # the keys below the panels, where they cover no part of the map
    legend(ax_full, ax_near)
    held_out_legend(ax_near, held_handles)
    for ax in (ax_full, ax_near):
        _below(ax)
    ax_full.set_title(
        f"{len(rows)} samples: footprints coloured by {colour_by}, rover traverse (white)",
        fontsize=10,
    )
    named = "held-out areas hatched, buffer zones dashed" if held_handles else "no held-out area"
    where = ", cyan box on the left" if zoomed else ""
    ax_near.set_title(
        f"the traverse ({len(set(zip(xs, ys, strict=True)))} rover positions{where}); {named}",
        fontsize=10,
    )
    fig.suptitle(f"map CRS: {crs_name}", fontsize=10)
    label_stops_apart(ax_near, stops)  # last: it needs the settled layout
    return fig


def _below(ax: Any) -> None:
    """The panel's legend moved below it (outside the map; the layout makes room)."""
    old = ax.get_legend()
    if old is None:
        return
    handles, title = old.legend_handles, old.get_title().get_text()
    labels = [t.get_text() for t in old.get_texts()]
    old.remove()
    ax.legend(
        handles, labels, title=title or None, loc="upper center", bbox_to_anchor=(0.5, -0.08),
        ncols=min(len(labels), 4), fontsize=8, title_fontsize=8, frameon=False,
    )  # fmt: skip


MAX_NAMED_REGIONS = 12  # more held-out regions on a panel: named in the legend only


def _few_regions(regions: dict[str, list[Any]], box: tuple[float, float, float, float]) -> bool:
    """Whether the held-out regions (merged per split) meeting the panel ``box`` (map units)
    are few enough to be named on the map."""
    frame = shapely.box(*box)
    count = 0
    for cells in regions.values():
        union = shapely.intersection(shapely.union_all(cells), frame)
        count += len(getattr(union, "geoms", [union])) if not union.is_empty else 0
    return count <= MAX_NAMED_REGIONS


def _colours(plt: Any, rows: list[dict[str, Any]], colour_by: str) -> tuple[list[Any], Any]:
    """A colour per row and a function drawing the key (colour bar or legend)."""
    if colour_by == "sol":
        return sol_colours(plt, [r["sol"] for r in rows])
    values = [str(r["split"]) for r in rows]
    palette = split_colours(values)

    def legend(ax: Any, other: Any) -> None:
        for v, c in palette.items():
            ax.plot([], [], "s", color=c, label=f"{v} ({values.count(v)})")
        ax.legend(loc="upper right", fontsize=8, title="split", title_fontsize=8)

    return [palette[v] for v in values], legend
