"""Synthetic orthoimage that agrees with the synthetic DEM: albedo x hillshade, plus rocks.

Grid convention: the ortho covers exactly the DEM's bounds with ``factor`` x ``factor`` ortho
pixels per DEM cell (row 0 north, column 0 west). Values are 8-bit reflectance, 1..255; 0 is
nodata. Texture is built at two scales: DEM-cell scale (albedo patches, sand in lows, the
DEM's hillshade), upsampled bilinearly, times ortho-pixel scale (grain, wind ripples on the
sand, rocks with their sunlit side and cast shadow), so 0.25-0.5 m pixels show detail.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from mars_pairs.synth.terrain import Boulders, hillshade, spectral_noise

F64 = NDArray[np.float64]
SUN_AZIMUTH_DEG = 300.0  # clockwise from north
SUN_ELEVATION_DEG = 32.0
RIPPLE_WAVELENGTH_M = 3.0
_TILE = 1024  # side (ortho pixels) of the periodic fine-texture tile


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


@njit(cache=True, parallel=True)
def compose_ortho(
    coarse: np.ndarray, sand: np.ndarray, grain: np.ndarray, ripple: np.ndarray, factor: int
) -> np.ndarray:
    """Ortho-resolution brightness: upsampled ``coarse`` x (1 + grain) x (1 + sand x ripple).

    ``coarse`` and ``sand``: DEM-cell grids (cell centred); ``grain`` and ``ripple``: periodic
    tiles in ortho pixels, repeated over the output. Rows over numba's threads (each pixel
    its own: the values of one thread's loop).
    """
    n0, n1 = coarse.shape
    th, tw = grain.shape
    out = np.empty((n0 * factor, n1 * factor), dtype=np.float32)
    for q in prange(n0 * factor):
        fy = min(max((q + 0.5) / factor - 0.5, 0.0), n0 - 1.0)
        i = min(int(fy), n0 - 2)
        ty = fy - i
        tq = q % th
        for p in range(n1 * factor):
            fx = min(max((p + 0.5) / factor - 0.5, 0.0), n1 - 1.0)
            j = min(int(fx), n1 - 2)
            tx = fx - j
            c = (coarse[i, j] * (1 - tx) + coarse[i, j + 1] * tx) * (1 - ty) + (
                coarse[i + 1, j] * (1 - tx) + coarse[i + 1, j + 1] * tx
            ) * ty
            s = (sand[i, j] * (1 - tx) + sand[i, j + 1] * tx) * (1 - ty) + (
                sand[i + 1, j] * (1 - tx) + sand[i + 1, j + 1] * tx
            ) * ty
            tp = p % tw
            out[q, p] = c * (1.0 + grain[tq, tp]) * (1.0 + s * ripple[tq, tp])
    return out


@njit(cache=True)
def stamp_rocks(
    img: np.ndarray,
    cols: np.ndarray,
    rows: np.ndarray,
    radii: np.ndarray,
    gains: np.ndarray,
    sun_x: float,
    sun_y: float,
    sun_z: float,
) -> None:
    """Paint rocks (ortho pixels; centres, radii) on ``img`` in place.

    A rock is a dome lit by the sun (unit vector in image axes: x = column, y = row (south),
    z = up): Lambert shading of its surface normal times its albedo ``gains[k]`` relative to
    the ground. Its cast shadow is the disk swept away from the sun over the shadow length.
    """
    h, w = img.shape
    horiz = math.sqrt(sun_x * sun_x + sun_y * sun_y)
    ax, ay = -sun_x / horiz, -sun_y / horiz  # anti-sun direction on the image
    for k in range(cols.size):
        r = radii[k]
        c0, r0 = cols[k], rows[k]
        slen = 0.7 * r * sun_z / horiz + 0.6 * r  # dome height ~0.7 r, plus the rock's own side
        ext = int(r + slen) + 2
        for i in range(max(0, int(r0) - ext), min(h, int(r0) + ext + 1)):
            for j in range(max(0, int(c0) - ext), min(w, int(c0) + ext + 1)):
                dx, dy = j + 0.5 - c0, i + 0.5 - r0
                d2 = (dx * dx + dy * dy) / (r * r)
                if d2 < 1.0:
                    nz = math.sqrt(1.0 - d2)
                    nx, ny = 0.9 * dx / r, 0.9 * dy / r
                    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
                    lam = max(0.0, (nx * sun_x + ny * sun_y + nz * sun_z) / nn) / sun_z
                    img[i, j] *= gains[k] * (0.18 + 0.82 * lam)
                    continue
                # distance from the shadow axis segment (centre -> centre + slen * anti-sun)
                u = min(max(dx * ax + dy * ay, 0.0), slen)
                ex, ey = dx - u * ax, dy - u * ay
                if ex * ex + ey * ey < r * r:
                    img[i, j] *= 0.42


def _smooth(z: F64, sigma_px: float) -> F64:
    """Gaussian blur through the FFT (periodic edges: used for albedo only)."""
    n0, n1 = z.shape
    fy = np.fft.fftfreq(n0)[:, None]
    fx = np.fft.rfftfreq(n1)[None, :]
    g = np.exp(-2 * (np.pi * sigma_px) ** 2 * (fx * fx + fy * fy))
    return np.fft.irfft2(np.fft.rfft2(z) * g, s=z.shape)


def sand_weight(filled: F64, res_m: float) -> F64:
    """0..1 sand weight of DEM cells (``filled``: no NaN, ``res_m`` metres a cell): how far a
    cell lies below its 12 m Gaussian mean, 1 at 1.2 m or more below."""
    low = filled - _smooth(filled, 12.0 / res_m)
    return np.clip(-low / 1.2, 0.0, 1.0)


def _smoothstep(x: F64, lo: float, hi: float) -> F64:
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fine_texture(
    rng: np.random.Generator, tile: int, px_m: float
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Periodic (tile x tile ortho pixels of ``px_m`` metres) relative grain and ripple fields.

    Grain: speckle of about +-6 %. Ripples: sinuous crests about ``RIPPLE_WAVELENGTH_M`` apart,
    at right angles to a random wind, bright stoss / dark lee sides, +-25 % where fully sandy.
    """
    grain = 0.06 * spectral_noise(rng, tile, 1.6, 0.0)
    theta = rng.uniform(0.0, np.pi)
    cycles = tile * px_m / RIPPLE_WAVELENGTH_M
    kx, ky = round(cycles * np.cos(theta)), round(cycles * np.sin(theta))
    v, u = (g.astype(np.float64) / tile for g in np.ogrid[0:tile, 0:tile])  # broadcast
    bend = 2.2 * spectral_noise(rng, tile, 4.0, 0.0)  # radians of phase: sinuous crests
    phase = 2.0 * np.pi * (kx * u + ky * v) + bend
    strength = np.clip(0.65 + 0.35 * spectral_noise(rng, tile, 3.0, 0.0), 0.0, 1.0)
    ripple = 0.2 * strength * (np.sin(phase) + 0.35 * np.sin(2.0 * phase))
    return grain.astype(np.float32), ripple.astype(np.float32)


def fill_nodata(dem: F64) -> F64:
    """``dem`` with its NaN cells set to the mean of the others."""
    filled: F64 = np.where(np.isfinite(dem), dem, np.nanmean(dem))
    return filled


def make_ortho(
    rng: np.random.Generator, dem: F64, res_m: float, factor: int, boulders: Boulders,
    *, filled: F64 | None = None,
) -> NDArray[np.uint8]:  # fmt: skip
    """The orthoimage for ``dem`` (NaN = nodata) at ``res_m / factor`` metres per pixel.

    Albedo: fractal patches, dark sand sheets, darker rippled sand in local lows, grain, and
    rocks 0.1..1 m wide (denser in rocky patches) plus the DEM's boulders, each with a sunlit
    side and a cast shadow. Shading: the DEM's hillshade (sun at azimuth 300, elevation 32
    degrees), computed at the DEM's resolution and upsampled bilinearly. ``filled``:
    ``fill_nodata(dem)`` when the caller has it.
    """
    n = dem.shape[0]
    px_m = res_m / factor
    m = n * factor
    filled = fill_nodata(dem) if filled is None else filled
    # the DEM's shading and sand (no draw) on a thread beside the noise fields' draws (numpy's
    # large-array loops release the GIL); the same values as computed one after the other
    with ThreadPoolExecutor(1) as pool:
        shading = pool.submit(hillshade, filled, res_m, SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
        sanding = pool.submit(sand_weight, filled, res_m)
        albedo = 0.52 + 0.09 * spectral_noise(rng, n, 3.2, 3.0 / res_m)
        albedo += 0.03 * spectral_noise(rng, n, 2.0, 2.0 / res_m)
        dark = _smoothstep(spectral_noise(rng, n, 3.0, 5.0 / res_m), 0.2, 1.1)
        rocky = spectral_noise(rng, n, 3.0, 4.0 / res_m)
        grain, ripple = fine_texture(rng, min(m, _TILE), px_m)
        shade, sand = shading.result(), sanding.result()
    albedo *= (1.0 - 0.32 * dark) * (1.0 - 0.22 * sand)
    sand = np.maximum(sand, 0.8 * dark)  # the dark sheets are rippled sand too
    rockiness = np.clip(0.45 + 0.55 * rocky, 0.03, 1.0)
    rockiness *= 1.0 - 0.9 * sand  # few rocks on the sand

    coarse = (200.0 * albedo * shade).astype(np.float32)
    img = compose_ortho(coarse, sand.astype(np.float32), grain, ripple, factor)

    count = int(90000 * (n * res_m / 1000.0) ** 2)
    cols, rows = rng.uniform(0, m, count), rng.uniform(0, m, count)
    keep = rng.random(count) < rockiness[(rows / factor).astype(int), (cols / factor).astype(int)]
    r_min, r_max = 0.07, 0.8  # rock radius, metres: cumulative N(>r) ~ r^-2
    radius_m = r_min / np.sqrt(1.0 - rng.random(count) * (1.0 - (r_min / r_max) ** 2))
    gains = np.exp(rng.normal(0.0, 0.25, count)) * 1.1  # dark basalt to bright float rocks
    bcols, brows = boulders.col * factor, boulders.row * factor
    all_cols = np.concatenate([cols[keep], bcols])
    all_rows = np.concatenate([rows[keep], brows])
    all_r = np.concatenate([radius_m[keep], 0.45 * boulders.diameter_m]) / px_m
    all_g = np.concatenate([gains[keep], np.full(bcols.size, 1.15)])
    az, el = np.radians(SUN_AZIMUTH_DEG), np.radians(SUN_ELEVATION_DEG)
    sun = (np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el))  # column, row, up
    stamp_rocks(img, all_cols, all_rows, np.maximum(all_r, 0.6), all_g, *sun)
    out = np.clip(np.rint(img), 1, 255).astype(np.uint8)
    bad = ~np.isfinite(dem)
    if bad.any():
        out[np.repeat(np.repeat(bad, factor, 0), factor, 1)] = 0
    return np.asarray(out)
