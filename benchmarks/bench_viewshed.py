"""Benchmark: numba viewshed / ray casting against gdal_viewshed on one fractal DEM.

    python benchmarks/bench_viewshed.py            # 4096 x 4096 DEM at 1 m, radius 2000 m
    python benchmarks/bench_viewshed.py --size 1024 --radius 500   # quick run

Builds a seeded spectral fractal DEM as a GeoTIFF (Mars equirectangular CRS) in a temp dir,
puts the observer at its centre 2 m above the ground, and prints a markdown table of median
wall times (ms; warm-up runs first, then the median of --repeats runs) with the speed-up
against gdal_viewshed's full 360-degree run, and the machine load (os.getloadavg) before and
after: numba's threads stall when other processes hold the cores, so compare rows of one run.

Accuracy: each viewshed (ours and gdal_viewshed's) is compared with the exact line-of-sight
reference of the tests (tests/support/los_reference.py: bilinear terrain, the whole segment
from the eye to each cell centre tested exactly) on --ref-cells cells drawn at random inside
the case's band (all of them when the band holds fewer): visible-set IoU, false positives and
false negatives per 1000 sampled cells.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from mars_pairs.kernels import cast_rays, compute_viewshed  # noqa: E402
from mars_pairs.kernels.raycast import max_pyramid  # noqa: E402
from mars_pairs.raster.terrain import Terrain  # noqa: E402
from mars_pairs.runtime import configure_process  # noqa: E402
from mars_pairs.synth.terrain import spectral_noise  # noqa: E402
from support.los_reference import exact_viewshed  # noqa: E402

EQC = "+proj=eqc +lat_ts=0 +lon_0=0 +R=3396190 +units=m +no_defs"
X0, Y0 = 8141036.0, -271512.0  # a Gale-like map corner (metres)
HEIGHT = 2.0
R_MARS = 3396190.0
CAM_EL = -3.0  # camera looks slightly down (degrees); azimuth: the most open direction


def fractal_dem(n: int, seed: int = 42, std: float = 25.0, beta: float = 2.0) -> np.ndarray:
    """Seeded spectral-synthesis fractal (n x n float32 metres): amplitude ~ 1/f^beta."""
    return (spectral_noise(np.random.default_rng(seed), n, 2.0 * beta) * std).astype(np.float32)


def write_dem(path: Path, dem: np.ndarray, cell: float) -> None:
    """Single-band float32 GeoTIFF in the Mars eqc CRS."""
    tr = Affine(cell, 0.0, X0, 0.0, -cell, Y0)
    with rasterio.open(
        path, "w", driver="GTiff", width=dem.shape[1], height=dem.shape[0], count=1,
        dtype="float32", crs=EQC, transform=tr, tiled=True, blockxsize=256, blockysize=256,
    ) as ds:  # fmt: skip
        ds.write(dem, 1)


def median_ms(fn: Callable[[], object], repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``fn`` in milliseconds, after ``warmup`` untimed runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times))


def open_azimuth(mask: np.ndarray, win, x: float, y: float, reach: float) -> float:
    """Centre (deg) of the 6-degree sector with most visible cells within ``reach`` metres."""
    rr, cc = np.nonzero(mask)
    xs, ys = win.colrow_to_xy(cc, rr)
    ok = np.hypot(xs - x, ys - y) <= reach
    az = np.degrees(np.arctan2(xs[ok] - x, ys[ok] - y)) % 360.0
    counts = np.bincount((az // 6).astype(int), minlength=60)
    return float(np.argmax(counts) * 6 + 3)


def camera_rays(width: int, height: int, stride: int, hfov: float, eye: np.ndarray, cam_az):
    """Pinhole camera at ``eye`` looking (cam_az, CAM_EL): origins, unit directions (map)."""
    az, el = math.radians(cam_az), math.radians(CAM_EL)
    fwd = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    right = np.array([math.cos(az), -math.sin(az), 0.0])
    up = np.cross(right, fwd)
    f = (width / 2) / math.tan(math.radians(hfov / 2))
    s, ln = np.meshgrid(np.arange(0, width, stride), np.arange(0, height, stride))
    xs = (s.ravel() - (width - 1) / 2) / f
    ys = (ln.ravel() - (height - 1) / 2) / f
    d = fwd[None, :] + xs[:, None] * right[None, :] - ys[:, None] * up[None, :]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.tile(eye, (len(d), 1)), d


def band_cells(win, x, y, radius, az_band, el_band, eye, n_max, seed=0):
    """(rows, cols) of up to ``n_max`` random window cells inside the radius and bands
    (azimuth clockwise from north, elevation of the cell's own surface point, with curvature)."""
    rows, cols = np.mgrid[0 : win.shape[0], 0 : win.shape[1]]
    cx, cy = win.colrow_to_xy(cols.ravel(), rows.ravel())
    east, north = np.asarray(cx) - x, np.asarray(cy) - y
    d = np.hypot(east, north)
    ok = d <= radius
    if az_band is not None:
        az = np.degrees(np.arctan2(east, north)) % 360.0
        ok &= ((az - az_band[0]) % 360.0) <= (az_band[1] - az_band[0]) % 360.0
    if el_band is not None:
        z = win.data.ravel() - d**2 / (2 * R_MARS)
        el = np.degrees(np.arctan2(z - eye, d))
        ok &= (el >= el_band[0]) & (el <= el_band[1])
    idx = np.flatnonzero(ok)
    if idx.size > n_max:
        idx = np.sort(np.random.default_rng(seed).choice(idx, n_max, replace=False))
    return rows.ravel()[idx], cols.ravel()[idx]


def accuracy(mask: np.ndarray, ref: np.ndarray) -> str:
    """'IoU | false + per 1000 | false - per 1000' of sampled verdicts against the reference."""
    mask, ref = mask.astype(bool), ref.astype(bool)
    union = (mask | ref).sum()
    score = 1.0 if union == 0 else (mask & ref).sum() / union
    fp = 1000 * (mask & ~ref).sum() / mask.size
    fn = 1000 * (~mask & ref).sum() / mask.size
    return f"{score:.4f} | {fp:.1f} | {fn:.1f}"


def run_gdal(dem_path: Path, out: Path, x: float, y: float, radius: float) -> list[str] | None:
    """gdal_viewshed command line, or None when the binary is absent."""
    exe = shutil.which("gdal_viewshed")
    if exe is None:
        return None
    return [exe, "-q", "-ox", repr(x), "-oy", repr(y), "-oz", str(HEIGHT), "-md", str(radius),
            "-b", "1", "-cc", "1", str(dem_path), str(out)]  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    configure_process()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=4096, help="DEM size in cells (square)")
    ap.add_argument("--cell", type=float, default=1.0, help="cell size in metres")
    ap.add_argument("--radius", type=float, default=2000.0, help="viewshed radius, metres")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per case (>= 5)")
    ap.add_argument("--ref-cells", type=int, default=200_000,
                    help="cells per case checked against the exact reference")  # fmt: skip
    args = ap.parse_args(argv)
    args.repeats = max(5, args.repeats)
    args.load_before = os.getloadavg()

    rows: list[tuple[str, float | None, str, str]] = []
    na = "| |"
    t0 = time.perf_counter()
    tiny = np.zeros((16, 16), np.float32), Affine(1, 0, 0, 0, -1, 16)
    compute_viewshed(tiny, 8, 8, height=2, radius=5)
    compute_viewshed(tiny, 8, 8, height=2, radius=5, az_band=(0, 10), el_band=(-10, 0))
    cast_rays([[8.0, 8.0, 2.0]], [[0.0, 0.6, -0.8]], tiny, max_range=5)
    cast_rays([[8.0, 8.0, 2.0]], [[0.0, 0.6, -0.8]], tiny, max_range=5, pyramid=max_pyramid(tiny))
    rows.append(("numba first call (compile or cache load)", (time.perf_counter() - t0) * 1e3,
                 na, "once per process"))  # fmt: skip

    with tempfile.TemporaryDirectory() as tmp:
        dem_path = Path(tmp) / "dem.tif"
        write_dem(dem_path, fractal_dem(args.size, std=25.0 * args.size / 4096), args.cell)
        half = args.size * args.cell / 2
        x, y = X0 + half + args.cell / 2, Y0 - half - args.cell / 2
        with Terrain.open(dem_path) as t:
            win = t.read_dem_window(x, y, args.radius)
            rows.append(("DEM window read (rasterio)",
                         median_ms(lambda: t.read_dem_window(x, y, args.radius), args.repeats),
                         na, f"{win.shape[0]} x {win.shape[1]} window"))  # fmt: skip
            eye = np.array([x, y, t.elevation_at(x, y) + HEIGHT])

        vs_kw = {"height": HEIGHT, "radius": args.radius}
        full = compute_viewshed(win, x, y, **vs_kw)
        cam_az = open_azimuth(full, win, x, y, 20 * HEIGHT / math.tan(math.radians(-CAM_EL)))
        cases = [
            ("viewshed full 360 (oversample=1, default)", {}),
            ("viewshed full 360 (oversample=2)", {"oversample": 2}),
            (f"viewshed wedge 6 x 5 deg (Mastcam-like, az {cam_az:.0f})",
             {"az_band": (cam_az - 3, cam_az + 3), "el_band": (CAM_EL - 2.5, CAM_EL + 2.5)}),
            ("viewshed wedge 20 x 11 deg",
             {"az_band": (cam_az - 10, cam_az + 10), "el_band": (CAM_EL - 5.5, CAM_EL + 5.5)}),
            ("viewshed wedge 30 deg, all elevations",
             {"az_band": (cam_az - 15, cam_az + 15)}),
        ]  # fmt: skip
        u0, v0 = (float(t) - 0.5 for t in ~win.transform * (x, y))
        ref_kw = {"a": win.transform.a, "e": win.transform.e, "planet_radius": R_MARS}
        full_cells = None
        for name, kw in cases:
            mask = compute_viewshed(win, x, y, **vs_kw, **kw)
            ms = median_ms(lambda kw=kw: compute_viewshed(win, x, y, **vs_kw, **kw), args.repeats)
            cells = band_cells(win, x, y, args.radius, kw.get("az_band"), kw.get("el_band"),
                               eye[2], args.ref_cells)  # fmt: skip
            ref = exact_viewshed(win.data, u0, v0, eye[2], args.radius, cells=cells, **ref_kw)
            if not kw:
                full_cells, full_ref = cells, ref
            rows.append((name, ms, accuracy(mask[cells], ref),
                         f"{int(mask.sum())} cells visible; {len(ref)} checked"))  # fmt: skip

        cmd = run_gdal(dem_path, Path(tmp) / "gdal_vs.tif", x, y, args.radius)
        gdal_ms = None
        if cmd is None:
            rows.append(("gdal_viewshed full 360 (subprocess)", None, na, "not installed"))
        else:
            gdal_ms = median_ms(lambda: subprocess.run(cmd, check=True), args.repeats)
            with rasterio.open(Path(tmp) / "gdal_vs.tif") as ds:
                gdal_vis = ds.read(1) == 255
                # the window's cells on the gdal output grid (same cell size, same origin grid)
                c_off = round((win.transform.c - ds.transform.c) / ds.transform.a)
                r_off = round((win.transform.f - ds.transform.f) / ds.transform.e)
            g_mask = gdal_vis[full_cells[0] + r_off, full_cells[1] + c_off]
            rows.append(("gdal_viewshed full 360 (subprocess)", gdal_ms,
                         accuracy(g_mask, full_ref),
                         f"{int(gdal_vis.sum())} cells visible; incl. process start + GeoTIFF "
                         "I/O"))  # fmt: skip

        origins, dirs = camera_rays(1648, 1200, 4, 20.0, eye, cam_az)
        hits, _ = cast_rays(origins, dirs, win, max_range=args.radius)
        n_hits = f"{int(np.isfinite(hits[:, 0]).sum())} hits"
        pyr = max_pyramid(win)
        rows.append(("max pyramid of the window (`max_pyramid`, once per window)",
                     median_ms(lambda: max_pyramid(win), args.repeats), na,
                     f"levels 2..{pyr.n_levels}"))  # fmt: skip
        ms = median_ms(lambda: cast_rays(origins, dirs, win, max_range=args.radius, pyramid=pyr),
                       args.repeats)  # fmt: skip
        rows.append((f"ray casting 1648 x 1200 / stride 4 ({len(dirs)} rays), pyramid given", ms,
                     na, n_hits))  # fmt: skip
        ms = median_ms(lambda: cast_rays(origins, dirs, win, max_range=args.radius), args.repeats)
        rows.append(("ray casting, same rays, pyramid built in the call", ms, na, n_hits))

    print_table(rows, gdal_ms, args)


def print_table(rows, gdal_ms: float | None, args: argparse.Namespace) -> None:
    """Markdown table: name, median ms, speed-up vs gdal_viewshed full run, note."""
    before = ", ".join(f"{v:.2f}" for v in args.load_before)
    after = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(
        f"\nDEM {args.size} x {args.size} at {args.cell} m, radius {args.radius} m, observer "
        f"{HEIGHT} m above the centre, median of {args.repeats} after 2 warm-up runs; "
        f"{os.cpu_count()} CPUs, load average (1, 5, 15 min) {before} before, {after} after\n"
    )
    print("| case | median ms | speed-up vs gdal_viewshed full | IoU vs exact | false + /1000 "
          "| false - /1000 | note |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, ms, acc, note in rows:
        ms_s = "n/a" if ms is None else f"{ms:.1f}"
        ratio = "n/a" if (ms is None or gdal_ms is None) else f"{gdal_ms / ms:.2f}x"
        print(f"| {name} | {ms_s} | {ratio} | {acc} | {note} |")


if __name__ == "__main__":
    main()
