"""Synthetic Mars terrain: a fractal DEM with craters, ridges and boulders.

Grid convention: a square array of ``n`` x ``n`` cells at ``res_m`` metres, row 0 at the north
edge; values are elevations in metres above the areoid (z up). Everything is drawn from one
``numpy.random.Generator`` so that a seed gives the same terrain bit for bit.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mars_pairs.raster.shading import lambert_shading

F64 = NDArray[np.float64]
C128 = NDArray[np.complex128]


@dataclass(frozen=True)
class Boulders:
    """Boulder centres (col, row in DEM cells, fractional), diameters and heights (metres)."""

    col: F64
    row: F64
    diameter_m: F64
    height_m: F64


def noise_spectrum(rng: np.random.Generator, n: int, beta: float, cutoff_px: float = 0.0) -> C128:
    """The random half-spectrum (n x (n // 2 + 1)) of ``spectral_noise``: all its draws."""
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2.0)
    if cutoff_px > 0:
        amp *= np.exp(-((f * cutoff_px) ** 2))
    amp[0, 0] = 0.0
    spec: C128 = (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)) * amp
    return spec


def noise_field(spec: C128) -> F64:
    """The n x n field of a ``noise_spectrum``, zero mean, unit standard deviation (no draw:
    may run on another thread while the generator draws on)."""
    n = spec.shape[0]
    field = np.fft.irfft2(spec, s=(n, n))
    field -= field.mean()
    return np.asarray(field / field.std())


def spectral_noise(rng: np.random.Generator, n: int, beta: float, cutoff_px: float = 0.0) -> F64:
    """Isotropic 1/f^beta noise on an n x n grid, zero mean, unit standard deviation.

    ``cutoff_px``: wavelengths shorter than about this many cells are rolled off (Gaussian).
    """
    return noise_field(noise_spectrum(rng, n, beta, cutoff_px))


def _add_craters(rng: np.random.Generator, z: F64, res_m: float, count: int) -> None:
    """Add bowl craters with raised rims; diameters follow a D^-2 cumulative power law."""
    n = z.shape[0]
    d_min, d_max = 6.0, min(0.3 * n * res_m, 350.0)
    u = rng.random(count)
    # truncated Pareto (cumulative N(>D) ~ D^-2)
    diam = d_min / np.sqrt(1.0 - u * (1.0 - (d_min / d_max) ** 2))
    cx = rng.uniform(0, n, count)
    cy = rng.uniform(0, n, count)
    freshness = rng.uniform(0.25, 1.0, count)
    for d, x0, y0, fr in zip(diam, cx, cy, freshness, strict=True):
        radius = 0.5 * d / res_m
        depth = 0.2 * d * fr
        rim = 0.035 * d * fr
        ext = int(np.ceil(radius * 3.0))
        i0, i1 = max(0, int(y0) - ext), min(n, int(y0) + ext + 1)
        j0, j1 = max(0, int(x0) - ext), min(n, int(x0) + ext + 1)
        if i0 >= i1 or j0 >= j1:
            continue
        yy, xx = np.ogrid[i0:i1, j0:j1]  # broadcast: the values of full index grids
        r = np.hypot(xx + 0.5 - x0, yy + 0.5 - y0) / radius
        inside = -depth + (depth + rim) * r * r
        outside = rim * np.maximum(r, 1.0) ** -3.0  # (np.clip's values, without its overhead)
        prof = np.where(r < 1.0, inside, outside)
        # fade the far ejecta to zero at the window edge
        prof *= np.minimum(np.maximum((3.0 - r) / 1.5, 0.0), 1.0)
        z[i0:i1, j0:j1] += prof


@dataclass(frozen=True)
class Ridge:
    """One sinuous ridge's draws: direction (radians), centre (col, row in cells), length,
    width (cells), height (metres), the centre line's two waves (wavenumbers per cell,
    phases) and its wiggle amplitude (cells)."""

    theta: float
    x0: float
    y0: float
    length: float
    width: float
    height: float
    k1: float
    k2: float
    p1: float
    p2: float
    wig: float


def _draw_ridge(rng: np.random.Generator, n: int, res_m: float) -> Ridge:
    theta = rng.uniform(0, np.pi)
    x0, y0 = rng.uniform(0.1 * n, 0.9 * n, 2)
    length = rng.uniform(0.3, 0.8) * min(n, 1500.0 / res_m)
    width = rng.uniform(8.0, 25.0) / res_m
    height = rng.uniform(2.0, 8.0)
    k1, k2 = rng.uniform(1.0, 3.0, 2) * 2 * np.pi / length
    p1, p2 = rng.uniform(0, 2 * np.pi, 2)
    wig = rng.uniform(0.02, 0.08) * length
    return Ridge(theta, x0, y0, length, width, height, k1, k2, p1, p2, wig)


def _ridge_bump(r: Ridge, n: int) -> tuple[slice, slice, F64]:
    """The window (rows, cols) of ridge ``r`` on an n x n grid and its heights there."""
    ext = int(0.5 * r.length + 1.5 * r.wig + 3 * r.width) + 1
    i0, i1 = max(0, int(r.y0) - ext), min(n, int(r.y0) + ext + 1)
    j0, j1 = max(0, int(r.x0) - ext), min(n, int(r.x0) + ext + 1)
    yy, xx = (g.astype(np.float64) for g in np.ogrid[i0:i1, j0:j1])  # broadcast index grids
    s = (xx - r.x0) * np.cos(r.theta) + (yy - r.y0) * np.sin(r.theta)
    t = -(xx - r.x0) * np.sin(r.theta) + (yy - r.y0) * np.cos(r.theta)
    off = r.wig * (np.sin(r.k1 * s + r.p1) + 0.5 * np.sin(r.k2 * s + r.p2))
    taper = np.sqrt(np.clip(1.0 - (2.0 * s / r.length) ** 2, 0.0, 1.0))
    return slice(i0, i1), slice(j0, j1), r.height * taper * np.exp(-(((t - off) / r.width) ** 2))


def _add_ridges(rng: np.random.Generator, z: F64, res_m: float, count: int) -> None:
    """Add sinuous ridges: Gaussian cross-section around a wavy centre line, tapered ends.
    Their shapes are computed on two threads (numpy's large-array loops release the GIL),
    added to ``z`` in the order drawn (the same sums as one thread's)."""
    n = z.shape[0]
    ridges = [_draw_ridge(rng, n, res_m) for _ in range(count)]
    with ThreadPoolExecutor(2) as pool:
        pending = [pool.submit(_ridge_bump, r, n) for r in ridges[:2]]
        for k in range(count):
            rows, cols, bump = pending.pop(0).result()
            if k + 2 < count:  # at most two bumps (up to ~13 MB each) in flight
                pending.append(pool.submit(_ridge_bump, ridges[k + 2], n))
            z[rows, cols] += bump


def _boulders(rng: np.random.Generator, n: int, res_m: float, count: int) -> Boulders:
    d = rng.uniform(1.5, 4.0, count)
    return Boulders(
        col=rng.uniform(0, n, count),
        row=rng.uniform(0, n, count),
        diameter_m=d,
        height_m=d * rng.uniform(0.25, 0.45, count),
    )


def _add_boulders(z: F64, res_m: float, b: Boulders) -> None:
    """Add boulders as Gaussian bumps (a 1 m DEM resolves only their rough shape)."""
    n = z.shape[0]
    for x0, y0, d, h in zip(b.col, b.row, b.diameter_m, b.height_m, strict=True):
        sigma = 0.35 * d / res_m
        ext = int(np.ceil(3 * sigma)) + 1
        i0, i1 = max(0, int(y0) - ext), min(n, int(y0) + ext + 1)
        j0, j1 = max(0, int(x0) - ext), min(n, int(x0) + ext + 1)
        yy, xx = np.ogrid[i0:i1, j0:j1]
        r2 = (xx + 0.5 - x0) ** 2 + (yy + 0.5 - y0) ** 2
        z[i0:i1, j0:j1] += h * np.exp(-r2 / (2 * sigma * sigma))


def make_dem(
    rng: np.random.Generator, n: int, res_m: float, base_elevation_m: float
) -> tuple[F64, Boulders]:
    """An n x n DEM (metres above the areoid, row 0 north) and the boulders put on it.

    Relief: about 4.5 m RMS of rolling fractal terrain (wavelengths below ~4 m rolled off like a
    HiRISE stereo DTM), craters 6..350 m wide, a few ridges, and boulders 1.5..4 m wide.
    """
    area_km2 = (n * res_m / 1000.0) ** 2
    with ThreadPoolExecutor(1) as pool:  # the first field's transform beside the second's draws
        first = pool.submit(noise_field, noise_spectrum(rng, n, beta=4.2, cutoff_px=4.0 / res_m))
        second = spectral_noise(rng, n, beta=2.4, cutoff_px=3.0 / res_m)
        z = 4.5 * first.result()
    z += 0.12 * second
    _add_craters(rng, z, res_m, int(150 * area_km2))
    _add_ridges(rng, z, res_m, max(2, int(3 * area_km2)))
    boulders = _boulders(rng, n, res_m, int(150 * area_km2))
    _add_boulders(z, res_m, boulders)
    return z + base_elevation_m, boulders


def hillshade(z: F64, res_m: float, sun_azimuth_deg: float, sun_elevation_deg: float) -> F64:
    """Lambertian shading of a DEM (row 0 north, metres, ``res_m`` metres a cell; sun azimuth
    degrees clockwise from north, elevation degrees) relative to flat ground; >= 0, flat = 1
    (:func:`mars_pairs.raster.shading.lambert_shading` over sin(elevation))."""
    shade = lambert_shading(z, res_m, sun_azimuth_deg, sun_elevation_deg)
    relative: F64 = shade / np.sin(np.radians(sun_elevation_deg))
    return relative
