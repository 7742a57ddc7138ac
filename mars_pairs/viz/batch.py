"""The picture of a batch: one column per sample, one row per field it holds."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mars_pairs.viz.common import pyplot
from mars_pairs.viz.sample import (
    apply_affine,
    dem_colours,
    display_arrays,
    draw_ortho_panel,
    invert_affine,
    keypoint_links,
    view_note,
    wedge_pixels,
)

#: inches per panel of a batch figure
PANEL_IN = 2.3


def _rows(samples: Sequence[dict[str, Any]]) -> list[str]:
    """The rows a batch figure draws: the ground image, the ortho chip (with the viewshed),
    the DEM chip, those the samples hold (a viewshed alone is drawn on a blank chip)."""
    held = set().union(*(set(s) for s in samples))
    rows: list[str] = [name for name in ("ground", "ortho", "dem") if name in held]
    if "ortho" not in held and "viewshed" in held:
        rows.insert(1 if "ground" in rows else 0, "viewshed")
    return rows


def batch_figure(
    samples: Sequence[dict[str, Any]], *, title: str | None = None, max_samples: int = 8
) -> Any:
    """A matplotlib Figure of the first ``max_samples`` samples of a batch (as
    :func:`mars_pairs.torch.unbind_samples` gives them): a column per sample, titled with
    its instrument, sol and split; a row per field the samples hold: the ground image (cut
    to its ``ground_mask``; keypoints dotted on it with ``corr``), the ortho chip with the
    viewshed, wedge and rover, the DEM chip in shaded terrain colours (its elevation range
    under it). ``PANEL_IN`` inches a panel."""
    plt = pyplot()
    shown = list(samples)[: max(1, int(max_samples))]
    rows = _rows(shown) or ["ground"]
    n = len(shown)
    fig, axes = plt.subplots(
        len(rows), n, figsize=(PANEL_IN * n, PANEL_IN * len(rows) + 0.9), squeeze=False
    )
    for j, sample in enumerate(shown):
        row = dict(sample.get("meta") or {})
        parts = display_arrays(sample)
        chip = next((parts[k] for k in ("ortho", "dem", "viewshed") if parts[k] is not None), None)
        chip_shape = chip.shape if chip is not None else (1, 1)
        vis = parts["viewshed"] if parts["viewshed"] is not None else np.zeros(chip_shape, bool)
        transform = [float(v) for v in np.asarray(sample["transform"])[:6]]
        res = float(np.hypot(transform[0], transform[3]))
        inv = invert_affine(transform)
        rover = apply_affine(inv, row.get("easting", np.nan), row.get("northing", np.nan))
        wedge = wedge_pixels(row, inv)
        for i, name in enumerate(rows):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if name == "ground" and parts["ground"] is not None:
                ax.imshow(parts["ground"])
                if parts["corr"] is not None and parts["corr_ground"] is not None:
                    links = keypoint_links(
                        parts["corr"], parts["corr_ground"], parts["ground"].shape, chip_shape,
                        target=(9, 7),
                    )  # fmt: skip
                    if links is not None and len(links.ground):
                        ax.scatter(*links.ground.T, c=links.colours, s=7, linewidths=0)
            elif name in ("ortho", "viewshed") and chip is not None:
                ortho = parts["ortho"]
                if ortho is None:
                    ortho = np.full(chip_shape, 128, dtype=np.uint8)
                draw_ortho_panel(ax, ortho, vis, rover, wedge)
                note = view_note(row, chip_shape[0] * chip_shape[1] * res * res)
                if note is not None:
                    box = {"facecolor": "white", "alpha": 0.8, "edgecolor": "none"}
                    ax.text(
                        0.5, 0.04, "view: almost nothing", ha="center", va="bottom",
                        fontsize=7, color="darkred", transform=ax.transAxes, bbox=box,
                    )  # fmt: skip
            elif name == "dem" and parts["dem"] is not None:
                dem = parts["dem"]
                rgb, norm, _ = dem_colours(dem, res)
                ax.imshow(rgb, extent=(0, dem.shape[1], dem.shape[0], 0))
                ax.set_xlabel(f"DEM {norm.vmin:.0f} to {norm.vmax:.0f} m", fontsize=7, labelpad=2)
            else:
                ax.text(0.5, 0.5, f"no {name}", ha="center", va="center", fontsize=8)
        axes[0, j].set_title(
            f"{row.get('instrument')}\nsol {row.get('sol')}, {row.get('split')}", fontsize=8
        )
    for i, name in enumerate(rows):
        label = {"ground": "ground image", "ortho": "ortho + viewshed", "dem": "DEM (shaded)",
                 "viewshed": "viewshed"}[name]  # fmt: skip
        axes[i, 0].set_ylabel(label, fontsize=9)
    more = len(samples) - n
    fig.suptitle(
        title or f"batch of {len(samples)} samples" + (f" (first {n} shown)" if more else ""),
        fontsize=10,
    )
    fig.subplots_adjust(left=0.04, right=0.99, top=1 - 0.7 / fig.get_size_inches()[1],
                        bottom=0.03, wspace=0.05, hspace=0.12)  # fmt: skip
    return fig
