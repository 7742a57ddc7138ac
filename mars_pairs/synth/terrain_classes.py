"""The synthetic mission's true terrain classes, on the ortho grid, in AI4Mars values.

Derived from the terrain the ortho is drawn from, without drawing any random number (so the
mission's other files keep their bytes): sand (2) where the ortho darkens local lows into
rippled sand (``synth.ortho``: the DEM minus its 12 m smoothing below -0.4 m, sand weight
> 1/3), bedrock (1) on slopes steeper than 14 degrees (crater walls, ridge flanks), big rock
(3) on the DEM's boulders (disks of 0.45 diameter, as the ortho stamps them), soil (0) else;
255 where the DEM has no data. Grid: the ortho's (``factor`` pixels per DEM cell, row 0
north).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mars_pairs.synth.ortho import sand_weight
from mars_pairs.synth.terrain import Boulders

SOIL, BEDROCK, SAND, BIG_ROCK, NO_LABEL = 0, 1, 2, 3, 255
SAND_WEIGHT = 1.0 / 3.0
BEDROCK_SLOPE_DEG = 14.0


def terrain_classes(dem: NDArray[np.float64], res_m: float, factor: int,
                    boulders: Boulders) -> NDArray[np.uint8]:  # fmt: skip
    """(n * factor, n * factor) uint8 classes of ``dem`` (n x n, NaN nodata, ``res_m``
    metres a cell) on the ortho grid."""
    filled = np.where(np.isfinite(dem), dem, np.nanmean(dem))
    sand = sand_weight(filled, res_m)
    gy, gx = np.gradient(filled, res_m)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    cells = np.full(dem.shape, SOIL, dtype=np.uint8)
    cells[slope > BEDROCK_SLOPE_DEG] = BEDROCK
    cells[sand > SAND_WEIGHT] = SAND
    out = np.repeat(np.repeat(cells, factor, axis=0), factor, axis=1)
    m = out.shape[0]
    px_m = res_m / factor
    for col, row, diam in zip(boulders.col, boulders.row, boulders.diameter_m, strict=True):
        r = 0.45 * diam / px_m
        c0, r0 = col * factor, row * factor
        i0, i1 = max(0, int(r0 - r) - 1), min(m, int(r0 + r) + 2)
        j0, j1 = max(0, int(c0 - r) - 1), min(m, int(c0 + r) + 2)
        if i0 >= i1 or j0 >= j1:
            continue
        ii, jj = np.mgrid[i0:i1, j0:j1]
        inside = (jj + 0.5 - c0) ** 2 + (ii + 0.5 - r0) ** 2 < r * r
        out[i0:i1, j0:j1][inside] = BIG_ROCK
    bad = ~np.isfinite(dem)
    if bad.any():
        out[np.repeat(np.repeat(bad, factor, 0), factor, 1)] = NO_LABEL
    return out
