"""Orbital windows: the DEM/ortho around the rover positions, cut from remote rasters into COGs.

Frames and units: rover positions are PLACES easting/northing in the table's own CRS
(``infer_places_crs``: Perseverance eqc lat_ts=18.4663, Curiosity eqc lat_ts=0); the window
is the positions' bounding box grown by ``margin_m`` (ground metres, padded by 10 % for map
scale), transformed into each raster's CRS (the USGS Jezero mosaics are eqc lat_ts=0, not the
PLACES 18.4663: the same point has eastings 5 % apart) and snapped outward to its pixel grid.

GDAL reads only the blocks inside the window over HTTP range requests (``vsi.py``); the
window is written as a Cloud Optimized GeoTIFF (a temporary name, then a rename) tagged with
its source and bounds, so a rerun with the same request reads nothing.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv
import rasterio
import rasterio.shutil
from rasterio.io import MemoryFile
from rasterio.warp import transform_bounds
from rasterio.windows import Window, from_bounds

from mars_pairs.errors import FetchError
from mars_pairs.fetch.vsi import gdal_path, remote_env

Bounds = tuple[float, float, float, float]
SCALE_PAD = 1.1  # ground metres -> map units, generous for eqc at |lat| < 25 deg
MAX_CELLS = 400_000_000  # refuse windows above 20k x 20k cells: narrow the sols or sites


@dataclass(frozen=True)
class Positions:
    """Rover positions (map units of ``crs``, the PLACES table's CRS)."""

    x: np.ndarray
    y: np.ndarray
    crs: str


@dataclass(frozen=True)
class WindowResult:
    """One cut window: where it went, its bounds (raster CRS), size and if it was cached."""

    source: str
    path: Path
    bounds: Bounds
    shape: tuple[int, int]
    cached: bool


def rover_positions(
    places_csv: Path,
    *,
    sols: tuple[int, int] | None = None,
    sites: tuple[int, ...] = (),
) -> Positions:
    """ROVER-row positions of a PLACES table (columns by header name), optionally filtered."""
    from mars_pairs.geometry.places import MISSING, infer_places_crs

    try:
        raw = pacsv.read_csv(places_csv).to_pydict()
        table = {str(k).strip().lower(): v for k, v in raw.items()}  # PDS3-era: upper case
    except (OSError, ValueError) as exc:
        raise FetchError(places_csv, f"unreadable PLACES table: {exc}") from None
    for col in ("frame", "site", "easting", "northing", "longitude"):
        if col not in table:
            raise FetchError(places_csv, f"column {col!r}: missing")
    xs, ys, lon_of_first = [], [], None
    for i, frame in enumerate(table["frame"]):
        if str(frame).strip().upper() != "ROVER":
            continue
        x, y = float(table["easting"][i]), float(table["northing"][i])
        if MISSING in (x, y) or not (math.isfinite(x) and math.isfinite(y)):
            continue
        if sites and int(table["site"][i]) not in sites:
            continue
        if sols is not None and "sol" in table:
            sol = table["sol"][i]
            if sol is None or not sols[0] <= int(sol) <= sols[1]:
                continue
        if lon_of_first is None:
            lon_of_first = (x, float(table["longitude"][i]))
        xs.append(x)
        ys.append(y)
    if not xs:
        raise FetchError(places_csv, "no ROVER rows match the sols/sites asked for")
    crs = infer_places_crs(*lon_of_first)  # type: ignore[misc]
    return Positions(np.asarray(xs), np.asarray(ys), crs)


def window_bounds(pos: Positions, margin_m: float) -> Bounds:
    """(left, bottom, right, top) of the positions grown by ``margin_m``, in ``pos.crs``."""
    pad = margin_m * SCALE_PAD
    return (pos.x.min() - pad, pos.y.min() - pad, pos.x.max() + pad, pos.y.max() + pad)


def cut_window(source: str, bounds: Bounds, bounds_crs: str, out: Path) -> WindowResult:
    """Read ``bounds`` (in ``bounds_crs``) of a raster (local, URL or /vsicurl/) into a COG."""
    request = {"source": source, "bounds": [round(b, 6) for b in bounds], "crs": bounds_crs}
    cached = _cached(out, request)
    if cached is not None:
        return cached
    path = gdal_path(source)
    with remote_env():
        try:
            src = rasterio.open(path)
        except rasterio.errors.RasterioIOError as exc:
            raise FetchError(source, f"cannot open the raster: {exc}") from None
        with src:
            if src.crs is None:
                raise FetchError(source, "the raster has no CRS")
            native = transform_bounds(bounds_crs, src.crs, *bounds, densify_pts=21)
            win = _snap(from_bounds(*native, transform=src.transform), src.width, src.height)
            if win is None:
                raise FetchError(source, f"the rover positions ({bounds_crs}) are off the raster")
            if win.width * win.height > MAX_CELLS:
                raise FetchError(
                    source,
                    f"window of {win.width} x {win.height} cells is too large; narrow the sols",
                )
            try:
                data = src.read(window=win)
            except rasterio.errors.RasterioIOError as exc:
                raise FetchError(source, f"window read failed: {exc}") from None
            profile = {
                "driver": "GTiff",
                "width": int(win.width),
                "height": int(win.height),
                "count": src.count,
                "dtype": data.dtype.name,
                "crs": src.crs,
                "transform": src.window_transform(win),
                "nodata": src.nodata,
            }
            colorinterp = src.colorinterp
    _write_cog(out, data, profile, colorinterp, request)
    with rasterio.open(out) as done:
        return WindowResult(source, out, tuple(done.bounds), (done.height, done.width), False)


def _snap(win: Window, width: int, height: int) -> Window | None:
    """The window grown outward to whole pixels and clipped to the raster, or None if off it."""
    c0 = max(0, math.floor(win.col_off))
    r0 = max(0, math.floor(win.row_off))
    c1 = min(width, math.ceil(win.col_off + win.width))
    r1 = min(height, math.ceil(win.row_off + win.height))
    if c1 <= c0 or r1 <= r0:
        return None
    return Window(c0, r0, c1 - c0, r1 - r0)


def _write_cog(out: Path, data: np.ndarray, profile: dict, colorinterp, request: dict) -> None:  # type: ignore[no-untyped-def]
    """Write ``data`` as a deflate COG at ``out`` via a temporary name and a rename."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        with MemoryFile() as mem:
            with mem.open(**profile) as dst:
                dst.write(data)
                dst.colorinterp = colorinterp
                dst.update_tags(MARS_PAIRS_WINDOW=json.dumps(request, sort_keys=True))
            with mem.open() as filled:
                rasterio.shutil.copy(
                    filled, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=256,
                    OVERVIEWS="NONE", NUM_THREADS=1,
                )  # fmt: skip
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()


def _cached(out: Path, request: dict) -> WindowResult | None:
    """The existing window at ``out`` if it was cut for the same request."""
    if not out.is_file():
        return None
    try:
        with rasterio.open(out) as ds:
            tag = ds.tags().get("MARS_PAIRS_WINDOW")
            if tag and json.loads(tag) == json.loads(json.dumps(request, sort_keys=True)):
                return WindowResult(
                    request["source"], out, tuple(ds.bounds), (ds.height, ds.width), True
                )
    except (rasterio.errors.RasterioIOError, ValueError):
        return None
    return None
