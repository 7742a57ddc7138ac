"""Synthetic orthoimage that agrees with the synthetic DEM: albedo x hillshade, plus rocks.

Grid convention: the ortho covers exactly the DEM's bounds with ``factor`` x ``factor`` ortho
pixels per DEM cell (row 0 north). Values are 8-bit reflectance, 1..255; 0 is nodata.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from mars_pairs.synth.terrain import Boulders, hillshade, spectral_noise

F64 = NDArray[np.float64]
SUN_AZIMUTH_DEG = 300.0
SUN_ELEVATION_DEG = 35.0


@njit(cache=True)
def upsample_bilinear(a: np.ndarray, factor: int) -> np.ndarray:
    """Bilinear upsampling of cell-centred ``a`` by an integer factor (edges clamped)."""
    n0, n1 = a.shape
    out = np.empty((n0 * factor, n1 * factor), dtype=np.float32)
    for q in range(n0 * factor):
        fy = (q + 0.5) / factor - 0.5
        fy = min(max(fy, 0.0), n0 - 1.0)
        i = min(int(fy), n0 - 2)
        ty = fy - i
        for p in range(n1 * factor):
            fx = (p + 0.5) / factor - 0.5
            fx = min(max(fx, 0.0), n1 - 1.0)
            j = min(int(fx), n1 - 2)
            tx = fx - j
            top = a[i, j] * (1 - tx) + a[i, j + 1] * tx
            bot = a[i + 1, j] * (1 - tx) + a[i + 1, j + 1] * tx
            out[q, p] = top * (1 - ty) + bot * ty
    return out


@njit(cache=True)
def _stamp_rocks(
    img: np.ndarray,
    cols: np.ndarray,
    rows: np.ndarray,
    radii: np.ndarray,
    gains: np.ndarray,
    shadow_dx: float,
    shadow_dy: float,
) -> None:
    """Multiply ``img`` by rock brightness (soft disk) and a dark shadow on the anti-sun side."""
    h, w = img.shape
    for k in range(cols.size):
        r = radii[k]
        ext = int(2.5 * r) + 2
        c0, r0 = cols[k], rows[k]
        for i in range(max(0, int(r0) - ext), min(h, int(r0) + ext + 1)):
            for j in range(max(0, int(c0) - ext), min(w, int(c0) + ext + 1)):
                dx, dy = j + 0.5 - c0, i + 0.5 - r0
                d = np.sqrt(dx * dx + dy * dy) / r
                sx, sy = dx - shadow_dx * r, dy - shadow_dy * r
                ds = np.sqrt(sx * sx + sy * sy) / (1.1 * r)
                f = 1.0
                if ds < 1.0:
                    f *= 0.55 + 0.45 * ds * ds
                if d < 1.0:
                    f = gains[k] * (1.0 - 0.25 * d * d)
                img[i, j] *= f


def _smooth(z: F64, sigma_px: float) -> F64:
    """Gaussian blur through the FFT (periodic edges: used for albedo only)."""
    n0, n1 = z.shape
    fy = np.fft.fftfreq(n0)[:, None]
    fx = np.fft.rfftfreq(n1)[None, :]
    g = np.exp(-2 * (np.pi * sigma_px) ** 2 * (fx * fx + fy * fy))
    return np.fft.irfft2(np.fft.rfft2(z) * g, s=z.shape)


def make_ortho(
    rng: np.random.Generator, dem: F64, res_m: float, factor: int, boulders: Boulders
) -> NDArray[np.uint8]:
    """The orthoimage for ``dem`` (NaN = nodata) at ``res_m / factor`` metres per pixel.

    Albedo: smooth fractal patches, darker sand in local lows, bright boulders and small rocks
    (denser in rocky patches). Shading: the DEM's hillshade (sun at azimuth 300, elevation 35
    degrees), computed at the DEM's resolution and upsampled bilinearly.
    """
    n = dem.shape[0]
    filled = np.where(np.isfinite(dem), dem, np.nanmean(dem))
    shade = hillshade(filled, res_m, SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    low = filled - _smooth(filled, 12.0 / res_m)
    sand = np.clip(-low / 1.5, 0.0, 1.0)
    albedo = 0.5 + 0.07 * spectral_noise(rng, n, 3.2, 3.0 / res_m)
    albedo += 0.025 * spectral_noise(rng, n, 2.0, 2.0 / res_m)
    albedo -= 0.12 * sand
    rockiness = np.clip(0.5 + 0.5 * spectral_noise(rng, n, 3.0, 4.0 / res_m), 0.05, 1.0)
    img = upsample_bilinear((200.0 * albedo * shade).astype(np.float32), factor)

    px_m = res_m / factor
    m = n * factor
    count = int(30000 * (n * res_m / 1000.0) ** 2)
    cols, rows = rng.uniform(0, m, count), rng.uniform(0, m, count)
    keep = rng.random(count) < rockiness[(rows / factor).astype(int), (cols / factor).astype(int)]
    radius_m = 0.12 / np.sqrt(1.0 - rng.random(count) * 0.9)  # many small, few large
    gains = rng.uniform(1.15, 1.5, count)
    bcols, brows = boulders.col * factor, boulders.row * factor
    all_cols = np.concatenate([cols[keep], bcols])
    all_rows = np.concatenate([rows[keep], brows])
    all_r = np.concatenate([radius_m[keep], 0.45 * boulders.diameter_m]) / px_m
    all_g = np.concatenate([gains[keep], np.full(bcols.size, 1.2)])
    az = np.radians(SUN_AZIMUTH_DEG)
    _stamp_rocks(img, all_cols, all_rows, np.maximum(all_r, 0.6), all_g,
                 -0.8 * np.sin(az), 0.8 * np.cos(az))  # fmt: skip
    out = np.clip(np.rint(img), 1, 255).astype(np.uint8)
    bad = ~np.isfinite(dem)
    if bad.any():
        out[np.repeat(np.repeat(bad, factor, 0), factor, 1)] = 0
    return out
