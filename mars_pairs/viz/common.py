"""Shared pieces of the pictures: matplotlib on demand, manifest rows, members, hillshade.

matplotlib is imported here only, inside the functions (the ``viz`` extra), so a build, a
query or ``import mars_pairs.cli`` needs no plotting stack."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mars_pairs.errors import MarsPairsError
from mars_pairs.raster.shading import lambert_shading
from mars_pairs.store.query import Manifest

DPI = 90


SHOW_SIZE = (16.0, 10.0)  # inches: show_sample writes SHOW_SIZE * DPI pixels


OVERVIEW_SIZE = (16.0, 8.0)  # inches: overview writes OVERVIEW_SIZE * DPI pixels


#: Split colours of every picture; buffer pink, visible over a grey orthoimage.
SPLIT_COLOURS = {"train": "#1f77b4", "val": "#ff7f0e", "test": "#2ca02c", "buffer": "#e377c2"}


def pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise MarsPairsError("pictures need matplotlib: pip install 'mars-pairs[viz]'") from exc
    return plt


def png_bytes(fig: Any, dpi: int = DPI) -> bytes:
    """The figure as PNG bytes (the figure is closed)."""
    plt = pyplot()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return buf.getvalue()


def split_colours(splits: Sequence[str]) -> dict[str, str]:
    """A colour (#rrggbb) for every split name: ``SPLIT_COLOURS`` for the usual ones, others
    from tab10."""
    from matplotlib.colors import to_hex

    plt = pyplot()
    extra = iter(plt.get_cmap("tab10").colors[3:])
    return {s: to_hex(SPLIT_COLOURS.get(s) or next(extra, "grey")) for s in sorted(set(splits))}


def manifest_rows(root: Path) -> list[dict[str, Any]]:
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    rows: list[dict[str, Any]] = Manifest.open(root).require().to_table().to_pylist()
    return rows


def hillshade(
    dem: np.ndarray, res: float, azimuth: float = 315.0, altitude: float = 35.0
) -> np.ndarray:
    """Hillshade in [0, 1] of an elevation grid (metres, ``res`` metres per pixel; NaN kept):
    :func:`~mars_pairs.raster.shading.lambert_shading`, no-data cells filled with the median
    for the slopes of their neighbours.

    ``azimuth`` is the light's direction in degrees clockwise from the grid's up (row 0)
    direction, ``altitude`` its elevation in degrees.
    """
    finite = np.isfinite(dem)
    z = np.where(finite, dem, np.nanmedian(dem) if finite.any() else 0.0)
    return np.where(finite, lambert_shading(z, res, azimuth, altitude), np.nan)


def nice_length(length: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``length`` (> 0)."""
    power = 10.0 ** math.floor(math.log10(length))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= length)


def scale_bar(
    ax: Any,
    box: tuple[float, float, float, float],
    metres_per_unit: float = 1.0,
    *,
    y_down: bool = False,
    unit: str = "m",
    corner: str = "lower left",
) -> float:
    """A black and white scale bar in the ``corner`` (``lower left``, ``lower right``,
    ``upper left``, ``upper right``; default lower left) of a panel showing ``box``
    (x0, y0, x1, y1, axis data units; ``y_down``: an image panel whose y grows downwards),
    about a fifth of the panel wide, labelled in metres (``metres_per_unit`` metres per data
    unit; ``unit`` names the data unit when it is not metres, ``metres_per_unit`` then 1).
    Returns the bar's length in ``unit``s (metres by default)."""
    import matplotlib.patheffects as pe
    from matplotlib.patches import Rectangle

    width, height = abs(box[2] - box[0]), abs(box[3] - box[1])
    length = nice_length(width * metres_per_unit * 0.22)
    span = length / metres_per_unit  # data units
    thick = 0.012 * height
    x0 = min(box[0], box[2]) + 0.05 * width
    if corner.endswith("right"):
        x0 = max(box[0], box[2]) - 0.05 * width - span
    bottom = max(box[1], box[3]) - 0.05 * height if y_down else min(box[1], box[3]) + 0.05 * height
    if corner.startswith("upper"):
        bottom = (
            min(box[1], box[3]) + 0.1 * height if y_down else max(box[1], box[3]) - 0.1 * height
        )
    up = -1.0 if y_down else 1.0  # towards the top of the panel
    for k in range(2):
        ax.add_patch(
            Rectangle(
                (x0 + k * span / 2, bottom + (up * thick if y_down else 0.0)), span / 2, thick,
                facecolor="black" if k == 0 else "white", edgecolor="black", lw=0.8, zorder=6,
            )
        )  # fmt: skip
    label = f"{length / 1000:g} km" if length >= 1000 and unit == "m" else f"{length:g} {unit}"
    ax.text(
        x0 + span / 2, bottom + up * 2.2 * thick, label, ha="center",
        va="bottom", fontsize=9, color="black", zorder=6,
        path_effects=[pe.withStroke(linewidth=3, foreground="white")],
    )  # fmt: skip
    return length


def map_axes(
    ax: Any, box: tuple[float, float, float, float], unit: str, corner: str = "lower left"
) -> None:
    """A map panel showing ``box`` (xmin, ymin, xmax, ymax in the dataset CRS's map units,
    named ``unit``): its limits, equal aspect, plain tick labels, easting/northing axis labels
    and a scale bar (in ``corner``: :func:`scale_bar`)."""
    ax.set_xlim(box[0], box[2])
    ax.set_ylim(box[1], box[3])
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_xlabel(f"easting ({unit})", fontsize=9)
    ax.set_ylabel(f"northing ({unit})", fontsize=9)
    scale_bar(ax, box, unit=unit, corner=corner)


def sol_colours(plt: Any, sols: Sequence[int | None]) -> tuple[list[Any], Any]:
    """A viridis colour per sol (None as sol 0) and a function ``bar(ax, other)`` drawing the
    sol colour bar of ``ax``'s figure beside the axes ``other``."""
    from matplotlib.colors import Normalize
    from matplotlib.ticker import MaxNLocator

    whole = [int(s) if s is not None else 0 for s in sols]
    norm = Normalize(min(whole), max(max(whole), min(whole) + 1))
    cmap = plt.get_cmap("viridis")

    def bar(ax: Any, other: Any) -> None:
        sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        cb = ax.figure.colorbar(sm, ax=other, fraction=0.04, pad=0.02)
        cb.set_label("sol", fontsize=9)
        cb.ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        cb.ax.tick_params(labelsize=7)

    return [cmap(norm(s)) for s in whole], bar
