"""Stage chips: ortho, DEM and viewshed chips around the rover, and the correspondence."""

from __future__ import annotations

from typing import Any

import numpy as np

from mars_pairs.pds.observation import Observation
from mars_pairs.pipeline.context import SampleContext
from mars_pairs.pipeline.view import View, in_view
from mars_pairs.raster.chips import ChipGrid, resample_array


def cut_chips(view: View, ctx: SampleContext, obs: Observation) -> tuple[ChipGrid, dict[str, Any]]:
    """Ortho, DEM and viewshed chips around the rover (north-up or heading-up)."""
    spec = ctx.config.chips
    rover = view.camera.origin_map
    rotation = 0.0
    if spec.orientation == "heading-up":
        # the chip's up is the camera azimuth, as a map (grid) azimuth
        rotation = float(view.camera.grid_azimuth_deg(view.camera.pointing_az_el()[0]))
    grid = ChipGrid.around(
        float(rover[0]),
        float(rover[1]),
        spec.size_m,
        spec.size_px,
        ctx.crs_wkt,
        rotation_deg=rotation,
    )
    ortho = ctx.ortho.read_uint8(grid)  # scaled by the ortho's declared or measured range
    dem = ctx.dem.read(grid)
    los = view.mask if view.los is None else view.los
    vis = resample_array(los, view.window.transform, ctx.crs_wkt, grid, nearest=True)
    visible = chip_view(np.nan_to_num(vis) > 0.5, dem, grid, view)
    return grid, {
        "ortho": ortho,
        "dem": dem.astype(np.float32),
        "viewshed": visible.astype(np.uint8) * 255,
    }


def chip_view(visible: np.ndarray, dem: np.ndarray, grid: ChipGrid, view: View) -> np.ndarray:
    """The chip's viewshed, each pixel tested itself: line of sight of the DEM cell it lies in
    (``visible``: the kernel's mask, nearest) and the view's exact test on the pixel centre's
    own terrain point (``dem`` chip heights): inside the image at the chip's resolution."""
    rows, cols = np.nonzero(visible & np.isfinite(dem))
    out = np.zeros_like(visible, dtype=bool)
    if len(rows):
        x, y = grid.transform * (cols + 0.5, rows + 0.5)
        points = np.column_stack([x, y, dem[rows, cols].astype(np.float64)])
        keep = in_view(points, view)
        out[rows[keep], cols[keep]] = True
    return out


def correspondence(view: View, grid: ChipGrid) -> np.ndarray:
    """Chip pixel (column, row) of each strided ground pixel's ray hit; NaN for no hit."""
    if view.hits is None:
        return np.zeros((0, 0, 2), dtype=np.float32)
    chip_px = grid.to_pixel(view.hits[:, 0], view.hits[:, 1]).astype(np.float32)
    return chip_px.reshape(*view.grid_shape, 2)
