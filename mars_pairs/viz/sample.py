"""The picture of one sample: ground image, ortho with viewshed and wedge, DEM, links."""

from __future__ import annotations

import colorsys
import math
import textwrap
from dataclasses import dataclass
from typing import Any

import numpy as np

from mars_pairs.viz.common import SHOW_SIZE, hillshade, pyplot, scale_bar


@dataclass(frozen=True)
class _Links:
    """Sampled keypoints: ground pixels and their map points (chip pixels), colour-linked."""

    ground: np.ndarray  # (N, 2) ground image (x, y), pixel-edge coordinates
    chip: np.ndarray  # (N, 2) chip (column, row), pixel-edge coordinates as the transform
    colours: np.ndarray  # (N, 3) RGB
    on_chip: np.ndarray  # (N,) bool
    rays: int  # strided rays cast
    hits: int  # of which hit the terrain


def keypoint_links(
    corr: np.ndarray,
    corr_ground: np.ndarray,
    ground_shape: tuple[int, ...],
    chip_shape: tuple[int, ...],
    target: tuple[int, int] = (18, 13),
) -> _Links | None:
    """About ``target`` (columns, lines) evenly spread keypoints that hit the terrain.

    ``corr`` and ``corr_ground`` are [2, h, w] (the sample's keypoints: chip column, row and
    ground x, y of each strided ray)."""
    if corr.size == 0:
        return None
    gh, gw = corr.shape[1:]
    sy, sx = max(1, math.ceil(gh / target[1])), max(1, math.ceil(gw / target[0]))
    pts = corr[:, ::sy, ::sx].reshape(2, -1).T.astype(np.float64)
    ground = corr_ground[:, ::sy, ::sx].reshape(2, -1).T.astype(np.float64)
    hit = np.all(np.isfinite(pts), axis=1) & np.all(np.isfinite(ground), axis=1)
    ground, chip = ground[hit], pts[hit]
    on_chip = (
        (chip[:, 0] >= 0)
        & (chip[:, 1] >= 0)
        & (chip[:, 0] <= chip_shape[1])
        & (chip[:, 1] <= chip_shape[0])
    )
    height, width = max(ground_shape[0], 1), max(ground_shape[1], 1)
    colours = _colour_wheel(
        np.clip(ground[:, 0] / width, 0, 1), np.clip(ground[:, 1] / height, 0, 1)
    )
    all_hits = int(np.all(np.isfinite(corr.reshape(2, -1)), axis=0).sum())
    return _Links(ground - 0.5, chip, colours, on_chip, gh * gw, all_hits)


def _colour_wheel(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """RGB colours: hue from the column, brightness from the line (top dark, bottom bright)."""
    rgb = [
        colorsys.hsv_to_rgb(float(a) * 0.85, 0.95, 0.4 + 0.6 * float(b))
        for a, b in zip(u, v, strict=True)
    ]
    return np.array(rgb, dtype=np.float64).reshape(-1, 3)


def invert_affine(t: list[float]) -> tuple[float, ...]:
    """The inverse of the affine ``t`` (a, b, c, d, e, f as GDAL's x = a col + b row + c,
    y = d col + e row + f): the map (x, y, map units) -> chip pixel (column, row) affine of a
    chip ``transform``."""
    a, b, c, d, e, f = t
    det = a * e - b * d
    return (e / det, -b / det, (b * f - c * e) / det, -d / det, a / det, (c * d - a * f) / det)


def apply_affine(t: tuple[float, ...], x: Any, y: Any) -> tuple[Any, Any]:
    """The affine ``t`` (a, b, c, d, e, f) applied to ``x``, ``y`` (scalars or arrays, the
    frame ``t`` maps from): (a x + b y + c, d x + e y + f)."""
    a, b, c, d, e, f = t
    return a * np.asarray(x) + b * np.asarray(y) + c, d * np.asarray(x) + e * np.asarray(y) + f


def wedge_apex(row: dict[str, Any]) -> tuple[float, float, bool]:
    """Where a sample's camera wedge starts, map x, y (dataset CRS, map units): the camera
    centre (``camera_center_map`` of the sample's meta.json, ~1 m from the rover origin on a
    mast) when the row has it, else the rover origin (``easting``, ``northing``); and whether
    it is the camera centre."""
    centre = row.get("camera_center_map")
    if centre is not None and len(centre) >= 2 and np.all(np.isfinite(centre[:2])):
        return float(centre[0]), float(centre[1]), True
    return float(row.get("easting", np.nan)), float(row.get("northing", np.nan)), False


def wedge_ring(
    apex: tuple[float, float], azimuth_deg: float, hfov_deg: float, range_m: float, n: int = 33
) -> tuple[np.ndarray, np.ndarray]:
    """The camera's azimuth wedge (``azimuth_deg`` +/- ``hfov_deg``/2, degrees clockwise from
    north) from ``apex`` (map x, y, map units of a projected CRS in metres) out to
    ``range_m``, as a closed ring of map x, y: the apex, ``n`` points on the arc, the apex."""
    half = hfov_deg / 2
    az = np.radians(np.linspace(azimuth_deg - half, azimuth_deg + half, n))
    x = np.concatenate([[apex[0]], apex[0] + range_m * np.sin(az), [apex[0]]])
    y = np.concatenate([[apex[1]], apex[1] + range_m * np.cos(az), [apex[1]]])
    return x, y


def wedge_pixels(row: dict[str, Any], inv: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The camera's wedge (``wedge_ring`` from ``wedge_apex``) to the farthest visible range,
    as a closed ring of chip pixel coordinates (``inv``: map -> chip pixel affine)."""
    x0, y0, _ = wedge_apex(row)
    rng = max(float(row.get("max_visible_range_m") or 0.0), 1.0)
    ring = wedge_ring(
        (x0, y0), float(row.get("azimuth_deg") or 0.0), float(row.get("hfov_deg") or 0.0), rng
    )
    return apply_affine(inv, *ring)


def _limits(ax: Any, box: tuple[float, float, float, float]) -> None:
    ax.set_xlim(box[0], box[2])
    ax.set_ylim(box[3], box[1])


def draw_ortho_panel(
    ax: Any,
    ortho: np.ndarray,
    vis: np.ndarray,
    rover: tuple[float, float],
    wedge: tuple[np.ndarray, np.ndarray],
    alpha: float = 0.45,
) -> None:
    """The ortho chip with the viewshed (green), the camera wedge and the rover."""
    n_rows, n_cols = ortho.shape[:2]
    extent = (0, n_cols, n_rows, 0)  # pixel-edge coordinates, as the chip transform
    ax.imshow(ortho, cmap="gray", vmin=0, vmax=255, extent=extent, interpolation="nearest")
    overlay = np.zeros((*vis.shape, 4))
    overlay[vis] = (0.1, 0.95, 0.3, alpha)
    ax.imshow(overlay, extent=extent, interpolation="nearest")
    ax.plot(*wedge, color="orange", lw=1.3)
    ax.plot(*rover, marker="^", color="red", markersize=9, markeredgecolor="white", ls="none")
    ax.plot(wedge[0][0], wedge[1][0], marker="o", color="orange", markersize=4, ls="none")
    _limits(ax, (0, 0, n_cols, n_rows))


def _zoom_box(
    vis: np.ndarray,
    rover: tuple[float, float],
    links: _Links | None,
    n: int,
    min_px: float = 32.0,
) -> tuple[float, float, float, float] | None:
    """A square (x0, y0, x1, y1) in chip pixels around the viewshed, the map points and the
    rover; None when it would cover most of the chip anyway."""
    rows, cols = np.nonzero(vis)
    xs = [cols + 0.5, np.array([rover[0]])]
    ys = [rows + 0.5, np.array([rover[1]])]
    if links is not None and links.on_chip.any():
        xs.append(links.chip[links.on_chip, 0])
        ys.append(links.chip[links.on_chip, 1])
    x, y = np.concatenate(xs), np.concatenate(ys)
    x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
    side = max(x1 - x0, y1 - y0) * 1.25 + 6.0
    side = max(side, min_px)
    if side > 0.7 * n:
        return None
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    cx = min(max(cx, side / 2), n - side / 2)
    cy = min(max(cy, side / 2), n - side / 2)
    return (cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)


def _north_arrow(ax: Any, inv: tuple[float, ...], n: int) -> None:
    """A north arrow in the top-left corner of a chip panel."""
    dx, dy = inv[1], inv[4]  # chip pixels per map unit northwards
    norm = math.hypot(dx, dy) or 1.0
    length = 0.08 * n
    x0, y0 = 0.07 * n - dx / norm * length / 2, 0.1 * n - dy / norm * length / 2
    x1, y1 = x0 + dx / norm * length, y0 + dy / norm * length
    ax.annotate(
        "N",
        xy=(x1, y1),
        xytext=(x0, y0),
        color="white",
        fontsize=9,
        ha="center",
        va="center",
        arrowprops={"arrowstyle": "->", "color": "white", "lw": 1.5},
    )


def _draw_links(ground_ax: Any, map_ax: Any, links: _Links | None) -> None:
    """Ground pixels over the image and their map points over the ortho, same colours."""
    if links is None or len(links.chip) == 0:
        return
    on, off = links.on_chip, ~links.on_chip
    ground_ax.scatter(
        *links.ground[on].T, c=links.colours[on], s=16, edgecolors="black", linewidths=0.4
    )
    if off.any():  # map points beyond the chip: hollow rings on the ground image
        ground_ax.scatter(
            *links.ground[off].T, facecolors="none", edgecolors=links.colours[off], s=16,
            linewidths=0.9,
        )  # fmt: skip
    map_ax.scatter(*links.chip[on].T, c=links.colours[on], s=16, edgecolors="black", linewidths=0.4)


def _info_lines(
    row: dict[str, Any], res: float, rotation: float, links: _Links | None
) -> list[list[str]]:
    """The sample's numbers, as three columns of short lines."""

    def num(name: str, fmt: str) -> str:
        value = row.get(name)
        return "?" if value is None else format(value, fmt)

    elevation = row.get("elevation_m", row.get("elevation"))
    where = [
        f"{row.get('mission')}  {row.get('instrument')}   split {row.get('split')}",
        f"sol {row.get('sol')}   site {row.get('site')}   drive {row.get('drive')}",
        f"rover  E {num('easting', '.1f')}  N {num('northing', '.1f')}",
        f"lat {num('latitude', '.6f')}  lon {num('longitude', '.6f')}",
        f"elevation {'?' if elevation is None else format(elevation, '.1f')} m  "
        f"({row.get('localization')})",
    ]
    view = [
        f"camera  az {num('azimuth_deg', '.1f')}°  el {num('elevation_deg', '.1f')}°",
        f"FOV  {num('hfov_deg', '.1f')}° x {num('vfov_deg', '.1f')}°",
        f"viewshed  {row.get('visible_cells')} cells, {num('viewshed_area_m2', '.0f')} m²",
        f"farthest visible  {num('max_visible_range_m', '.0f')} m",
        f"chip  {res:.2f} m/px, rotation {rotation:.0f}°",
    ]
    if links is not None:
        shown = f"links  {int(links.on_chip.sum())} on the chip"
        if not links.on_chip.all():
            shown += f", {int((~links.on_chip).sum())} beyond (rings)"
        keypoints = [
            f"rays  {links.hits} of {links.rays} hit the terrain",
            shown,
            "colour: hue = image column,",
            "brightness = image line",
        ]
    else:
        keypoints = ["no keypoints: read the corr field", "(fields=ALL_FIELDS) to draw them"]
    return [where, view, keypoints]


def _info_strip(ax: Any, columns: list[list[str]]) -> None:
    """The sample's numbers in columns across a thin strip."""
    ax.axis("off")
    for k, lines in enumerate(columns):
        ax.text(
            k / len(columns), 1.0, "\n".join(lines), va="top", ha="left", fontsize=8.5,
            family="monospace", transform=ax.transAxes,
        )  # fmt: skip


def _legend(
    ax: Any, links: _Links | None, zoom: bool, camera_centre: bool, column: bool = False
) -> None:
    """What the marks on the chip panels mean: in a panel of its own (``column``: one column)
    or in the strip's right part (two columns)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ax.axis("off")
    handles = [
        Patch(facecolor=(0.1, 0.95, 0.3, 0.45), edgecolor="none", label="viewshed (visible cells)"),
        Line2D([], [], color="lime", lw=0.8, label="viewshed outline (DEM)"),
        Line2D([], [], color="orange", lw=1.3, label="camera wedge (FOV to farthest hit)"),
        Line2D([], [], marker="^", color="red", markeredgecolor="white", ls="none",
               markersize=9, label="rover"),
    ]  # fmt: skip
    if camera_centre:
        handles.append(
            Line2D([], [], marker="o", color="orange", ls="none", markersize=4,
                   label="camera centre")
        )  # fmt: skip
    if zoom:
        handles.append(Line2D([], [], color="cyan", ls="--", lw=1, label="zoomed area"))
    if links is not None:
        handles.append(
            Line2D([], [], marker="o", color="tab:blue", markeredgecolor="black", ls="none",
                   markersize=5, label="keypoint (ground pixel = map point)")
        )  # fmt: skip
        if not links.on_chip.all():
            handles.append(
                Line2D([], [], marker="o", markerfacecolor="none", markeredgecolor="tab:blue",
                       ls="none", markersize=5, label="keypoint beyond the chip")
            )  # fmt: skip
    ax.legend(handles=handles, loc="center left" if column else "upper left",
              ncol=1 if column else 2, fontsize=9 if column else 8, frameon=False,
              borderaxespad=0.0, handlelength=1.6, columnspacing=1.0,
              title="legend" if column else None)  # fmt: skip


#: a view smaller than this share of the chip's area is drawn with a note (a down-looking
#: camera sees a metre or two beside the rover: its viewshed and wedge vanish at chip scale)
SMALL_VIEW_SHARE = 0.005


def view_note(row: dict[str, Any], chip_area_m2: float) -> str | None:
    """A sentence for a sample whose view covers almost nothing of its chip (under
    ``SMALL_VIEW_SHARE`` of ``chip_area_m2``, square metres), None otherwise."""
    area = row.get("viewshed_area_m2")
    if area is None or not np.isfinite(area) or chip_area_m2 <= 0:
        return None
    if area >= SMALL_VIEW_SHARE * chip_area_m2:
        return None
    el = row.get("elevation_deg")
    far = row.get("max_visible_range_m") or 0.0
    if not area:
        why = "no ray hits the terrain"
        if el is not None and el > 0:
            why += f": the camera looks above the horizon (el {el:.1f}°)"
        return f"Nothing of the chip is in view: {why}."
    looks = ""
    if el is not None and el < -20:
        looks = f"the camera looks down (el {el:.1f}°) at the ground beside the rover: "
    return (
        f"The view covers almost nothing of the chip: {looks}{area:.0f} m² seen, to "
        f"{far:.1f} m ({100 * area / chip_area_m2:.2f}% of the chip), so the viewshed and the "
        "wedge are a few pixels and the ground image shows a close-up."
    )


def _crop_to_mask(image: np.ndarray | None, mask: np.ndarray | None) -> np.ndarray | None:
    """A padded ground image cut back to its own pixels (``ground_mask``'s True box)."""
    if image is None or mask is None or mask.all():
        return image
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return image
    return image[: rows.max() + 1, : cols.max() + 1]


def display_arrays(sample: dict[str, Any]) -> dict[str, Any]:
    """The sample's images as display arrays: ground [H, W, 3] uint8 (a padded one cut to
    its ``ground_mask``), ortho [h, w] uint8, viewshed bool, dem float (metres); absent fields
    are None."""

    def arr(name: str) -> np.ndarray | None:
        value = sample.get(name)
        return None if value is None else np.asarray(value)

    def uint8(a: np.ndarray | None) -> np.ndarray | None:
        if a is None or a.dtype == np.uint8:
            return a
        return np.asarray((np.clip(np.nan_to_num(a), 0, 1) * 255 + 0.5).astype(np.uint8))

    ground, ortho, vis, dem = arr("ground"), arr("ortho"), arr("viewshed"), arr("dem")
    mask = arr("ground_mask")
    ground_hwc = None if ground is None else uint8(ground.transpose(1, 2, 0))
    return {
        "ground": _crop_to_mask(ground_hwc, None if mask is None else mask[0] > 0),
        "ortho": None if ortho is None else uint8(ortho[0]),
        "viewshed": None if vis is None else vis[0] > 0,
        "dem": None if dem is None else dem[0].astype(np.float64),
        "corr": arr("corr"),
        "corr_ground": arr("corr_ground"),
    }


def _missing(ax: Any, what: str) -> None:
    ax.text(0.5, 0.5, f"{what}\nnot in the sample", ha="center", va="center", fontsize=10)


def dem_colours(dem: np.ndarray, res: float) -> tuple[np.ndarray, Any, Any]:
    """The DEM chip (metres) as RGB: terrain colours of the elevation, shaded by the
    hillshade; and the (norm, colormap) of its colourbar."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    finite = np.isfinite(dem)
    lo, hi = (float(np.nanmin(dem)), float(np.nanmax(dem))) if finite.any() else (0.0, 1.0)
    norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1.0)
    cmap = colormaps["terrain"]
    shade = np.nan_to_num(hillshade(dem, res), nan=1.0)
    rgb = cmap(norm(np.where(finite, dem, lo)))[..., :3] * (0.45 + 0.55 * shade[..., None])
    rgb[~finite] = 1.0
    return np.clip(rgb, 0, 1), norm, cmap


def draw_dem_panel(
    fig: Any,
    ax: Any,
    dem: np.ndarray,
    res: float,
    vis: np.ndarray,
    rover: tuple[float, float],
    wedge: tuple[np.ndarray, np.ndarray],
    colourbar: bool = True,
) -> None:
    """The DEM chip in terrain colours shaded by its hillshade (a colourbar in metres), the
    viewshed outline, the wedge and the rover."""
    from matplotlib.cm import ScalarMappable

    n_rows, n_cols = dem.shape
    rgb, norm, cmap = dem_colours(dem, res)
    ax.imshow(rgb, extent=(0, n_cols, n_rows, 0), interpolation="nearest")
    if vis.any() and not vis.all():
        ax.contour(
            np.arange(n_cols) + 0.5,  # pixel centres, in the panel's pixel-edge coordinates
            np.arange(n_rows) + 0.5,
            vis.astype(float),
            levels=[0.5],
            colors=["lime"],
            linewidths=0.8,
        )
    ax.plot(*wedge, color="orange", lw=1.0)
    ax.plot(*rover, marker="^", color="red", markersize=9, markeredgecolor="white", ls="none")
    _limits(ax, (0, 0, n_cols, n_rows))
    if colourbar:
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, fraction=0.046, pad=0.02)
        bar.set_label("elevation (m)", fontsize=8)
        bar.ax.tick_params(labelsize=7)


def sample_figure(sample: dict[str, Any], *, title: str | None = None) -> Any:
    """A matplotlib Figure of one dataset sample, transformed or not, drawing the fields it
    holds.

    Top row: the ground image (a padded one cut to its ``ground_mask``); the ortho chip with
    the viewshed, the rover and the camera wedge; the DEM chip in terrain colours shaded by
    its hillshade, with a colourbar in metres. With keypoints (``corr``), a second row: the
    keypoints (ground pixels and their map points), colour-linked, over the ground image and
    over the ortho zoomed on the viewshed. Under them a thin strip: the sample's numbers and
    the legend, and a note when the view covers almost nothing of the chip
    (:func:`view_note`). ``SHOW_SIZE`` inches with keypoints, ``SHOW_SIZE`` wide and 6.0
    inches high without. The chip panels are drawn through the sample's ``transform``, so a
    rotated, cropped or flipped chip shows its own wedge and north arrow. Axes in order:
    ground, ortho, DEM, (keypoints on the ground, on the map), the strip's text, its legend,
    then the colourbar.
    """
    plt = pyplot()
    row = dict(sample.get("meta") or {})
    parts = display_arrays(sample)
    ground, ortho, vis, dem = parts["ground"], parts["ortho"], parts["viewshed"], parts["dem"]
    chip = next((a for a in (ortho, dem, vis) if a is not None), None)
    chip_shape = chip.shape if chip is not None else (1, 1)
    n_rows, n_cols = chip_shape
    if vis is None:
        vis = np.zeros(chip_shape, dtype=bool)
    transform = [float(v) for v in np.asarray(sample["transform"])[:6]]
    res = float(np.hypot(transform[0], transform[3]))  # map units per chip pixel
    rotation = float(sample.get("rotation", 0.0))
    inv = invert_affine(transform)
    rover = apply_affine(inv, row.get("easting", np.nan), row.get("northing", np.nan))
    wedge = wedge_pixels(row, inv)
    links = None
    if parts["corr"] is not None and parts["corr_ground"] is not None:
        ground_shape = ground.shape if ground is not None else (1, 1)
        links = keypoint_links(parts["corr"], parts["corr_ground"], ground_shape, chip_shape)
    zoom = _zoom_box(vis, rover, links, max(n_rows, n_cols)) if links is not None else None
    note = view_note(row, n_rows * n_cols * res * res)

    size = SHOW_SIZE if links is not None else (SHOW_SIZE[0], 6.0)
    fig = plt.figure(figsize=size)
    if links is not None:
        grid = fig.add_gridspec(3, 6, height_ratios=[1, 1, 0.2], hspace=0.18, wspace=0.12)
        top = [fig.add_subplot(grid[0, 2 * k : 2 * k + 2]) for k in range(3)]
        low = [fig.add_subplot(grid[1, 0:2]), fig.add_subplot(grid[1, 2:4])]
        text_ax, legend_ax = fig.add_subplot(grid[2, :]), fig.add_subplot(grid[1, 4:6])
    else:
        grid = fig.add_gridspec(2, 6, height_ratios=[1, 0.3], hspace=0.1, wspace=0.12)
        top = [fig.add_subplot(grid[0, 2 * k : 2 * k + 2]) for k in range(3)]
        low = []
        inner = grid[1, :].subgridspec(1, 5, wspace=0.05)
        text_ax, legend_ax = fig.add_subplot(inner[0, :3]), fig.add_subplot(inner[0, 3:])

    ax = top[0]
    if ground is not None:
        ax.imshow(ground)
    else:
        _missing(ax, "ground image")
    if note is not None:  # on the ground image: a close-up or the sky, little to hide
        ax.text(0.5, 0.5, textwrap.fill(note, 44), ha="center", va="center", fontsize=9.5,
                color="darkred", transform=ax.transAxes,
                bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "darkred"})  # fmt: skip
    ax.set_title(
        title
        or f"ground image\n{row.get('product_id')}\n{row.get('instrument')}, sol "
        f"{row.get('sol')}, az {row.get('azimuth_deg', np.nan):.1f}°, "
        f"el {row.get('elevation_deg', np.nan):.1f}°",
        fontsize=9,
    )
    ax = top[1]
    if ortho is not None:
        draw_ortho_panel(ax, ortho, vis, rover, wedge)
        if zoom is not None:
            x0, y0, x1, y1 = zoom
            ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="cyan", lw=1, ls="--")
        _north_arrow(ax, inv, n_cols)
        scale_bar(ax, (0, 0, n_cols, n_rows), res, y_down=True)
        if note is not None:
            ax.text(0.5, 0.97, "view: almost nothing\n(note on the ground image)", ha="center",
                    va="top", fontsize=9, color="darkred", transform=ax.transAxes,
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})  # fmt: skip
    else:
        _missing(ax, "ortho chip")
    apex = "camera centre" if wedge_apex(row)[2] else "rover (camera centre unknown)"
    ax.set_title(
        f"ortho chip {n_cols * res:.0f} m, viewshed {row.get('viewshed_area_m2', np.nan):.0f} m²"
        f"\ncamera wedge az {row.get('azimuth_deg', np.nan):.0f}° ± "
        f"{row.get('hfov_deg', np.nan) / 2:.1f}° to {row.get('max_visible_range_m', np.nan):.0f} m"
        f" from the {apex}",
        fontsize=9,
    )
    ax = top[2]
    if dem is not None:
        draw_dem_panel(fig, ax, dem, res, vis, rover, wedge, colourbar=False)
        _north_arrow(ax, inv, n_cols)
        scale_bar(ax, (0, 0, n_cols, n_rows), res, y_down=True)
        finite = np.isfinite(dem)
        lo, hi = (np.nanmin(dem), np.nanmax(dem)) if finite.any() else (np.nan, np.nan)
        ax.set_title(f"DEM chip, {lo:.0f} to {hi:.0f} m\n(shaded, viewshed outline)", fontsize=9)
    else:
        _missing(ax, "DEM chip")

    if links is not None:
        if ground is not None:
            low[0].imshow(ground)
        low[0].set_title("keypoints: ground pixels (sampled) ...", fontsize=9)
        if ortho is not None:
            draw_ortho_panel(low[1], ortho, vis, rover, wedge, alpha=0.3)
        _draw_links(low[0], low[1], links)
        if zoom is not None:
            _limits(low[1], zoom)
            if ortho is not None:
                scale_bar(low[1], zoom, res, y_down=True)
            low[1].set_title(
                f"... and their map points, same colours (ortho zoom "
                f"{(zoom[2] - zoom[0]) * res:.0f} m across)",
                fontsize=9,
            )
        else:
            low[1].set_title("... and their map points on the ortho chip, same colours",
                             fontsize=9)  # fmt: skip
    _info_strip(text_ax, _info_lines(row, res, rotation, links))
    _legend(legend_ax, links, zoom is not None, wedge_apex(row)[2], column=links is not None)
    for a in [*top, *low]:
        a.set_xticks([])
        a.set_yticks([])
    if dem is not None:  # the colourbar last: it takes its room from the DEM panel
        from matplotlib.cm import ScalarMappable

        _, norm, cmap = dem_colours(dem, res)
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=top[2], fraction=0.046,
                           pad=0.02)  # fmt: skip
        bar.set_label("elevation (m)", fontsize=8)
        bar.ax.tick_params(labelsize=7)
    fig.subplots_adjust(left=0.02, right=0.95, top=0.92, bottom=0.02)
    return fig


# -- dense members (output.members) ---------------------------------------------------------------
DENSE_PANELS = ("range", "depth", "ortho_view", "dem_view", "ground_on_map")


def has_dense(sample: dict[str, Any]) -> bool:
    """Whether the sample holds a dense member to draw (:func:`dense_figure`)."""
    return any(name in sample for name in DENSE_PANELS)


def _dense_image(sample: dict[str, Any], name: str, mask: str | None) -> np.ndarray | None:
    """[H, W] (first band) or [H, W, 3] float display array, NaN where ``mask`` is 0."""
    value = sample.get(name)
    if value is None:
        return None
    a = np.asarray(value).astype(np.float64)
    a = a[0] if a.shape[0] == 1 else a.transpose(1, 2, 0)
    if np.asarray(value).dtype == np.uint8:
        a = a / 255.0
    if mask is not None and mask in sample:
        keep = np.asarray(sample[mask])[0] > 0
        a = np.where(keep[..., None] if a.ndim == 3 else keep, a, np.nan)
    return a


def dense_figure(sample: dict[str, Any], *, title: str | None = None) -> Any:
    """A matplotlib Figure of a sample's dense members: range and depth (metres along the ray
    and the camera axis) and the ortho and DEM seen from the rover (ground image's dense
    grid, blank where invalid); the ground image laid on the map over the ortho chip (chip
    grid, only covered pixels coloured)."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=SHOW_SIZE)
    panels = (
        ("ground", None, "ground image", "gray"),
        ("range", None, "range (m along the ray)", "viridis"),
        ("depth", None, "depth (m along the camera axis)", "viridis"),
        ("ortho_view", "view_valid", "ortho seen from the rover", "gray"),
        ("dem_view", "view_valid", "DEM seen from the rover (m)", "terrain"),
        ("ground_on_map", "ground_on_map_cover", "ground image laid on the map", "gray"),
    )
    for ax, (name, mask, label, cmap) in zip(axes.ravel(), panels, strict=True):
        image = _dense_image(sample, name, mask)
        if image is None:
            _missing(ax, name)
        else:
            if name == "ground_on_map" and "ortho" in sample:
                ortho = _dense_image(sample, "ortho", None)
                ax.imshow(ortho, cmap="gray", alpha=0.5)
            shown = ax.imshow(np.clip(image, 0, 1) if image.ndim == 3 else image, cmap=cmap)
            if image.ndim == 2 and name in ("range", "depth", "dem_view"):
                fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.02)
        ax.set_title(label, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
