"""The picture of one sample: ground image, ortho with viewshed and wedge, DEM, links."""

from __future__ import annotations

import colorsys
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from mars_pairs.viz.common import (
    DPI,
    SHOW_SIZE,
    hillshade,
    manifest_row,
    member_bytes,
    pyplot,
)


@dataclass(frozen=True)
class _Links:
    """Sampled ground pixels and their map points (chip pixels), colour-linked."""

    ground: np.ndarray  # (N, 2) displayed ground image (x, y), pixel-centre coordinates
    chip: np.ndarray  # (N, 2) chip (column, row), pixel-edge coordinates as the transform
    colours: np.ndarray  # (N, 3) RGB
    on_chip: np.ndarray  # (N,) bool
    rays: int  # strided rays cast
    hits: int  # of which hit the terrain


def _links(
    corr: np.ndarray,
    meta: dict[str, Any],
    ground_shape: tuple[int, ...],
    chip_shape: tuple[int, ...],
    target: tuple[int, int] = (18, 13),
) -> _Links | None:
    """About ``target`` (columns, lines) evenly spread strided pixels that hit the terrain."""
    if corr.size == 0:
        return None
    k = int(meta["ray_stride"])
    gh, gw = corr.shape[:2]
    sy, sx = max(1, math.ceil(gh / target[1])), max(1, math.ceil(gw / target[0]))
    lines, samples = np.meshgrid(np.arange(0, gh, sy) * k, np.arange(0, gw, sx) * k, indexing="ij")
    pts = corr[::sy, ::sx].reshape(-1, 2).astype(np.float64)
    hit = np.all(np.isfinite(pts), axis=1)
    width, height = max(int(meta["width"]), 1), max(int(meta["height"]), 1)
    s, ln = samples.ravel()[hit], lines.ravel()[hit]
    ground = np.stack(
        [
            (s + 0.5) * ground_shape[1] / width - 0.5,
            (ln + 0.5) * ground_shape[0] / height - 0.5,
        ],
        axis=-1,
    )
    chip = pts[hit]
    on_chip = (
        (chip[:, 0] >= 0)
        & (chip[:, 1] >= 0)
        & (chip[:, 0] <= chip_shape[1])
        & (chip[:, 1] <= chip_shape[0])
    )
    colours = _colour_wheel(s / width, ln / height)
    all_hits = int(np.all(np.isfinite(corr.reshape(-1, 2)), axis=1).sum())
    return _Links(ground, chip, colours, on_chip, gh * gw, all_hits)


def _colour_wheel(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """RGB colours: hue from the column, brightness from the line (top dark, bottom bright)."""
    rgb = [
        colorsys.hsv_to_rgb(float(a) * 0.85, 0.95, 0.4 + 0.6 * float(b))
        for a, b in zip(u, v, strict=True)
    ]
    return np.array(rgb, dtype=np.float64).reshape(-1, 3)


def _inverse(t: list[float]) -> tuple[float, ...]:
    a, b, c, d, e, f = t
    det = a * e - b * d
    return (e / det, -b / det, (b * f - c * e) / det, -d / det, a / det, (c * d - a * f) / det)


def _apply(t: tuple[float, ...], x: Any, y: Any) -> tuple[Any, Any]:
    a, b, c, d, e, f = t
    return a * np.asarray(x) + b * np.asarray(y) + c, d * np.asarray(x) + e * np.asarray(y) + f


def _wedge_pixels(
    row: dict[str, Any], origin: list[float], inv: tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The camera's azimuth wedge (az +/- hFOV/2) from ``origin`` to the farthest visible range,
    as a closed ring of chip pixel coordinates."""
    rng = max(float(row["max_visible_range_m"] or 0.0), 1.0)
    half = float(row["hfov_deg"]) / 2
    az = np.radians(np.linspace(row["azimuth_deg"] - half, row["azimuth_deg"] + half, 33))
    x = np.concatenate([[origin[0]], origin[0] + rng * np.sin(az), [origin[0]]])
    y = np.concatenate([[origin[1]], origin[1] + rng * np.cos(az), [origin[1]]])
    return _apply(inv, x, y)


def _limits(ax: Any, box: tuple[float, float, float, float]) -> None:
    ax.set_xlim(box[0], box[2])
    ax.set_ylim(box[3], box[1])


def _ortho_panel(
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


def _info_panel(ax: Any, row: dict[str, Any], meta: dict[str, Any], links: _Links | None) -> None:
    """The sample's numbers as text."""
    ax.axis("off")
    lines = [
        f"key  {row['key']}",
        f"mission  {row['mission']}   instrument  {row['instrument']}",
        f"sol {row['sol']}   site {row['site']}   drive {row['drive']}   split {row['split']}",
        f"rover  E {row['easting']:.1f}  N {row['northing']:.1f}  ({row['localization']})",
        f"lat {row['latitude']:.6f}   lon {row['longitude']:.6f}",
        f"elevation  {row['elevation']:.1f} m",
        f"camera  az {row['azimuth_deg']:.1f}°  el {row['elevation_deg']:.1f}°  "
        f"FOV {row['hfov_deg']:.1f}° x {row['vfov_deg']:.1f}°",
        f"viewshed  {row['visible_cells']} cells, {row['viewshed_area_m2']:.0f} m², "
        f"max range {row['max_visible_range_m']:.0f} m",
        f"chip  {meta.get('chip_transform', [0])[0] * 1.0:.2f} map units / px, "
        f"rotation {row['chip_rotation_deg']:.0f}°",
    ]
    if links is not None:
        lines += [
            f"rays  {links.hits} of {links.rays} strided pixels hit the terrain",
            f"shown  {int(links.on_chip.sum())} links on the chip"
            + (f", {int((~links.on_chip).sum())} beyond it (rings)" if not links.on_chip.all()
               else ""),
            "colour: hue = image column, brightness = image line",
        ]  # fmt: skip
    else:
        lines.append("no correspondence (ray casting off)")
    ax.text(
        0.0,
        1.0,
        "\n".join(lines),
        va="top",
        ha="left",
        fontsize=9,
        family="monospace",
        transform=ax.transAxes,
        wrap=True,
    )


def show_sample(root: str | Path, key: str, out: str | Path, dpi: int = DPI) -> Path:
    """One figure of a sample, written to ``out`` (PNG of ``SHOW_SIZE`` inches at ``dpi``).

    Top: the ground image; the ortho chip with the viewshed, the rover and the camera wedge;
    the DEM chip as a hillshade. Bottom: ground pixels and their map points, colour-linked,
    over the ground image and over the ortho zoomed on the viewshed; the sample's numbers.
    """
    plt = pyplot()
    root, out = Path(root), Path(out)
    row = manifest_row(root, key)
    ground = np.asarray(Image.open(io.BytesIO(member_bytes(root, row, "ground"))).convert("RGB"))
    ortho = np.asarray(Image.open(io.BytesIO(member_bytes(root, row, "ortho"))))
    vis = np.asarray(Image.open(io.BytesIO(member_bytes(root, row, "viewshed")))) > 0
    dem = np.load(io.BytesIO(member_bytes(root, row, "dem")))
    corr = np.load(io.BytesIO(member_bytes(root, row, "corr")))
    meta = json.loads(member_bytes(root, row, "meta"))
    n = ortho.shape[0]
    transform = meta["chip_transform"]
    res = float(np.hypot(transform[0], transform[3]))  # map units per chip pixel
    inv = _inverse(transform)
    rover = _apply(inv, row["easting"], row["northing"])
    cam_xy = (meta.get("camera_center_map") or [row["easting"], row["northing"]])[:2]
    wedge = _wedge_pixels(row, cam_xy, inv)
    links = _links(corr, meta, ground.shape, ortho.shape)
    zoom = _zoom_box(vis, rover, links, n)

    fig, axes = plt.subplots(2, 3, figsize=SHOW_SIZE)
    ax = axes[0, 0]
    ax.imshow(ground)
    ax.set_title(
        f"ground image\n{row['product_id']}\n{row['instrument']}, sol {row['sol']}, "
        f"az {row['azimuth_deg']:.1f}°, el {row['elevation_deg']:.1f}°",
        fontsize=9,
    )
    ax = axes[0, 1]
    _ortho_panel(ax, ortho, vis, rover, wedge)
    if zoom is not None:
        x0, y0, x1, y1 = zoom
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="cyan", lw=1, ls="--")
    _north_arrow(ax, inv, n)
    ax.set_title(
        f"ortho chip {n * res:.0f} m: viewshed (green) {row['viewshed_area_m2']:.0f} m², "
        f"rover ▲,\ncamera wedge (orange) az {row['azimuth_deg']:.0f}° ± "
        f"{row['hfov_deg'] / 2:.1f}° to {row['max_visible_range_m']:.0f} m",
        fontsize=9,
    )
    ax = axes[0, 2]
    ax.imshow(hillshade(dem, res), cmap="gray", vmin=0, vmax=1, extent=(0, n, n, 0))
    if vis.any() and not vis.all():
        centres = np.arange(n) + 0.5  # pixel centres, in the panel's pixel-edge coordinates
        ax.contour(
            centres, centres, vis.astype(float), levels=[0.5], colors=["lime"], linewidths=0.8
        )
    ax.plot(*wedge, color="orange", lw=1.0)
    ax.plot(*rover, marker="^", color="red", markersize=9, markeredgecolor="white", ls="none")
    _north_arrow(ax, inv, n)
    _limits(ax, (0, 0, n, n))
    lo, hi = (np.nanmin(dem), np.nanmax(dem)) if np.isfinite(dem).any() else (np.nan, np.nan)
    ax.set_title(
        f"DEM chip hillshade ({lo:.0f} to {hi:.0f} m)\nviewshed outline (green), wedge",
        fontsize=9,
    )

    axes[1, 0].imshow(ground)
    axes[1, 0].set_title("ground pixels (sampled) ...", fontsize=9)
    ax = axes[1, 1]
    _ortho_panel(ax, ortho, vis, rover, wedge, alpha=0.3)
    _draw_links(axes[1, 0], ax, links)
    if zoom is not None:
        _limits(ax, zoom)
        ax.set_title(
            f"... and their map points, same colours\n(ortho zoom {(zoom[2] - zoom[0]) * res:.0f}"
            " m across: cyan box)",
            fontsize=9,
        )
    else:
        ax.set_title("... and their map points on the ortho chip, same colours", fontsize=9)
    _info_panel(axes[1, 2], row, meta, links)
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
