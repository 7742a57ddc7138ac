"""The picture of a dataset: every footprint over the downsampled ortho, the traverse and
the held-out areas, in the dataset CRS (map units)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import shapely

from mars_pairs.errors import MarsPairsError
from mars_pairs.store.manifest import Manifest
from mars_pairs.viz.common import (
    DPI,
    OVERVIEW_SIZE,
    SPLIT_COLOURS,
    manifest_rows,
    map_axes,
    pyplot,
)


def overview(
    root: str | Path,
    out: str | Path,
    ortho_path: str | Path | None = None,
    colour_by: str = "sol",
    max_px: int = 1400,
    dpi: int = DPI,
) -> Path:
    """All footprints over a downsampled ortho with the rover traverse and the held-out areas
    (:func:`overview_figure`), written to ``out``: a PNG of ``OVERVIEW_SIZE`` inches at
    ``dpi``."""
    plt = pyplot()
    out = Path(out)
    fig = overview_figure(root, ortho_path, colour_by=colour_by, max_px=max_px)
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
    from mars_pairs.store.dataset_info import read_dataset_doc
    from mars_pairs.viz.report import _crs
    from mars_pairs.viz.report_figures import _draw_held_out, held_out_regions

    if colour_by not in ("sol", "split"):
        raise MarsPairsError(f"colour_by must be 'sol' or 'split', not {colour_by!r}")
    plt = pyplot()
    root = Path(root)
    rows = manifest_rows(root)
    if not rows:
        raise MarsPairsError(f"{root}: the dataset has no samples")
    info = read_dataset_doc(root, missing_ok=True)
    crs_name, unit = _crs(info, Manifest.open(root))
    if ortho_path is None:  # dataset.json's path is relative to the dataset folder
        ortho = (info.get("config") or {}).get("inputs", {}).get("ortho")
        ortho_path = Path(root) / ortho if ortho else None
    xs = np.array([r["easting"] for r in rows], dtype=np.float64)
    ys = np.array([r["northing"] for r in rows], dtype=np.float64)
    geoms = [shapely.from_wkb(r["footprint"]) if r["footprint"] is not None else None for r in rows]
    points = list(shapely.points(xs, ys))
    everything = shapely.total_bounds([g for g in geoms if g is not None] + points)
    full = _square(tuple(everything), pad=0.06, min_side=50.0)
    near = _square((xs.min(), ys.min(), xs.max(), ys.max()), pad=0.25, min_side=60.0)

    colour, legend = _colours(plt, rows, colour_by)
    fig, (ax_full, ax_near) = plt.subplots(1, 2, figsize=OVERVIEW_SIZE, layout="constrained")
    held_handles: list[Any] = []
    for ax, box in ((ax_full, full), (ax_near, near)):
        ax.set_facecolor("#d9d9d9")
        image, extent = _ortho_overview(Path(ortho_path) if ortho_path else None, box, max_px)
        if image is not None:
            ax.imshow(image, cmap="gray", extent=extent, vmin=0, vmax=255, interpolation="bilinear")
        order = sorted(range(len(rows)), key=lambda i: -(geoms[i].area if geoms[i] else 0.0))
        for i in order:
            if geoms[i] is None:
                continue
            for poly in getattr(geoms[i], "geoms", [geoms[i]]):
                gx, gy = poly.exterior.xy
                ax.fill(gx, gy, color=colour[i], alpha=0.3, lw=0)
                ax.plot(gx, gy, color=colour[i], lw=1.1)
        held = held_out_regions(info, box)
        found = _draw_held_out(ax, held, SPLIT_COLOURS, label=_few_regions(held.regions, box))
        held_handles = held_handles or found
        _traverse(ax, rows, xs, ys, label_sols=ax is ax_near)
        map_axes(ax, box, unit)
        if image is None:
            ax.text(0.5, 0.02, "orthoimage not found: no background", transform=ax.transAxes,
                    ha="center", fontsize=9)  # fmt: skip
    if near[2] - near[0] < full[2] - full[0]:
        x0, y0, x1, y1 = near
        ax_full.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="cyan", lw=1, ls="--")
    legend(ax_full, ax_near)
    if held_handles:
        ax_near.legend(handles=held_handles, loc="lower right", fontsize=8, framealpha=0.9,
                       facecolor="#9a9a9a")  # fmt: skip
    for ax in (ax_full, ax_near):
        if ax.get_legend() is not None:
            ax.get_legend().set_zorder(10)  # above the held-out areas and their names
    ax_full.set_title(
        f"{len(rows)} samples: footprints coloured by {colour_by}, rover traverse (white)",
        fontsize=10,
    )
    named = "held-out areas hatched, buffer zones dashed" if held_handles else "no held-out area"
    ax_near.set_title(
        f"the traverse ({len(set(zip(xs, ys, strict=True)))} rover positions, cyan box); {named}",
        fontsize=10,
    )
    fig.suptitle(f"map CRS: {crs_name}", fontsize=10)
    return fig


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


def _square(
    bounds: tuple[float, ...], pad: float, min_side: float
) -> tuple[float, float, float, float]:
    """A square box around ``bounds``, padded by ``pad`` of its side, at least ``min_side``."""
    side = max(bounds[2] - bounds[0], bounds[3] - bounds[1], min_side) * (1 + 2 * pad)
    cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
    return (cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)


def _colours(plt: Any, rows: list[dict[str, Any]], colour_by: str) -> tuple[list[Any], Any]:
    """A colour per row and a function drawing the key (colour bar or legend)."""
    if colour_by == "sol":
        from matplotlib.colors import Normalize
        from matplotlib.ticker import MaxNLocator

        sols = [int(r["sol"]) if r["sol"] is not None else 0 for r in rows]
        norm = Normalize(min(sols), max(max(sols), min(sols) + 1))
        cmap = plt.get_cmap("viridis")

        def key(ax: Any, other: Any) -> None:
            sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
            bar = ax.figure.colorbar(sm, ax=other, fraction=0.04, pad=0.02)
            bar.set_label("sol", fontsize=9)
            bar.ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            bar.ax.tick_params(labelsize=7)

        return [cmap(norm(s)) for s in sols], key
    values = [str(r["split"]) for r in rows]
    extra = iter(plt.get_cmap("tab10").colors[3:])
    palette = {v: SPLIT_COLOURS.get(v) or next(extra, "grey") for v in sorted(set(values))}

    def legend(ax: Any, other: Any) -> None:
        for v, c in palette.items():
            ax.plot([], [], "s", color=c, label=f"{v} ({values.count(v)})")
        ax.legend(loc="upper right", fontsize=8, title="split", title_fontsize=8)

    return [palette[v] for v in values], legend


def _traverse(
    ax: Any, rows: list[dict[str, Any]], xs: np.ndarray, ys: np.ndarray, label_sols: bool
) -> None:
    """The rover traverse: positions in (sol, site, drive) order, joined by a white line."""
    import matplotlib.patheffects as pe

    order = sorted(
        range(len(rows)), key=lambda i: (rows[i]["sol"] or 0, rows[i]["site"], rows[i]["drive"])
    )
    stops: list[tuple[float, float, Any]] = []
    for i in order:
        if not stops or (xs[i], ys[i]) != stops[-1][:2]:
            stops.append((float(xs[i]), float(ys[i]), rows[i]["sol"]))
    px, py = [s[0] for s in stops], [s[1] for s in stops]
    outline = [pe.Stroke(linewidth=3.2, foreground="black"), pe.Normal()]
    ax.plot(px, py, "-", color="white", lw=1.8, path_effects=outline)
    ax.plot(px, py, "^", color="red", markersize=7, markeredgecolor="white", ls="none")
    if label_sols:
        for x, y, sol in stops:
            ax.annotate(
                f"sol {sol}", (x, y), xytext=(6, 4), textcoords="offset points", fontsize=8,
                color="white", path_effects=[pe.withStroke(linewidth=2.5, foreground="black")],
            )  # fmt: skip


def _ortho_overview(
    path: Path | None, bounds: tuple[float, float, float, float], max_px: int
) -> tuple[np.ndarray | None, tuple[float, float, float, float]]:
    """A decimated read of the ortho where it overlaps ``bounds``: (image, imshow extent)."""
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
