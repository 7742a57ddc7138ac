"""Every grid index the viewshed kernel touches lies inside the grid.

numba does not check indices: a read one line past the DEM returns garbage (a wrong error
bar) or, where the array ends at the end of a heap, kills the process (seen on Dask workers).
Here the kernel's functions run as plain Python on small grids, where numpy checks every
index, with observers at and near the edges and wedges in every direction; the answer must
be the compiled kernel's (up to its contracted multiply-adds)."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from numba.core.registry import CPUDispatcher

import mars_pairs.kernels.viewshed as kernel_module
from mars_pairs.kernels import compute_viewshed

N = 40  # cells a side, 1 m cells
TRANSFORM = Affine(1.0, 0.0, 0.0, 0.0, -1.0, float(N))


def rough_dem(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (rng.normal(0.0, 1.5, (N, N)).cumsum(axis=0) * 0.3).astype(np.float32)


def viewshed(dem: np.ndarray, col: float, row: float, az_band, radius: float = 60.0) -> np.ndarray:
    x, y = TRANSFORM * (col + 0.5, row + 0.5)
    return compute_viewshed((dem, TRANSFORM), x, y, height=1.5, radius=radius, az_band=az_band)


@pytest.fixture
def as_python(monkeypatch: pytest.MonkeyPatch):
    """Swap every compiled function the kernel module calls for its Python original."""

    def swap() -> None:
        for name, value in list(vars(kernel_module).items()):
            if isinstance(value, CPUDispatcher):
                monkeypatch.setattr(kernel_module, name, value.py_func)
        as_grid = kernel_module.as_grid

        def as_grid64(*args, **kwargs):
            # compiled code reads float32 cells into float64 arithmetic; numpy would keep
            # float32 scalars float32 (NEP 50), so the Python run gets the same values as float64
            dem, transform = as_grid(*args, **kwargs)
            return dem.astype(np.float64), transform

        monkeypatch.setattr(kernel_module, "as_grid", as_grid64)

    return swap


CASES = [
    (3, 11.0, 2.0, (100.0, 140.0)),  # near the top edge, looking east-south-east
    (4, 0.0, 20.0, (30.0, 150.0)),  # on the left edge, looking east
    (5, 39.0, 39.0, (270.0, 360.0)),  # bottom-right corner, looking north-west
    (6, 20.3, 28.6, (160.0, 200.0)),  # 11 lines above the bottom edge, looking south
    (7, 33.0, 17.0, None),  # full circle (tree of rays), near the right edge
]


@pytest.mark.parametrize(("seed", "col", "row", "az_band"), CASES)
def test_no_index_leaves_the_grid(as_python, seed: int, col: float, row: float, az_band) -> None:
    dem = rough_dem(seed)
    compiled = viewshed(dem, col, row, az_band)
    as_python()
    checked = viewshed(dem, col, row, az_band)  # IndexError on any index off the grid
    assert compiled.sum() > 0
    # the same algorithm; the compiled one contracts multiply-adds (fastmath "contract"),
    # which moves cells whose sight line grazes the terrain
    both = np.count_nonzero((checked == 1) & (compiled == 1))
    either = np.count_nonzero((checked == 1) | (compiled == 1))
    assert both / either >= 0.99  # 1.0 on every case here


QUADRANTS = [(0.0, 90.0), (90.0, 180.0), (180.0, 270.0), (270.0, 360.0)]


@pytest.mark.parametrize("az_band", QUADRANTS)
@pytest.mark.parametrize(("col", "row"), [(5.0, 28.0), (28.0, 5.0), (34.0, 11.0), (11.0, 34.0)])
def test_rays_whose_step_lands_exactly_on_the_last_line(as_python, az_band, col, row) -> None:
    """Radius 20 cells: rays of resolution P = 21; the observer 11 lines from one edge and
    more than 21 from the opposite one. A ray with minor step k = 11 reaches the last line
    exactly at step 21 (11 * 21 = 21 * 11), where the float bound rounded up; rows and
    columns as the minor axis, both directions."""
    dem = rough_dem(8)
    compiled = viewshed(dem, col, row, az_band, radius=20.0)
    as_python()
    checked = viewshed(dem, col, row, az_band, radius=20.0)
    assert compiled.sum() > 0
    both = np.count_nonzero((checked == 1) & (compiled == 1))
    assert both / np.count_nonzero((checked == 1) | (compiled == 1)) >= 0.99
