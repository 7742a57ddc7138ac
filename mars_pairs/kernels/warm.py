"""Load every compiled kernel a build and the viewshed command use, on a tiny grid, before
the first sample.

A new worker process spends ~0.45 s on its first sample loading numba's cached machine
code (0.3 s of it the viewshed's). Called in a worker's initializer, the loading overlaps
the driver's planning instead of delaying the first result. The arguments have the types of
a build's calls (float32 C-ordered DEM windows, float64 rays), so the same compiled versions
are loaded; on a cold cache they are compiled and saved (``mars_pairs.warmup`` runs this at
install). One call compiles a kernel's serial and parallel paths both (they are branches of
one compiled function). (Not in the fork server that the workers are forked from: loading a
kernel that can run in parallel starts numba's OpenMP threads, and a process with OpenMP
threads must not fork.)
"""

from __future__ import annotations

import numpy as np
from affine import Affine

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.kernels.frustum import frustum_keep, frustum_mask
from mars_pairs.kernels.nodata import float32_nodata_nan, uint8_nodata_nan
from mars_pairs.kernels.quantize import quantize_steps
from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.resample import sample_affine
from mars_pairs.kernels.viewshed import compute_viewshed


def warm_kernels() -> None:
    """Run the viewshed (wedge and full circle), the ray caster, the chip resampler and the
    view's frustum test (points; a uint8 and a boolean cell selection) once on a 16 x 16
    grid of 1 m cells."""
    dem = np.linspace(0.0, 3.0, 256, dtype=np.float32).reshape(16, 16)
    transform = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 16.0)
    grid = (dem, transform)
    for band in ((10.0, 50.0), None):
        compute_viewshed(grid, 8.5, 7.5, height=1.5, radius=6.0, az_band=band,
                         el_band=(-40.0, 10.0), planet_radius=MARS_RADIUS_M)  # fmt: skip
    origins = np.array([[8.5, 7.5, 5.0]])
    directions = np.array([[0.6, 0.0, -0.8]])
    cast_rays(origins, directions, grid, max_range=6.0, observer_xy=(8.5, 7.5))
    for nearest in (False, True):  # axis-aligned and rotated: both paths
        sample_affine(dem, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 8, 8, nearest)
        sample_affine(dem, 0.8, -0.6, 4.0, 0.6, 0.8, 2.0, 8, 8, nearest)
    camera = np.array([[0.0, 0.0, -1.5], [1.0, 0.0, 0.0], [8.0, 10.0, 0.0], [8.0, 0.0, 10.0],
                       [1.0, 0.0, 0.0], [0.0, 0.01, 0.0]])  # fmt: skip
    args = (np.array([8.5, 7.5, 0.0]), np.eye(3), MARS_RADIUS_M, np.array([0.0, 0.0, -1.5]),
            6.0, camera, True, 16, 16)  # fmt: skip
    frustum_keep(np.array([[10.0, 7.5, 0.0]]), *args)
    quantize_steps(dem, -1.0, 2.0**-7, 65534, 65535)  # a DEM chip's dem.tif values
    for nonfinite in (False, True):  # a float32 DEM block read with its nodata
        float32_nodata_nan(dem, np.float32(-3.4028234663852886e38), nonfinite)
    uint8_nodata_nan(dem.astype(np.uint8), 0)  # an 8-bit ortho's
    coefficients = np.array(tuple(transform)[:6])
    frozen = dem.copy()  # a chip's DEM values, read-only (``SampleContext.chip_values``)
    frozen.flags.writeable = False
    # the DEM window's line of sight (uint8) and a chip's seen pixels (bool)
    frustum_mask((dem > 1.0).astype(np.uint8), dem, coefficients, *args)
    frustum_mask(dem > 1.0, frozen, coefficients, *args)
