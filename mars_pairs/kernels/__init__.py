"""Numba kernels on DEM windows: viewshed masks and per-ray terrain intersection.

Both work in the DEM window's projected map frame: x, y map units (~metres), z metres of
elevation, azimuth clockwise from grid north.
"""

from mars_pairs.kernels.raycast import cast_rays
from mars_pairs.kernels.viewshed import compute_viewshed

__all__ = ["cast_rays", "compute_viewshed"]
