"""The map panels of the overview and the report: the dataset CRS (map units), the ortho
as background, the rover traverse, the held-out areas of the split rule and their buffer
zones. Each function draws on a matplotlib Axes whose data coordinates are map x, y."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from mars_pairs.store.dataset_info import DatasetInfo
from mars_pairs.store.splits import TRAIN, SplitRule
from mars_pairs.viz.common import SPLIT_COLOURS, map_axes

MAX_BLOCKS_DRAWN = 2500  # same-area blocks tested for held-out ones inside a map panel
MAX_LABELLED_STOPS = 1000  # more rover stops on a panel: no sol labels

Box = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax in map units


def square(bounds: tuple[float, ...], pad: float, min_side: float) -> Box:
    """A square box (map units) around ``bounds`` (xmin, ymin, xmax, ymax), padded by ``pad``
    of its side, at least ``min_side`` before padding."""
    side = max(bounds[2] - bounds[0], bounds[3] - bounds[1], min_side) * (1 + 2 * pad)
    cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
    return (cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)


def ortho_window(
    path: Path | None, bounds: Box, max_px: int
) -> tuple[np.ndarray | None, tuple[float, float, float, float]]:
    """A decimated read (at most ``max_px`` pixels a side) of the ortho at ``path`` where it
    overlaps ``bounds`` (map units of the ortho's CRS): (masked image or None, imshow extent
    (west, east, south, north))."""
    empty = (bounds[0], bounds[2], bounds[1], bounds[3])
    if path is None or not path.is_file():
        return None, empty
    import rasterio
    from rasterio.windows import Window, from_bounds
    from rasterio.windows import bounds as window_bounds

    with rasterio.open(path) as src:
        window = from_bounds(*bounds, transform=src.transform)
        full = Window(0, 0, src.width, src.height)
        try:
            window = window.intersection(full)
        except Exception:  # no overlap
            return None, empty
        if window.width < 1 or window.height < 1:
            return None, empty
        scale = max(window.width, window.height, 1) / max_px
        shape = (
            max(1, round(window.height / max(scale, 1))),
            max(1, round(window.width / max(scale, 1))),
        )
        image = src.read(1, window=window, out_shape=shape, masked=True)
        w, s, e, n = window_bounds(window, src.transform)
    return image, (w, e, s, n)


def draw_background(ax: Any, ortho: Path | None, box: Box, max_px: int) -> bool:
    """A grey panel with the ortho (:func:`ortho_window`) over ``box``; whether the ortho
    was found there."""
    ax.set_facecolor("#d9d9d9")
    image, extent = ortho_window(ortho, box, max_px)
    if image is not None:
        ax.imshow(image, cmap="gray", extent=extent, vmin=0, vmax=255, interpolation="bilinear")
    return image is not None


def frame_panel(ax: Any, box: Box, unit: str, background: bool, corner: str = "lower left") -> None:
    """The panel's limits, axes and scale bar (:func:`map_axes`; in ``corner``), and a note
    when the ortho (``background``) was not found."""
    map_axes(ax, box, unit, corner)
    if not background:
        ax.text(0.5, 0.02, "orthoimage not found: no background", transform=ax.transAxes,
                ha="center", fontsize=9)  # fmt: skip


def mark_zoom(ax: Any, near: Box, full: Box) -> bool:
    """The zoom panel's box ``near`` drawn (cyan, dashed) on the panel showing ``full``, when
    it is smaller; whether it was drawn."""
    if near[2] - near[0] < full[2] - full[0]:
        x0, y0, x1, y1 = near
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="cyan", lw=1, ls="--")
        return True
    return False


def quiet_corner(box: Box, busy: Any, size: float = 0.3) -> str:
    """The corner (``lower left``, ``lower right``, ``upper left``, ``upper right``) of the
    panel ``box`` (map units) whose square of ``size`` of the panel's side meets the least of
    the geometry ``busy`` (map units: what a scale bar or a note should not cover)."""
    x0, y0, x1, y1 = box
    side = size * max(x1 - x0, y1 - y0)
    corners = {
        "lower left": shapely.box(x0, y0, x0 + side, y0 + side),
        "lower right": shapely.box(x1 - side, y0, x1, y0 + side),
        "upper left": shapely.box(x0, y1 - side, x0 + side, y1),
        "upper right": shapely.box(x1 - side, y1 - side, x1, y1),
    }
    if busy is None or busy.is_empty:
        return "lower left"
    return min(corners, key=lambda c: shapely.intersection(corners[c], busy).area)


def label_stops_apart(ax: Any, stops: list[tuple[float, float, Any]], pad_px: float = 3.0) -> int:
    """ "sol N" beside stops of the traverse (map x, y), each label only where it overlaps no
    label already placed (display pixels, ``pad_px`` apart) and lies inside the panel: the
    first and last stop first, then the others in order. Draws the figure once to know where
    the text lands (call it after everything else of the panel's layout); the labels take no
    part in the layout. Returns the count placed."""
    import matplotlib.patheffects as pe

    if not stops or len(stops) > MAX_LABELLED_STOPS:
        return 0
    fig = ax.figure
    fig.canvas.draw()  # the layout settled: display positions are final
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    order = [0, len(stops) - 1, *range(1, len(stops) - 1)] if len(stops) > 1 else [0]
    taken = [t.get_window_extent(renderer) for t in ax.texts if t.get_visible()]  # names
    placed: list[Any] = []
    shown: set[Any] = set()
    for i in order:
        x, y, sol = stops[i]
        if sol in shown:
            continue
        text = ax.annotate(
            f"sol {sol}", (x, y), xytext=(6, 4), textcoords="offset points", fontsize=8,
            color="white", zorder=6,
            path_effects=[pe.withStroke(linewidth=2.5, foreground="black")],
        )  # fmt: skip
        text.set_in_layout(False)
        bbox = text.get_window_extent(renderer).expanded(1.0, 1.0)
        padded = bbox.padded(pad_px)
        inside = (
            bbox.x0 >= frame.x0
            and bbox.x1 <= frame.x1
            and bbox.y0 >= frame.y0
            and bbox.y1 <= frame.y1
        )
        if not inside or any(padded.overlaps(other) for other in (*taken, *placed)):
            text.remove()
            continue
        placed.append(bbox)
        shown.add(sol)
    return len(placed)


# -- the traverse --------------------------------------------------------------------------------


def traverse_stops(rows: list[dict[str, Any]]) -> list[tuple[float, float, Any]]:
    """The rover positions of manifest ``rows`` (easting, northing in map units; sol) in
    (sol, site, drive) order, a position repeated by consecutive rows kept once."""
    order = sorted(rows, key=lambda r: (r["sol"] or 0, r["site"] or 0, r["drive"] or 0))
    stops: list[tuple[float, float, Any]] = []
    for r in order:
        x, y = float(r["easting"]), float(r["northing"])
        if not stops or (x, y) != stops[-1][:2]:
            stops.append((x, y, r["sol"]))
    return stops


def draw_traverse(ax: Any, stops: list[tuple[float, float, Any]], zorder: float | None) -> None:
    """The rover traverse: ``stops`` (map x, y) joined by a white line, red triangles;
    ``zorder`` None draws at matplotlib's default order."""
    import matplotlib.patheffects as pe

    px, py = [s[0] for s in stops], [s[1] for s in stops]
    outline = [pe.Stroke(linewidth=3.2, foreground="black"), pe.Normal()]
    z = {} if zorder is None else {"zorder": zorder}
    ax.plot(px, py, "-", color="white", lw=1.8, path_effects=outline, **z)
    ax.plot(px, py, "^", color="red", markersize=7, markeredgecolor="white", ls="none", **z)


# -- held-out areas ------------------------------------------------------------------------------


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


def held_out_regions(info: DatasetInfo, box: Box) -> HeldOut:
    """The held-out regions of a build (its ``dataset.json``, ``info``) meeting the map
    ``box`` (xmin, ymin, xmax, ymax, map units): cross-area areas, or same-area held-out
    blocks."""
    cfg = info.split_config
    rep = info.splits
    reach, buffer_m = rep.get("reach_m"), rep.get("buffer_m")
    zone = float(reach) + float(buffer_m) if reach is not None and buffer_m is not None else None
    regions: dict[str, list[shapely.Polygon]] = {}
    note = ""
    if cfg.get("style") == "cross-area":
        for name, boxes in (cfg.get("areas") or {}).items():
            regions[str(name)] = [
                shapely.box(float(b[0]), float(b[1]), float(b[2]), float(b[3])) for b in boxes
            ]
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


def rings(geom: Any) -> list[np.ndarray]:
    """The exterior rings (N, 2) of a polygon or multipolygon."""
    return [np.asarray(p.exterior.coords) for p in getattr(geom, "geoms", [geom]) if not p.is_empty]


def draw_held_out(
    ax: Any, held: HeldOut, colours: dict[str, Any], label: bool, box: Box | None = None
) -> list[Any]:
    """Held-out regions (hatched, named when ``label``) and their buffer zones (dashed) in
    the split ``colours``; the legend handles. ``box``: the panel (map units), which the names
    are kept inside (a region or zone reaching past its edge is named within it)."""
    import matplotlib.patheffects as pe
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    handles: list[Any] = []
    outline = [pe.withStroke(linewidth=3, foreground="black")]
    for name, cells in held.regions.items():
        colour = colours.get(name) or SPLIT_COLOURS.get(name, "magenta")
        union = shapely.union_all(cells)
        for ring in rings(union):
            ax.add_patch(
                Polygon(ring, closed=True, facecolor="none", edgecolor=colour, hatch="///",
                        lw=1.8, zorder=4)
            )  # fmt: skip
        if held.zone:
            for ring in rings(shapely.buffer(union, held.zone, quad_segs=16)):
                ax.plot(ring[:, 0], ring[:, 1], ls="--", color="white", lw=1.6, zorder=4,
                        path_effects=outline)  # fmt: skip
        if label:
            for cell in getattr(union, "geoms", [union]):
                cx, cy = _inside(box, cell.centroid.x, cell.bounds[3], 0.04)
                ax.text(
                    cx, cy, f"{name} (held out)", ha="center", va="bottom", fontsize=8,
                    color="white", zorder=7, clip_on=True,
                    path_effects=[pe.withStroke(linewidth=2.5, foreground=colour)],
                )  # fmt: skip
            if held.zone:
                top = shapely.buffer(union, held.zone).bounds
                zx, zy = _inside(box, (top[0] + top[2]) / 2, top[3], 0.01)
                ax.text(
                    zx, zy, "buffer zone", ha="center", va="top",
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


def _inside(box: Box | None, x: float, y: float, margin: float) -> tuple[float, float]:
    """Map point (x, y) moved inside the panel ``box``: ``margin`` of its side from the top
    and bottom edges, 8 % from the sides (a label's anchor: its text stays in the panel); as it
    is when ``box`` is None."""
    if box is None:
        return x, y
    side = max(box[2] - box[0], box[3] - box[1])
    x = min(max(x, box[0] + 0.08 * side), box[2] - 0.08 * side)  # half a label's width
    return x, min(max(y, box[1] + margin * side), box[3] - margin * side)


def held_out_legend(ax: Any, handles: list[Any]) -> None:
    """The held-out areas' legend (``handles`` of :func:`draw_held_out`), lower right."""
    if handles:
        ax.legend(handles=handles, loc="lower right", fontsize=8, framealpha=0.9,
                  facecolor="#9a9a9a")  # fmt: skip
