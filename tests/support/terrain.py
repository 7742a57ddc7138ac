"""Terrain and grids of the kernel tests: seeded fractal DEMs, a north-up grid at a Jezero-like
origin, grid <-> map and a numpy bilinear interpolation. Map frame: x east, y north (metres);
grid (col, row) with cell centres at integers."""

from __future__ import annotations

import numpy as np
from affine import Affine

from mars_pairs.synth.terrain import spectral_noise

X0, Y0 = 4351200.0, 1095210.0  # a Jezero-like map origin (upper-left corner)


def fractal_dem(n: int, seed: int, std: float = 4.0, beta: float = 1.6) -> np.ndarray:
    """Seeded spectral-synthesis fractal (n x n float32 metres): amplitude ~ 1/f^beta."""
    return (spectral_noise(np.random.default_rng(seed), n, 2.0 * beta) * std).astype(np.float32)


def grid(n: int, cell: float = 1.0) -> Affine:
    """North-up transform of an n x n grid of ``cell`` metre pixels at the test origin."""
    return Affine(cell, 0.0, X0, 0.0, -cell, Y0)


def centre_xy(tr: Affine, col: float, row: float) -> tuple[float, float]:
    """Map x, y of grid (col, row) with cell centres at integers."""
    return tr @ (col + 0.5, row + 0.5)


def bilinear_np(dem: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Numpy bilinear interpolation at grid (u, v), cell centres at integers (clamped)."""
    h, w = dem.shape
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    c0 = np.minimum(np.floor(u).astype(int), w - 2)
    r0 = np.minimum(np.floor(v).astype(int), h - 2)
    fu, fv = u - c0, v - r0
    return (
        dem[r0, c0] * (1 - fu) * (1 - fv)
        + dem[r0, c0 + 1] * fu * (1 - fv)
        + dem[r0 + 1, c0] * (1 - fu) * fv
        + dem[r0 + 1, c0 + 1] * fu * fv
    )
