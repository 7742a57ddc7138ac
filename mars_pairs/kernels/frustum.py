"""Numba: the view's exact test of many map points in one pass (``pipeline.sample.view.in_view``
in frustum mode, for CAHV and CAHVOR cameras).

The numpy path makes some thirty temporary arrays of the points for the same steps (map ->
local NED through the inverse Jacobian, the planet's curvature, the range test, the CAHVOR
distortion, the projection, the image bounds); here each point goes through them once. The
dot products are summed in index order, as written, so a point within about 1e-12 pixel of
an image edge (or 1e-12 m of the radius) may fall on the other side from the numpy path's
BLAS sums; the kept points are otherwise the same.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _keeps(
    px: float,
    py: float,
    pz: float,
    origin: np.ndarray,
    m: np.ndarray,
    planet_radius: float,
    centre_local: np.ndarray,
    radius: float,
    cam: np.ndarray,
    distorted: bool,
    x_max: float,
    y_max: float,
) -> bool:
    """The test of one map point (see ``frustum_keep``); ``cam`` rows: C, A, H, V, O, R."""
    d0, d1, d2 = px - origin[0], py - origin[1], pz - origin[2]
    l0 = d0 * m[0, 0] + d1 * m[1, 0] + d2 * m[2, 0]
    l1 = d0 * m[0, 1] + d1 * m[1, 1] + d2 * m[2, 1]
    l2 = d0 * m[0, 2] + d1 * m[1, 2] + d2 * m[2, 2]
    if planet_radius != 0.0:
        l2 += (l0 * l0 + l1 * l1) / (2.0 * planet_radius)
    if not math.hypot(l0 - centre_local[0], l1 - centre_local[1]) <= radius:
        return False
    p0, p1, p2 = l0 - cam[0, 0], l1 - cam[0, 1], l2 - cam[0, 2]
    if distorted:
        zeta = p0 * cam[4, 0] + p1 * cam[4, 1] + p2 * cam[4, 2]
        q0, q1, q2 = p0 - zeta * cam[4, 0], p1 - zeta * cam[4, 1], p2 - zeta * cam[4, 2]
        tau = (q0 * q0 + q1 * q1 + q2 * q2) / (zeta * zeta)
        mu = cam[5, 0] + cam[5, 1] * tau + cam[5, 2] * tau * tau
        p0, p1, p2 = p0 + mu * q0, p1 + mu * q1, p2 + mu * q2
    denom = p0 * cam[1, 0] + p1 * cam[1, 1] + p2 * cam[1, 2]
    if not denom > 0.0:
        return False
    x = (p0 * cam[2, 0] + p1 * cam[2, 1] + p2 * cam[2, 2]) / denom
    y = (p0 * cam[3, 0] + p1 * cam[3, 1] + p2 * cam[3, 2]) / denom
    inside: bool = x >= -0.5 and x <= x_max and y >= -0.5 and y <= y_max
    return inside


@njit(cache=True, error_model="numpy")
def frustum_keep(
    points: np.ndarray,
    origin: np.ndarray,
    inv_jacobian_t: np.ndarray,
    planet_radius: float,
    centre_local: np.ndarray,
    radius: float,
    cam: np.ndarray,
    distorted: bool,
    width: int,
    height: int,
) -> np.ndarray:
    """Which map points (N, 3: x, y map units, z metres; float64) the frustum test keeps.

    A point is taken to local NED metres at the rover, ``(p - origin) @ inv_jacobian_t``
    (``MapCamera.map_to_local``), lowered by d^2 / (2 ``planet_radius``) (d its horizontal
    distance from the rover; 0: no curvature); it is kept when its horizontal distance from
    ``centre_local`` (the camera centre, local NED) is at most ``radius`` (true metres) and
    the camera projects it in front of it inside the image's outer pixel edges: sample in
    [-0.5, ``width`` - 0.5], line in [-0.5, ``height`` - 0.5]. ``cam`` (6, 3): the camera's
    C, A, H, V and, used with ``distorted`` (CAHVOR), O and R."""
    n = points.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    x_max, y_max = width - 0.5, height - 0.5
    for i in range(n):
        out[i] = _keeps(
            points[i, 0], points[i, 1], points[i, 2], origin, inv_jacobian_t, planet_radius,
            centre_local, radius, cam, distorted, x_max, y_max,
        )  # fmt: skip
    return out


@njit(cache=True, error_model="numpy")
def frustum_mask(
    selected: np.ndarray,
    heights: np.ndarray,
    transform: np.ndarray,
    origin: np.ndarray,
    inv_jacobian_t: np.ndarray,
    planet_radius: float,
    centre_local: np.ndarray,
    radius: float,
    cam: np.ndarray,
    distorted: bool,
    width: int,
    height: int,
) -> np.ndarray:
    """``frustum_keep`` of the cells of a grid: uint8 (rows, cols), 1 where ``selected``
    (nonzero), the height finite and the cell's centre kept. ``heights`` (rows, cols: float32
    metres, NaN for none); ``transform`` (6: a, b, c, d, e, f) maps (col, row) pixel corners
    to map x, y as ``affine`` does (x = (col + 0.5) a + (row + 0.5) b + c at the centre)."""
    rows, cols = selected.shape
    out = np.zeros((rows, cols), dtype=np.uint8)
    a, b, c, d, e, f = (transform[0], transform[1], transform[2], transform[3],
                        transform[4], transform[5])  # fmt: skip
    x_max, y_max = width - 0.5, height - 0.5
    for r in range(rows):
        vy = r + 0.5
        for q in range(cols):
            if selected[r, q] == 0:
                continue
            z = heights[r, q]
            if not math.isfinite(z):
                continue
            vx = q + 0.5
            x = vx * a + vy * b + c
            y = vx * d + vy * e + f
            if _keeps(x, y, np.float64(z), origin, inv_jacobian_t, planet_radius,
                      centre_local, radius, cam, distorted, x_max, y_max):  # fmt: skip
                out[r, q] = 1
    return out
