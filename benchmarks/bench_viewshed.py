"""Benchmark: numba viewshed / ray casting against GDAL's viewshed on one fractal DEM.

    python benchmarks/bench_viewshed.py            # 4096 x 4096 DEM at 1 m, radius 2000 m
    python benchmarks/bench_viewshed.py --radius 500,2000          # a radius sweep, one run
    python benchmarks/bench_viewshed.py --size 1024 --radius 500   # quick run

Builds a seeded spectral fractal DEM as a GeoTIFF (Mars equirectangular CRS) in a temp dir,
puts the observer at its centre 2 m above the ground, and prints, per radius, a markdown table
of median wall times (ms; warm-up runs first, then the median of --repeats runs) with the
speed-up against GDAL's full 360-degree viewshed called in process, and the machine load
(os.getloadavg) before and after: numba's threads stall when other processes hold the cores,
so compare rows of one run.

The anchor: ``gdal.ViewshedGenerate`` (MEM dataset in, MEM dataset out, curvature
coefficient 1) timed inside a long-lived worker (benchmarks/gdal_viewshed_worker.py, run by
``--gdal-python``, default Debian's /usr/bin/python3 with python3-gdal), so neither process
start nor file I/O is counted. Its rounds are interleaved with our full-360 call and with the
``gdal_viewshed`` command run as a subprocess (the second GDAL row: process start and GeoTIFF
I/O included).

Accuracy: each viewshed (ours and gdal_viewshed's) is compared with the exact line-of-sight
reference of the tests (tests/support/los_reference.py: bilinear terrain, the whole segment
from the eye to each cell centre tested exactly) on --ref-cells cells drawn at random inside
the case's band (all of them when the band holds fewer): visible-set IoU, false positives and
false negatives per 1000 sampled cells.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numba
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


class GdalWorker:
    """benchmarks/gdal_viewshed_worker.py in a long-lived ``python`` (with GDAL's bindings)."""

    def __init__(self, python: str, dem_path: Path) -> None:
        script = Path(__file__).with_name("gdal_viewshed_worker.py")
        self.proc = subprocess.Popen(
            [python, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.version = str(self.ask({"dem": str(dem_path)})["gdal"])

    def ask(self, req: dict[str, object]) -> dict[str, object]:
        """Send one request, return its reply (see the worker's docstring)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the GDAL worker exited")
        return dict(json.loads(line))

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


def start_worker(python: str, dem_path: Path) -> GdalWorker | None:
    """The in-process GDAL worker, or None when ``python`` has no GDAL bindings."""
    probe = [python, "-c", "from osgeo import gdal; gdal.ViewshedGenerate"]
    if shutil.which(python) is None or subprocess.run(probe, capture_output=True).returncode:
        return None
    return GdalWorker(python, dem_path)


def interleaved(fns: dict[str, Callable[[], float]], repeats: int, warmup: int = 2):
    """Median ms of each ``fn`` (each returns its own ms), run in round-robin rounds."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for i in range(warmup + repeats):
        for k, fn in fns.items():
            ms = fn()
            if i >= warmup:
                times[k].append(ms)
    return {k: float(np.median(v)) for k, v in times.items()}


def timed(fn: Callable[[], object]) -> Callable[[], float]:
    """``fn`` wrapped to return its wall time in ms."""

    def run() -> float:
        t = time.perf_counter()
        fn()
        return (time.perf_counter() - t) * 1e3

    return run


def one_thread(fn: Callable[[], object]) -> object:
    """``fn()`` with numba's parallel regions on one thread."""
    n = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn()
    finally:
        numba.set_num_threads(n)


def gdal_cells(mask: np.ndarray, gt, win, cells) -> np.ndarray:
    """``mask`` (on a grid of geotransform ``gt``, same cell size) at the window's ``cells``."""
    c_off = round((win.transform.c - gt[0]) / gt[1])
    r_off = round((win.transform.f - gt[3]) / gt[5])
    return mask[cells[0] + r_off, cells[1] + c_off]


def main(argv: list[str] | None = None) -> None:
    configure_process()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=4096, help="DEM size in cells (square)")
    ap.add_argument("--cell", type=float, default=1.0, help="cell size in metres")
    ap.add_argument("--radius", default="2000",
                    help="viewshed radius, metres; a comma list sweeps (500,2000)")  # fmt: skip
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per case (>= 5)")
    ap.add_argument("--ref-cells", type=int, default=200_000,
                    help="cells per case checked against the exact reference")  # fmt: skip
    ap.add_argument("--gdal-python", default="/usr/bin/python3",
                    help="a Python with GDAL's bindings (the in-process anchor)")  # fmt: skip
    args = ap.parse_args(argv)
    args.repeats = max(5, args.repeats)
    radii = [float(r) for r in str(args.radius).split(",")]

    na = "| |"
    t0 = time.perf_counter()
    tiny = np.zeros((16, 16), np.float32), Affine(1, 0, 0, 0, -1, 16)
    compute_viewshed(tiny, 8, 8, height=2, radius=5)
    compute_viewshed(tiny, 8, 8, height=2, radius=5, az_band=(0, 10), el_band=(-10, 0))
    cast_rays([[8.0, 8.0, 2.0]], [[0.0, 0.6, -0.8]], tiny, max_range=5)
    cast_rays([[8.0, 8.0, 2.0]], [[0.0, 0.6, -0.8]], tiny, max_range=5, pyramid=max_pyramid(tiny))
    first = ("numba first call (compile or cache load)", (time.perf_counter() - t0) * 1e3,
             na, "once per process")  # fmt: skip

    with tempfile.TemporaryDirectory() as tmp:
        dem_path = Path(tmp) / "dem.tif"
        write_dem(dem_path, fractal_dem(args.size, std=25.0 * args.size / 4096), args.cell)
        worker = start_worker(args.gdal_python, dem_path)
        try:
            for i, radius in enumerate(radii):
                args.load_before = os.getloadavg()
                rows = [first] if i == 0 else []
                gdal_ms = run_radius(args, radius, dem_path, Path(tmp), worker, rows)
                print_table(rows, gdal_ms, args, radius, worker)
        finally:
            if worker is not None:
                worker.close()


def run_radius(args, radius: float, dem_path: Path, tmp: Path, worker, rows) -> float | None:
    """Append the rows of one radius to ``rows``; GDAL's in-process median ms (or None)."""
    na = "| |"
    half = args.size * args.cell / 2
    x, y = X0 + half + args.cell / 2, Y0 - half - args.cell / 2
    with Terrain.open(dem_path) as t:
        win = t.read_dem_window(x, y, radius)
        rows.append(("DEM window read (rasterio)",
                     median_ms(lambda: t.read_dem_window(x, y, radius), args.repeats),
                     na, f"{win.shape[0]} x {win.shape[1]} window"))  # fmt: skip
        eye = np.array([x, y, t.elevation_at(x, y) + HEIGHT])

    vs_kw = {"height": HEIGHT, "radius": radius}
    u0, v0 = (float(c) - 0.5 for c in ~win.transform * (x, y))
    ref_kw = {"a": win.transform.a, "e": win.transform.e, "planet_radius": R_MARS}
    full_cells = band_cells(win, x, y, radius, None, None, eye[2], args.ref_cells)
    full_ref = exact_viewshed(win.data, u0, v0, eye[2], radius, cells=full_cells, **ref_kw)

    # the full circle and both GDAL anchors, interleaved round by round
    full = compute_viewshed(win, x, y, **vs_kw)
    fns = {
        "ours": timed(lambda: compute_viewshed(win, x, y, **vs_kw)),
        "ours_1t": timed(lambda: one_thread(lambda: compute_viewshed(win, x, y, **vs_kw))),
    }
    g_req = {"x": x, "y": y, "height": HEIGHT, "radius": radius}
    g_mask = None
    if worker is not None:
        reply = worker.ask({**g_req, "out": str(tmp / "gdal_mem.npy")})
        g_mask = np.load(tmp / "gdal_mem.npy").astype(bool)
        g_gt = reply["gt"]
        fns["gdal"] = lambda: float(worker.ask({**g_req, "out": None})["ms"])
    cmd = run_gdal(dem_path, tmp / "gdal_vs.tif", x, y, radius)
    if cmd is not None:
        fns["subprocess"] = timed(lambda: subprocess.run(cmd, check=True))
    med = interleaved(fns, args.repeats)

    rows.append(("viewshed full 360 (oversample=1, default)", med["ours"],
                 accuracy(full[full_cells], full_ref),
                 f"{int(full.sum())} cells visible; {len(full_ref)} checked; "
                 f"{numba.get_num_threads()} threads"))  # fmt: skip
    same = np.array_equal(full, one_thread(lambda: compute_viewshed(win, x, y, **vs_kw)))
    rows.append(("viewshed full 360, 1 numba thread", med["ours_1t"], "| |",
                 "mask identical to the threaded one" if same else "MASK DIFFERS"))  # fmt: skip
    if g_mask is None:
        rows.append(("GDAL ViewshedGenerate full 360 (in process)", None, na,
                     f"no GDAL bindings in {args.gdal_python}"))  # fmt: skip
    else:
        rows.append(("GDAL ViewshedGenerate full 360 (in process, MEM in and out)", med["gdal"],
                     accuracy(gdal_cells(g_mask, g_gt, win, full_cells), full_ref),
                     f"{int(g_mask.sum())} cells visible"))  # fmt: skip
    if cmd is None:
        rows.append(("gdal_viewshed full 360 (subprocess)", None, na, "not installed"))
    else:
        with rasterio.open(tmp / "gdal_vs.tif") as ds:
            s_mask = ds.read(1) == 255
            s_gt = ds.transform.to_gdal()
        rows.append(("gdal_viewshed full 360 (subprocess)", med["subprocess"],
                     accuracy(gdal_cells(s_mask, s_gt, win, full_cells), full_ref),
                     f"{int(s_mask.sum())} cells visible; incl. process start + GeoTIFF "
                     "I/O"))  # fmt: skip

    full_az = open_azimuth(full, win, x, y, 20 * HEIGHT / math.tan(math.radians(-CAM_EL)))
    cam_az = full_az
    cases = [
        ("viewshed full 360 (oversample=2)", {"oversample": 2}),
        (f"viewshed wedge 6 x 5 deg (Mastcam-like, az {cam_az:.0f})",
         {"az_band": (cam_az - 3, cam_az + 3), "el_band": (CAM_EL - 2.5, CAM_EL + 2.5)}),
        ("viewshed wedge 20 x 11 deg",
         {"az_band": (cam_az - 10, cam_az + 10), "el_band": (CAM_EL - 5.5, CAM_EL + 5.5)}),
        ("viewshed wedge 30 deg, all elevations",
         {"az_band": (cam_az - 15, cam_az + 15)}),
    ]  # fmt: skip
    for name, kw in cases:
        mask = compute_viewshed(win, x, y, **vs_kw, **kw)
        ms = median_ms(lambda kw=kw: compute_viewshed(win, x, y, **vs_kw, **kw), args.repeats)
        if kw.get("az_band") is None:
            cells, ref = full_cells, full_ref
        else:
            cells = band_cells(win, x, y, radius, kw.get("az_band"), kw.get("el_band"),
                               eye[2], args.ref_cells)  # fmt: skip
            ref = exact_viewshed(win.data, u0, v0, eye[2], radius, cells=cells, **ref_kw)
        rows.append((name, ms, accuracy(mask[cells], ref),
                     f"{int(mask.sum())} cells visible; {len(ref)} checked"))  # fmt: skip

    origins, dirs = camera_rays(1648, 1200, 4, 20.0, eye, cam_az)
    hits, _ = cast_rays(origins, dirs, win, max_range=radius)
    n_hits = f"{int(np.isfinite(hits[:, 0]).sum())} hits"
    pyr = max_pyramid(win)
    rows.append(("max pyramid of the window (`max_pyramid`, once per window)",
                 median_ms(lambda: max_pyramid(win), args.repeats), na,
                 f"levels 2..{pyr.n_levels}"))  # fmt: skip
    ms = median_ms(lambda: cast_rays(origins, dirs, win, max_range=radius, pyramid=pyr),
                   args.repeats)  # fmt: skip
    rows.append((f"ray casting 1648 x 1200 / stride 4 ({len(dirs)} rays), pyramid given", ms,
                 na, n_hits))  # fmt: skip
    ms = median_ms(lambda: cast_rays(origins, dirs, win, max_range=radius), args.repeats)
    rows.append(("ray casting, same rays, pyramid built in the call", ms, na, n_hits))
    return med.get("gdal")


def print_table(rows, gdal_ms: float | None, args: argparse.Namespace, radius: float,
                worker: GdalWorker | None) -> None:  # fmt: skip
    """Markdown table: name, median ms, speed-up vs GDAL in process (full circle), note."""
    before = ", ".join(f"{v:.2f}" for v in args.load_before)
    after = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    gdal = "no in-process GDAL" if worker is None else f"GDAL {worker.version}"
    print(
        f"\nDEM {args.size} x {args.size} at {args.cell} m, radius {radius:g} m, observer "
        f"{HEIGHT} m above the centre, median of {args.repeats} after 2 warm-up runs "
        f"(full-360 rows interleaved round by round); {gdal}; {os.cpu_count()} CPUs, "
        f"load average (1, 5, 15 min) {before} before, {after} after\n"
    )
    print("| case | median ms | speed-up vs GDAL in process, full | IoU vs exact "
          "| false + /1000 | false - /1000 | note |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, ms, acc, note in rows:
        ms_s = "n/a" if ms is None else f"{ms:.1f}"
        if "viewshed" not in name.lower():
            ratio = ""  # the ratio compares viewsheds only
        elif ms is None or gdal_ms is None:
            ratio = "n/a"
        else:
            ratio = f"{gdal_ms / ms:.2f}x"
        print(f"| {name} | {ms_s} | {ratio} | {acc} | {note} |")


if __name__ == "__main__":
    main()
