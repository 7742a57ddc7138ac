"""The figures of ``mars-pairs report``: the map, the histograms and one gallery card.

Each function returns PNG bytes. Map coordinates are the dataset CRS (map units, metres for
the projected CRSs a build accepts); areas and ranges of the manifest are true metres.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from mars_pairs.store.splits import BUFFER, TRAIN, SplitRule
from mars_pairs.viz.common import DPI, SPLIT_COLOURS, map_axes, pyplot
from mars_pairs.viz.overview import _ortho_overview, _square

MAX_BLOCKS_DRAWN = 2500  # same-area blocks tested for held-out ones inside a map panel
MAX_LABELLED_STOPS = 1000  # more rover stops on a panel: no sol labels


def png_bytes(fig: Any, dpi: int = DPI) -> bytes:
    """The figure as PNG bytes (the figure is closed)."""
    plt = pyplot()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return buf.getvalue()


#: The report's split colours: those of the other pictures, but a buffer seen on a grey ortho.
REPORT_COLOURS = {**SPLIT_COLOURS, BUFFER: "#e377c2"}


def split_colours(splits: Sequence[str]) -> dict[str, str]:
    """A colour (#rrggbb) for every split name: the usual ones fixed, others from tab10."""
    from matplotlib.colors import to_hex

    plt = pyplot()
    extra = iter(plt.get_cmap("tab10").colors[3:])
    return {s: to_hex(REPORT_COLOURS.get(s) or next(extra, "grey")) for s in sorted(set(splits))}


# -- the map ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeldOut:
    """The held-out regions drawn on the map, per split (map CRS boxes), and the buffer.

    ``zone``: a sample of another split whose rover lies within ``zone`` map units of a
    region is in the buffer (``reach + buffer_m`` of the build's split rule); None: unknown.
    """

    regions: dict[str, list[shapely.Polygon]]
    zone: float | None
    reach: float | None
    buffer_m: float | None
    note: str = ""


def held_out_regions(info: dict[str, Any], box: tuple[float, float, float, float]) -> HeldOut:
    """The held-out regions of a build (``dataset.json`` ``info``) meeting the map ``box``
    (xmin, ymin, xmax, ymax, map units): cross-area areas, or same-area held-out blocks."""
    cfg = info.get("config", {}).get("splits", {}) or {}
    rep = info.get("splits", {}) or {}
    reach, buffer_m = rep.get("reach_m"), rep.get("buffer_m")
    zone = float(reach) + float(buffer_m) if reach is not None and buffer_m is not None else None
    regions: dict[str, list[shapely.Polygon]] = {}
    note = ""
    if cfg.get("style") == "cross-area":
        for name, boxes in (cfg.get("areas") or {}).items():
            regions[str(name)] = [shapely.box(*map(float, b)) for b in boxes]
    elif cfg.get("style") == "same-area" and cfg.get("block_m"):
        block = float(cfg["block_m"])
        rule = SplitRule(
            block_m=block, ratios=dict(cfg.get("ratios") or {}), seed=cfg.get("seed", 0)
        )
        bx0, bx1 = math.floor(box[0] / block), math.floor(box[2] / block)
        by0, by1 = math.floor(box[1] / block), math.floor(box[3] / block)
        if (bx1 - bx0 + 1) * (by1 - by0 + 1) > MAX_BLOCKS_DRAWN:
            note = f"held-out blocks of {block:g} m not drawn (too many on this map)"
        else:
            for bx in range(bx0, bx1 + 1):
                for by in range(by0, by1 + 1):
                    name = rule.home((bx + 0.5) * block, (by + 0.5) * block)
                    if name != TRAIN:
                        cell = shapely.box(
                            bx * block, by * block, (bx + 1) * block, (by + 1) * block
                        )
                        regions.setdefault(name, []).append(cell)
    return HeldOut(regions, zone, reach, buffer_m, note)


def _rings(geom: Any) -> list[np.ndarray]:
    """The exterior rings (N, 2) of a polygon or multipolygon."""
    return [np.asarray(p.exterior.coords) for p in getattr(geom, "geoms", [geom]) if not p.is_empty]


def _draw_held_out(ax: Any, held: HeldOut, colours: dict[str, Any], label: bool) -> list[Any]:
    """Held-out regions (hatched, named) and their buffer zones (dashed); legend handles."""
    import matplotlib.patheffects as pe
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    handles: list[Any] = []
    outline = [pe.withStroke(linewidth=3, foreground="black")]
    for name, cells in held.regions.items():
        colour = colours.get(name) or SPLIT_COLOURS.get(name, "magenta")
        union = shapely.union_all(cells)
        for ring in _rings(union):
            ax.add_patch(
                Polygon(ring, closed=True, facecolor="none", edgecolor=colour, hatch="///",
                        lw=1.8, zorder=4)
            )  # fmt: skip
        if held.zone:
            for ring in _rings(shapely.buffer(union, held.zone, quad_segs=16)):
                ax.plot(ring[:, 0], ring[:, 1], ls="--", color="white", lw=1.6, zorder=4,
                        path_effects=outline)  # fmt: skip
        if label:
            for cell in getattr(union, "geoms", [union]):
                cx, cy = cell.centroid.x, cell.bounds[3]
                ax.text(
                    cx, cy, f"{name} (held out)", ha="center", va="bottom", fontsize=8,
                    color="white", zorder=7, clip_on=True,
                    path_effects=[pe.withStroke(linewidth=2.5, foreground=colour)],
                )  # fmt: skip
            if held.zone:
                top = shapely.buffer(union, held.zone).bounds
                ax.text(
                    (top[0] + top[2]) / 2, top[3], "buffer zone", ha="center", va="top",
                    fontsize=8, color="white", zorder=7, clip_on=True, path_effects=outline,
                )  # fmt: skip
        handles.append(
            Patch(facecolor="none", edgecolor=colour, hatch="///", label=f"held-out area: {name}")
        )
    if held.regions and held.zone:
        handles.append(
            Line2D(
                [], [], ls="--", color="white", lw=1.6, path_effects=outline,
                label=f"buffer zone: rover within {held.zone:.0f} m (reach {held.reach:g} + "
                f"buffer {held.buffer_m:g})",
            )
        )  # fmt: skip
    return handles


def _traverse(
    ax: Any, rows: list[dict[str, Any]], box: tuple[float, float, float, float], labels: bool
) -> None:
    """The rover traverse (map CRS): positions in (sol, site, drive) order joined by a white
    line; with ``labels``, sols written where they do not crowd (3 % of the panel apart) when
    there are at most ``MAX_LABELLED_STOPS`` stops."""
    import matplotlib.patheffects as pe

    order = sorted(rows, key=lambda r: (r["sol"] or 0, r["site"] or 0, r["drive"] or 0))
    stops: list[tuple[float, float, Any]] = []
    for r in order:
        x, y = float(r["easting"]), float(r["northing"])
        if not stops or (x, y) != stops[-1][:2]:
            stops.append((x, y, r["sol"]))
    px, py = [s[0] for s in stops], [s[1] for s in stops]
    outline = [pe.Stroke(linewidth=3.2, foreground="black"), pe.Normal()]
    ax.plot(px, py, "-", color="white", lw=1.8, path_effects=outline, zorder=5)
    ax.plot(px, py, "^", color="red", markersize=7, markeredgecolor="white", ls="none", zorder=5)
    if not labels or len(stops) > MAX_LABELLED_STOPS:
        return
    gap = 0.03 * max(box[2] - box[0], box[3] - box[1])
    placed: list[tuple[float, float]] = []
    shown: set[Any] = set()
    for x, y, sol in stops:
        if sol in shown or any(math.hypot(x - a, y - b) < gap for a, b in placed):
            continue
        placed.append((x, y))
        shown.add(sol)
        ax.annotate(
            f"sol {sol}", (x, y), xytext=(-8, 0), textcoords="offset points", fontsize=8,
            ha="right", va="center", color="white", zorder=6, clip_on=True,
            path_effects=[pe.withStroke(linewidth=2.5, foreground="black")],
        )  # fmt: skip


def map_figure(
    rows: list[dict[str, Any]],
    info: dict[str, Any],
    ortho: Path | None,
    crs_name: str,
    unit: str,
    max_px: int = 1400,
) -> bytes:
    """Two map panels over the ortho (``rows``: manifest rows with easting, northing, sol,
    site, drive, split, footprint): every footprint, and a zoom on the traverse with the
    held-out areas and the buffer. Map CRS, ``unit`` per axis unit; PNG bytes."""
    from matplotlib.collections import PolyCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    plt = pyplot()
    xs = np.array([r["easting"] for r in rows], dtype=np.float64)
    ys = np.array([r["northing"] for r in rows], dtype=np.float64)
    feet = [shapely.from_wkb(r["footprint"]) if r["footprint"] is not None else None for r in rows]
    colours = split_colours([str(r["split"]) for r in rows])
    shapes = [g for g in feet if g is not None] + list(shapely.points(xs, ys))
    full = _square(tuple(shapely.total_bounds(shapes)), pad=0.06, min_side=50.0)
    held_full = held_out_regions(info, full)
    near_parts = list(shapely.points(xs, ys))
    for cells in held_full.regions.values():
        union = shapely.union_all(cells)
        zone = shapely.buffer(union, held_full.zone) if held_full.zone else union
        near_parts.append(shapely.intersection(zone, shapely.box(*full)))
    near_parts = [g for g in near_parts if not g.is_empty]
    near = _square(tuple(shapely.total_bounds(near_parts)), pad=0.08, min_side=60.0)
    held_near = held_out_regions(info, near)

    fig, (ax_full, ax_near) = plt.subplots(1, 2, figsize=(16.0, 8.4), layout="constrained")
    order = sorted(range(len(rows)), key=lambda i: -(feet[i].area if feet[i] else 0.0))
    polys, faces = [], []
    for i in order:
        for ring in _rings(feet[i]) if feet[i] is not None else []:
            polys.append(ring)
            faces.append(colours[str(rows[i]["split"])])
    handles: list[Any] = []
    for ax, box, held in ((ax_full, full, held_full), (ax_near, near, held_near)):
        ax.set_facecolor("#d9d9d9")
        image, extent = _ortho_overview(ortho, box, max_px)
        if image is not None:
            ax.imshow(image, cmap="gray", extent=extent, vmin=0, vmax=255, interpolation="bilinear")
        if polys:
            ax.add_collection(PolyCollection(polys, facecolors=faces, alpha=0.22, lw=0))
            ax.add_collection(PolyCollection(polys, facecolors="none", edgecolors=faces, lw=1.2))
        found = _draw_held_out(ax, held, colours, label=ax is ax_near)
        if ax is ax_near:
            handles = found
        _traverse(ax, rows, box, labels=ax is ax_near)
        map_axes(ax, box, unit)
        if image is None:
            ax.text(0.5, 0.02, "orthoimage not found: no background", transform=ax.transAxes,
                    ha="center", fontsize=9)  # fmt: skip
    if near[2] - near[0] < full[2] - full[0]:
        x0, y0, x1, y1 = near
        ax_full.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="cyan", lw=1, ls="--")
    counts = {s: sum(1 for r in rows if str(r["split"]) == s) for s in colours}
    legend = [Patch(facecolor=c, alpha=0.6, label=f"footprints: {s} ({counts[s]})")
              for s, c in colours.items()]  # fmt: skip
    legend.append(
        Line2D([], [], color="white", marker="^", markerfacecolor="red", markeredgecolor="white",
               lw=1.8, label="rover positions and traverse")
    )  # fmt: skip
    ax_full.legend(handles=legend, loc="upper right", fontsize=8, framealpha=0.85)
    if handles:
        ax_near.legend(handles=handles, loc="lower right", fontsize=8, framealpha=0.9,
                       facecolor="#9a9a9a")  # fmt: skip
    ax_full.set_title(f"{len(rows)} footprints coloured by split over the orthoimage", fontsize=10)
    fig.suptitle(f"map CRS: {crs_name}", fontsize=10)
    title = "the traverse (cyan box): held-out areas (hatched) and their buffer zones (dashed)"
    if held_near.note or held_full.note:
        title = f"the traverse (cyan box); {held_near.note or held_full.note}"
    elif not held_near.regions:
        title = "the traverse (cyan box); no held-out area on this panel"
    ax_near.set_title(title, fontsize=10)
    return png_bytes(fig)


# -- histograms ---------------------------------------------------------------------------------


def histograms_figure(rows: list[dict[str, Any]]) -> bytes:
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
    return png_bytes(fig)


def _finite(x: Any) -> bool:
    return x is not None and math.isfinite(float(x))


# -- a gallery card ------------------------------------------------------------------------------


def sample_card(sample: dict[str, Any], camera_center_map: list[float] | None = None) -> bytes:
    """One sample (a :class:`MarsPairsDataset` item with ground, ortho, viewshed): its ground
    image beside its ortho chip with the viewshed (green), the camera wedge (from
    ``camera_center_map``, map x, y of the dataset CRS, when given, else the rover origin) and
    the rover."""
    from mars_pairs.viz.sample import _apply, _inverse, _numpy_parts, _ortho_panel, _wedge_pixels

    plt = pyplot()
    row = dict(sample.get("meta") or {})
    if camera_center_map is not None:
        row["camera_center_map"] = camera_center_map
    parts = _numpy_parts(sample)
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
        inv = _inverse(transform)
        origin = [row.get("easting", np.nan), row.get("northing", np.nan)]
        rover = _apply(inv, *origin)
        if vis is None:
            vis = np.zeros(ortho.shape, dtype=bool)
        _ortho_panel(ax_o, ortho, vis, rover, _wedge_pixels(row, inv))
        size = ortho.shape[1] * float(np.hypot(transform[0], transform[3]))
        ax_o.set_title(f"ortho chip {size:.0f} m: viewshed, wedge", fontsize=9)
    for ax in (ax_g, ax_o):
        ax.set_xticks([])
        ax.set_yticks([])
    return png_bytes(fig)
