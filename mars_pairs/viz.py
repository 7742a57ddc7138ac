"""Pictures of a built dataset: one sample, and all footprints over the map.

matplotlib is imported here only (the ``viz`` extra), so a build needs no plotting stack.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import shapely
from PIL import Image

from mars_pairs.errors import MarsPairsError
from mars_pairs.manifest import Manifest
from mars_pairs.shards import MemberLocation, read_member

MEMBER_FILES = {
    "ortho": "ortho.png",
    "dem": "dem.npy",
    "viewshed": "viewshed.png",
    "corr": "corr.npy",
    "meta": "meta.json",
}


def _pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise MarsPairsError("pictures need matplotlib: pip install 'mars-pairs[viz]'") from exc
    return plt


def _row(root: Path, key: str) -> dict[str, Any]:
    table = Manifest.open(root).to_table()
    rows = [r for r in table.to_pylist() if r["key"] == key]
    if not rows:
        raise MarsPairsError(f"{root}: no sample with key {key!r}")
    return rows[0]


def _member(root: Path, row: dict[str, Any], name: str) -> bytes:
    loc = MemberLocation(row[f"{name}_shard"], row[f"{name}_offset"], row[f"{name}_size"])
    return read_member(root, loc)


def hillshade(
    dem: np.ndarray, res: float, azimuth: float = 315.0, altitude: float = 35.0
) -> np.ndarray:
    """Hillshade in [0, 1] of a north-up elevation grid (metres, ``res`` metres per pixel)."""
    z = np.where(np.isfinite(dem), dem, np.nanmedian(dem) if np.isfinite(dem).any() else 0.0)
    gy, gx = np.gradient(z, res)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, alt = np.radians(azimuth), np.radians(altitude)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.clip(shade, 0, 1)


def show_sample(root: str | Path, key: str, out: str | Path) -> Path:
    """One figure: ground image; ortho + viewshed + rover + wedge; DEM hillshade; correspondence."""
    plt = _pyplot()
    root, out = Path(root), Path(out)
    row = _row(root, key)
    ground = np.asarray(Image.open(io.BytesIO(_member(root, row, "ground"))).convert("RGB"))
    ortho = np.asarray(Image.open(io.BytesIO(_member(root, row, "ortho"))))
    vis = np.asarray(Image.open(io.BytesIO(_member(root, row, "viewshed")))) > 0
    dem = np.load(io.BytesIO(_member(root, row, "dem")))
    corr = np.load(io.BytesIO(_member(root, row, "corr")))
    meta = json.loads(_member(root, row, "meta"))
    n = ortho.shape[0]
    transform = meta["chip_transform"]
    res = float(np.hypot(transform[0], transform[3]))  # map units per chip pixel
    inv = _inverse(transform)
    rover = _apply(inv, row["easting"], row["northing"])

    fig, axes = plt.subplots(2, 2, figsize=(12, 10))
    ax = axes[0, 0]
    ax.imshow(ground)
    ax.set_title(
        f"{row['product_id']}\nsol {row['sol']}, az {row['azimuth_deg']:.1f}°, "
        f"el {row['elevation_deg']:.1f}°",
        fontsize=9,
    )
    ax = axes[0, 1]
    ax.imshow(ortho, cmap="gray", vmin=0, vmax=255)
    overlay = np.zeros((*vis.shape, 4))
    overlay[vis] = (0.1, 0.9, 0.3, 0.45)
    ax.imshow(overlay)
    _draw_wedge(ax, row, rover, inv, n)
    ax.plot(*rover, marker="^", color="red", markersize=9, markeredgecolor="white")
    ax.set_title(
        f"ortho chip + viewshed ({row['visible_cells']} cells, {row['viewshed_area_m2']:.0f} m²)",
        fontsize=9,
    )
    ax = axes[1, 0]
    ax.imshow(hillshade(dem, abs(res)), cmap="gray")
    ax.plot(*rover, marker="^", color="red", markersize=9, markeredgecolor="white")
    ax.set_title(f"DEM chip hillshade ({np.nanmin(dem):.0f} to {np.nanmax(dem):.0f} m)", fontsize=9)
    _draw_correspondence(axes[1, 1], axes[0, 0], ortho, corr, meta, ground.shape)
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _inverse(t: list[float]) -> tuple[float, ...]:
    a, b, c, d, e, f = t
    det = a * e - b * d
    return (e / det, -b / det, (b * f - c * e) / det, -d / det, a / det, (c * d - a * f) / det)


def _apply(t: tuple[float, ...], x: Any, y: Any) -> tuple[Any, Any]:
    a, b, c, d, e, f = t
    return a * np.asarray(x) + b * np.asarray(y) + c, d * np.asarray(x) + e * np.asarray(y) + f


def _draw_wedge(
    ax: Any, row: dict[str, Any], rover: tuple[float, float], inv: tuple[float, ...], n: int
) -> None:
    """The camera's azimuth wedge out to the farthest visible range."""
    rng = max(row["max_visible_range_m"], 1.0)
    az0 = row["azimuth_deg"] - row["hfov_deg"] / 2
    az1 = row["azimuth_deg"] + row["hfov_deg"] / 2
    az = np.radians(np.linspace(az0, az1, 32))
    x = row["easting"] + rng * np.sin(az)
    y = row["northing"] + rng * np.cos(az)
    px, py = _apply(inv, x, y)
    ax.plot([rover[0], *px, rover[0]], [rover[1], *py, rover[1]], color="orange", lw=1.2)
    ax.set_xlim(0, n)
    ax.set_ylim(n, 0)


def _draw_correspondence(
    ax: Any,
    ground_ax: Any,
    ortho: np.ndarray,
    corr: np.ndarray,
    meta: dict[str, Any],
    ground_shape: tuple[int, ...],
) -> None:
    """Ground pixels and their map points, colour-linked (a colour wheel over the image)."""
    ax.imshow(ortho, cmap="gray", vmin=0, vmax=255)
    if corr.size == 0:
        ax.set_title("no correspondence (ray casting off)", fontsize=9)
        return
    k = meta["ray_stride"]
    gh, gw = corr.shape[:2]
    lines, samples = np.meshgrid(np.arange(gh) * k, np.arange(gw) * k, indexing="ij")
    scale_x = ground_shape[1] / meta["width"]
    scale_y = ground_shape[0] / meta["height"]
    pts = corr.reshape(-1, 2)
    ok = np.all(np.isfinite(pts), axis=1)
    step = max(1, int(ok.sum() // 600))
    idx = np.flatnonzero(ok)[::step]
    colours = _colour_wheel(
        samples.ravel()[idx] / max(meta["width"], 1), lines.ravel()[idx] / max(meta["height"], 1)
    )
    ax.scatter(pts[idx, 0], pts[idx, 1], c=colours, s=4, linewidths=0)
    ground_ax.scatter(
        samples.ravel()[idx] * scale_x, lines.ravel()[idx] * scale_y, c=colours, s=4, linewidths=0
    )
    ax.set_xlim(0, ortho.shape[1])
    ax.set_ylim(ortho.shape[0], 0)
    ax.set_title(
        f"correspondence: {ok.sum()} of {ok.size} strided pixels hit the terrain", fontsize=9
    )


def _colour_wheel(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """RGB colours: hue from the column, brightness from the line (top dark, bottom bright)."""
    import colorsys

    return np.array(
        [
            colorsys.hsv_to_rgb(float(a) * 0.85, 0.9, 0.45 + 0.55 * float(b))
            for a, b in zip(u, v, strict=True)
        ]
    )


def overview(
    root: str | Path,
    out: str | Path,
    ortho_path: str | Path | None = None,
    colour_by: str = "sol",
    max_px: int = 1400,
) -> Path:
    """All footprints over a downsampled ortho with the rover traverse, coloured by sol/split."""
    plt = _pyplot()
    root, out = Path(root), Path(out)
    table = Manifest.open(root).to_table()
    if table.num_rows == 0:
        raise MarsPairsError(f"{root}: the dataset has no samples")
    rows = table.to_pylist()
    doc = json.loads((root / "dataset.json").read_text())
    ortho_path = Path(ortho_path or doc["config"]["inputs"]["ortho"])
    xs = np.array([r["easting"] for r in rows])
    ys = np.array([r["northing"] for r in rows])
    foot = [shapely.from_wkb(r["footprint"]) for r in rows if r["footprint"] is not None]
    bounds = (
        shapely.union_all([*foot, *shapely.points(xs, ys)]).bounds
        if foot
        else (xs.min(), ys.min(), xs.max(), ys.max())
    )
    pad = 0.08 * max(bounds[2] - bounds[0], bounds[3] - bounds[1], 50.0)
    west, south, east, north = bounds[0] - pad, bounds[1] - pad, bounds[2] + pad, bounds[3] + pad
    image = _ortho_overview(ortho_path, (west, south, east, north), max_px)

    fig, ax = plt.subplots(figsize=(10, 10 * (north - south) / max(east - west, 1e-9)))
    if image is not None:
        ax.imshow(image, cmap="gray", extent=(west, east, south, north), vmin=0, vmax=255)
    values = [r[colour_by] for r in rows]
    cats = sorted(set(values), key=str)
    cmap = plt.get_cmap("viridis" if colour_by == "sol" else "Set1")
    colour = {c: cmap(i / max(len(cats) - 1, 1)) for i, c in enumerate(cats)}
    for r in rows:
        if r["footprint"] is None:
            continue
        geom = shapely.from_wkb(r["footprint"])
        gx, gy = geom.exterior.xy
        ax.fill(gx, gy, color=colour[r[colour_by]], alpha=0.25, lw=0)
        ax.plot(gx, gy, color=colour[r[colour_by]], lw=0.8)
    order = np.argsort([(r["sol"], r["site"], r["drive"]) for r in rows], axis=0)[:, 0]
    ax.plot(xs[order], ys[order], "-", color="white", lw=1.5, alpha=0.8)
    ax.plot(xs, ys, "^", color="red", markersize=6, markeredgecolor="white")
    for c in cats:
        ax.plot([], [], "s", color=colour[c], label=f"{colour_by} {c}")
    ax.legend(loc="upper right", fontsize=8, ncol=2 if len(cats) > 8 else 1)
    ax.set_xlim(west, east)
    ax.set_ylim(south, north)
    ax.set_title(
        f"{len(rows)} samples: footprints and rover traverse (map CRS metres)", fontsize=10
    )
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _ortho_overview(
    path: Path, bounds: tuple[float, float, float, float], max_px: int
) -> np.ndarray | None:
    """A decimated read of the ortho over ``bounds`` (GDAL overview/decimated window read)."""
    import rasterio
    from rasterio.windows import from_bounds

    if not path.is_file():
        return None
    with rasterio.open(path) as src:
        window = from_bounds(*bounds, transform=src.transform)
        scale = max(window.width, window.height) / max_px
        shape = (
            max(1, int(window.height / max(scale, 1))),
            max(1, int(window.width / max(scale, 1))),
        )
        return src.read(1, window=window, out_shape=shape, boundless=True, fill_value=0)


def read_manifest_rows(root: Path) -> list[dict[str, Any]]:
    """All manifest rows (plain values)."""
    return pq.read_table(root / "manifest.parquet").to_pylist()
