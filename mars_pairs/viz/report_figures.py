"""The figures of ``mars-pairs report``: the map, the histograms and one gallery card.

Each function returns PNG bytes. Map coordinates are the dataset CRS (map units, metres for
the projected CRSs a build accepts); areas and ranges of the manifest are true metres.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
import shapely

from mars_pairs.store.dataset_info import DatasetInfo
from mars_pairs.viz.common import DPI, png_bytes, pyplot, split_colours
from mars_pairs.viz.map import (
    draw_background,
    draw_held_out,
    draw_traverse,
    frame_panel,
    held_out_legend,
    held_out_regions,
    label_stops_apart,
    mark_zoom,
    rings,
    square,
    traverse_stops,
)
from mars_pairs.viz.sample import (
    apply_affine,
    display_arrays,
    draw_ortho_panel,
    invert_affine,
    wedge_pixels,
)

# -- the map ------------------------------------------------------------------------------------


def map_figure(
    rows: list[dict[str, Any]],
    info: DatasetInfo,
    ortho: Path | None,
    crs_name: str,
    unit: str,
    max_px: int = 1400,
    dpi: int = DPI,
) -> bytes:
    """Two map panels over the ortho (``rows``: manifest rows with easting, northing, sol,
    site, drive, split, footprint): every footprint, and a zoom on the traverse with the
    held-out areas and the buffer. Map CRS, ``unit`` per axis unit; PNG bytes."""
    from matplotlib.artist import Artist
    from matplotlib.collections import PolyCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    plt = pyplot()
    xs = np.array([r["easting"] for r in rows], dtype=np.float64)
    ys = np.array([r["northing"] for r in rows], dtype=np.float64)
    feet = [shapely.from_wkb(r["footprint"]) if r["footprint"] is not None else None for r in rows]
    colours = split_colours([str(r["split"]) for r in rows])
    rovers = shapely.points(xs, ys)
    assert isinstance(rovers, np.ndarray)  # arrays of x, y: an array of points
    shapes = [g for g in feet if g is not None] + list(rovers)
    full = square(tuple(shapely.total_bounds(shapes)), pad=0.06, min_side=50.0)
    held_full = held_out_regions(info, full)
    near_parts = list(rovers)
    for cells in held_full.regions.values():
        union = shapely.union_all(cells)
        zone = shapely.buffer(union, held_full.zone) if held_full.zone else union
        near_parts.append(shapely.intersection(zone, shapely.box(*full)))
    near_parts = [g for g in near_parts if not g.is_empty]
    near = square(tuple(shapely.total_bounds(near_parts)), pad=0.08, min_side=60.0)
    held_near = held_out_regions(info, near)

    fig, (ax_full, ax_near) = plt.subplots(1, 2, figsize=(16.0, 8.4), layout="constrained")
    order = sorted(range(len(rows)), key=lambda i: -(g.area if (g := feet[i]) else 0.0))
    polys, faces = [], []
    for i in order:
        for ring in rings(feet[i]) if feet[i] is not None else []:
            polys.append(ring)
            faces.append(colours[str(rows[i]["split"])])
    handles: list[Any] = []
    stops = traverse_stops(rows)
    for ax, box, held in ((ax_full, full, held_full), (ax_near, near, held_near)):
        background = draw_background(ax, ortho, box, max_px)
        if polys:
            ax.add_collection(PolyCollection(polys, facecolors=faces, alpha=0.22, lw=0))
            ax.add_collection(PolyCollection(polys, facecolors="none", edgecolors=faces, lw=1.2))
        found = draw_held_out(ax, held, colours, label=ax is ax_near, box=box)
        if ax is ax_near:
            handles = found
        draw_traverse(ax, stops, zorder=5)
        frame_panel(ax, box, unit, background)
    mark_zoom(ax_full, near, full)
    counts = {s: sum(1 for r in rows if str(r["split"]) == s) for s in colours}
    legend: list[Artist] = [Patch(facecolor=c, alpha=0.6, label=f"footprints: {s} ({counts[s]})")
              for s, c in colours.items()]  # fmt: skip
    legend.append(
        Line2D([], [], color="white", marker="^", markerfacecolor="red", markeredgecolor="white",
               lw=1.8, label="rover positions and traverse")
    )  # fmt: skip
    ax_full.legend(handles=legend, loc="upper right", fontsize=8, framealpha=0.85)
    held_out_legend(ax_near, handles)
    ax_full.set_title(f"{len(rows)} footprints coloured by split over the orthoimage", fontsize=10)
    fig.suptitle(f"map CRS: {crs_name}", fontsize=10)
    title = "the traverse (cyan box): held-out areas (hatched) and their buffer zones (dashed)"
    if held_near.note or held_full.note:
        title = f"the traverse (cyan box); {held_near.note or held_full.note}"
    elif not held_near.regions:
        title = "the traverse (cyan box); no held-out area on this panel"
    ax_near.set_title(title, fontsize=10)
    label_stops_apart(ax_near, stops)  # last: it needs the settled layout
    return png_bytes(fig, dpi)


# -- histograms ---------------------------------------------------------------------------------


def histograms_figure(rows: list[dict[str, Any]], dpi: int = DPI) -> bytes:
    """Four histograms stacked by split: farthest visible range (m), footprint area (map
    units squared), visible area (true m2) and camera elevation angle (degrees); PNG."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    splits = [str(r["split"]) for r in rows]
    colours = split_colours(splits)
    feet = [shapely.from_wkb(r["footprint"]) if r["footprint"] is not None else None for r in rows]
    values = {
        "farthest visible range (m)": [r.get("max_visible_range_m") for r in rows],
        "footprint area (m², map)": [None if g is None else float(g.area) for g in feet],
        "visible (viewshed) area (m²)": [r.get("viewshed_area_m2") for r in rows],
        "camera elevation angle (°)": [r.get("elevation_deg") for r in rows],
    }
    fig, axes = plt.subplots(1, 4, figsize=(16.0, 3.4), layout="constrained")
    for ax, (title, vals) in zip(axes, values.items(), strict=True):
        per_split, labels, cols = [], [], []
        for name, colour in colours.items():
            v = [float(x) for x, s in zip(vals, splits, strict=True) if s == name and _finite(x)]
            per_split.append(v)
            labels.append(name)
            cols.append(colour)
        shown = sum(len(v) for v in per_split)
        missing = len(vals) - shown
        if shown:
            every = np.concatenate([np.asarray(v) for v in per_split if v])
            lo, hi = float(every.min()), float(every.max())
            edges = np.linspace(lo, hi if hi > lo else lo + 1.0, 21)
            ax.hist(per_split, bins=edges, stacked=True, color=cols, label=labels,
                    edgecolor="white", lw=0.4)  # fmt: skip
        else:
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(title, fontsize=9)
        ax.set_ylabel("samples", fontsize=9)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 5), useOffset=False)
        ax.tick_params(labelsize=8)
        ax.set_title(f"{shown} samples" + (f", {missing} without a value" if missing else ""),
                     fontsize=9)  # fmt: skip
    if rows:
        axes[0].legend(fontsize=8, title="split", title_fontsize=8)
    return png_bytes(fig, dpi)


def _finite(x: Any) -> TypeGuard[float]:
    return x is not None and math.isfinite(float(x))


# -- a gallery card ------------------------------------------------------------------------------


def sample_card(
    sample: dict[str, Any], camera_center_map: list[float] | None = None, dpi: int = DPI
) -> bytes:
    """One sample (a :class:`MarsPairsDataset` item with ground, ortho, viewshed): its ground
    image beside its ortho chip with the viewshed (green), the camera wedge (from
    ``camera_center_map``, map x, y of the dataset CRS, when given, else the rover origin) and
    the rover."""
    plt = pyplot()
    row = dict(sample.get("meta") or {})
    if camera_center_map is not None:
        row["camera_center_map"] = camera_center_map
    parts = display_arrays(sample)
    ground, ortho, vis = parts["ground"], parts["ortho"], parts["viewshed"]
    ratio = ground.shape[1] / ground.shape[0] if ground is not None else 1.0
    fig, (ax_g, ax_o) = plt.subplots(
        1, 2, figsize=(2.9 * (ratio + 1) + 0.3, 3.2), gridspec_kw={"width_ratios": [ratio, 1]},
        layout="constrained",
    )  # fmt: skip
    if ground is not None:
        ax_g.imshow(ground)
    ax_g.set_title("ground image", fontsize=9)
    if ortho is not None:
        transform = [float(v) for v in np.asarray(sample["transform"])[:6]]
        inv = invert_affine(transform)
        origin = [row.get("easting", np.nan), row.get("northing", np.nan)]
        rover = apply_affine(inv, *origin)
        if vis is None:
            vis = np.zeros(ortho.shape, dtype=bool)
        draw_ortho_panel(ax_o, ortho, vis, rover, wedge_pixels(row, inv))
        size = ortho.shape[1] * float(np.hypot(transform[0], transform[3]))
        ax_o.set_title(f"ortho chip {size:.0f} m: viewshed, wedge", fontsize=9)
    for ax in (ax_g, ax_o):
        ax.set_xticks([])
        ax.set_yticks([])
    return png_bytes(fig, dpi)
