"""``python -m mars_pairs.warmup``: compile every numba kernel the commands run, once, into
numba's cache, so that no command's first call compiles.

The cache is numba's default: ``__pycache__`` folders beside the package's modules (the
install's own folders; ``NUMBA_CACHE_DIR`` moves it, e.g. for a read-only install). ``make
demo`` and ``make test`` run this after installing; a later run only loads the cache (~1 s).
Compiled: the build's and the viewshed command's kernels (``kernels.warm``, all their
dtypes, serial and parallel paths), the point sampler's dtypes and the synthetic mission's
kernels (``synth.warm``).
"""

from __future__ import annotations

import time

import numpy as np

from mars_pairs.kernels.warm import warm_kernels
from mars_pairs.raster.transfer import sample_at
from mars_pairs.runtime import configure_process
from mars_pairs.synth.warm import warm_mission_kernels

#: the raster dtypes the point sampler (``raster.transfer.sample_at``: one compiled version
#: per dtype) is compiled for: DEM and ortho values, 8- and 16-bit images and class rasters,
#: anything else (read as float64)
SAMPLED_DTYPES = (np.float32, np.float64, np.uint8, np.uint16, np.int16)


def warm_all() -> None:
    """Load (compile on a cold cache) every kernel of ``kernels.warm`` and ``synth.warm``,
    and the point sampler for each of ``SAMPLED_DTYPES``."""
    warm_mission_kernels()  # first: a mission's render workers start before the build's
    warm_kernels()
    raster = np.zeros((4, 4), dtype=np.float32)
    points = np.array([1.5, 2.25])
    for dtype in SAMPLED_DTYPES:
        sample_at(raster.astype(dtype), points, points, nearest=True)


def main() -> None:
    """Warm every kernel (``warm_all``) and print how long it took."""
    configure_process()
    t = time.perf_counter()
    warm_all()
    print(f"numba kernels compiled or loaded from the cache in {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
