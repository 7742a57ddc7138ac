"""Stage chips: ortho, DEM and viewshed chips around the rover, their coverage, and the
correspondence."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from mars_pairs.errors import CoverageError
from mars_pairs.observation import Observation
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.key import sample_key
from mars_pairs.pipeline.sample.view import View, view_mask
from mars_pairs.raster.chips import ChipGrid, ChipReader, coverage, resample_array


@dataclass(frozen=True)
class ChipCoverage:
    """The fraction (0..1) of the ortho and DEM chips' pixels with data (not nodata, not
    masked, not off the raster)."""

    ortho: float
    dem: float


def check_coverage(
    fraction: float, minimum: float, what: str, reader: ChipReader, grid: ChipGrid
) -> None:
    """CoverageError unless the ``what`` chip ("ortho", "DEM") has data on some pixel and on
    at least ``minimum`` of them; the message names the raster, its extent and the chip's
    bounds (both in the chip's CRS, map units)."""
    if fraction > 0.0 and fraction >= minimum:
        return
    x0, y0, x1, y1 = grid.bounds()
    try:
        left, bottom, right, top = reader.bounds_in(grid.crs)
        extent = f"x {left:.3f}..{right:.3f}, y {bottom:.3f}..{top:.3f}"
    except Exception as exc:  # a CRS pair PROJ cannot transform: still name the raster
        extent = f"unknown in the chip's CRS ({type(exc).__name__})"
    why = "no data" if fraction == 0.0 else f"below chips.min_coverage {minimum:g}"
    raise CoverageError(
        f"{reader.path}: the {what} chip has data on {fraction:.1%} of its pixels ({why}): "
        f"chip x {x0:.3f}..{x1:.3f}, y {y0:.3f}..{y1:.3f}; the {what} covers {extent} "
        "(map units of the dataset CRS)"
    )


def cut_chips(
    view: View, ctx: SampleContext, obs: Observation
) -> tuple[ChipGrid, dict[str, Any], ChipCoverage]:
    """Ortho, DEM and viewshed chips around the rover (north-up or heading-up) and their
    coverage; CoverageError (naming the raster) when a chip has no data or less than
    ``chips.min_coverage``."""
    spec = ctx.config.chips
    rover = view.camera.origin_map
    rotation = 0.0
    if spec.orientation == "heading-up":
        # the chip's up is the camera azimuth, as a map (grid) azimuth
        rotation = float(view.camera.grid_azimuth_deg(view.camera.pointing_az_el()[0]))
    dx, dy = chip_offset(spec.offset_m, sample_key(obs), rotation)
    grid = ChipGrid.around(
        float(rover[0]) + dx,
        float(rover[1]) + dy,
        spec.size_m,
        spec.size_px,
        ctx.crs_wkt,
        rotation_deg=rotation,
    )
    ortho_values, dem = ctx.chip_values(grid)  # NaN where the raster has no data
    cover = ChipCoverage(coverage(ortho_values), coverage(dem))
    check_coverage(cover.ortho, spec.min_coverage, "ortho", ctx.ortho, grid)
    check_coverage(cover.dem, spec.min_coverage, "DEM", ctx.dem, grid)
    # scaled by the ortho's declared or measured range
    ortho = ctx.ortho.value_range().to_uint8(ortho_values)
    vis = resample_array(view.los, view.window.transform, ctx.crs_wkt, grid, nearest=True)
    visible = chip_view(np.nan_to_num(vis) > 0.5, dem, grid, view)
    return (
        grid,
        {
            "ortho": ortho,
            "dem": dem.astype(np.float32),
            "viewshed": visible.astype(np.uint8) * 255,
        },
        cover,
    )


def chip_offset(offset_m: float | None, key: str, rotation_deg: float) -> tuple[float, float]:
    """The chip centre's shift from the rover (map x, y, map units) for ``chips.offset_m``:
    uniform in [-offset_m, offset_m] along the chip's column and row axes, drawn from a
    generator seeded by the sample key's CRC-32 (the same shift on every build and worker).
    (0, 0) when the key is unset or 0."""
    if not offset_m:
        return 0.0, 0.0
    rng = np.random.default_rng([zlib.crc32(key.encode()), 23])
    right, down = rng.uniform(-offset_m, offset_m, size=2)
    t = math.radians(rotation_deg)
    # chip column axis (right) and row axis (down) in map x, y, as in ChipGrid.around
    return (
        float(right * math.cos(t) - down * math.sin(t)),
        float(-right * math.sin(t) - down * math.cos(t)),
    )


def localization_fields(view: View, grid: ChipGrid) -> dict[str, Any]:
    """``rover_px`` (the rover origin) and ``camera_px`` (the camera centre) as chip pixels
    (column, row; pixel-edge coordinates: the first pixel's centre is (0.5, 0.5)), and
    ``heading_deg``: the camera axis's map azimuth, clockwise from the chip's up (row 0)
    direction, degrees in [0, 360)."""
    camera = view.camera
    rover = grid.to_pixel(camera.origin_map[0], camera.origin_map[1])
    centre = grid.to_pixel(camera.center_map[0], camera.center_map[1])
    grid_az = float(camera.grid_azimuth_deg(camera.pointing_az_el()[0]))
    return {
        "rover_px": [float(v) for v in rover],
        "camera_px": [float(v) for v in centre],
        "heading_deg": (grid_az - grid.rotation_deg) % 360.0,
    }


def chip_view(visible: np.ndarray, dem: np.ndarray, grid: ChipGrid, view: View) -> np.ndarray:
    """The chip's viewshed, each pixel tested itself: line of sight of the DEM cell it lies in
    (``visible``: the kernel's mask, nearest) and the view's exact test on the pixel centre's
    own terrain point (``dem`` chip heights): inside the image at the chip's resolution."""
    return view_mask(visible, dem, grid.transform, view).astype(bool)


def correspondence(view: View, grid: ChipGrid) -> np.ndarray:
    """Chip pixel (column, row) of each strided ground pixel's ray hit; NaN for no hit."""
    if view.hits is None:
        return np.zeros((0, 0, 2), dtype=np.float32)
    chip_px = grid.to_pixel(view.hits[:, 0], view.hits[:, 1]).astype(np.float32)
    return chip_px.reshape(*view.grid_shape, 2)
