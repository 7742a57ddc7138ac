"""Orbital windows: the DEM/ortho around the rover positions, cut from remote rasters into COGs.

Frames and units: rover positions are PLACES easting/northing in the table's own CRS
(``infer_places_crs``: Perseverance eqc lat_ts=18.4663, Curiosity eqc lat_ts=0). The windows
are planned by ``windows.py`` (pure arithmetic on the source raster's grid) and cut from the
source in its own CRS and pixel grid, never resampled.

Sources: any raster GDAL opens, local, ``https://`` (read through ``/vsicurl/`` range requests,
``vsi.py``) or ``/vsi...``: GeoTIFF/COG (the USGS mosaics), VICAR, PDS3 and PDS4. A ``.img``
source is opened through its detached label when one exists beside it (``<stem>.xml`` PDS4,
``<stem>.lbl`` PDS3; GDAL's PDS driver documentation: "When a .lbl file exists it should be
used as the dataset name rather than the .img file"), else as itself (a VICAR or attached-label
PDS3 file carries its own georeferencing). The PLACES maps are such files: Perseverance
``data_maps/m20_orbital_dem.img`` (VICAR) with ``m20_orbital_dem.xml`` (PDS4), Curiosity
``MSLPLC_1XXX/DATA/MAPS/msl_orbital_dem.img`` with ``msl_orbital_dem.lbl`` (PDS3).

A window is written as a Cloud Optimized GeoTIFF (row blocks into a temporary tiled GeoTIFF,
then a COG copy and a rename) tagged with its source and pixel window, so a rerun with the same
request reads nothing. The source's grid is kept beside the windows (``<kind>.source.json``)
for the same reason. ``write_vrt`` mosaics a source's windows into one GDAL VRT for the build.
"""

from __future__ import annotations

import json
import math
import os
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.csv as pacsv
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.windows import Window

from mars_pairs.errors import FetchError
from mars_pairs.fetch.windows import PlannedWindow, RasterGrid
from mars_pairs.raster.vsi import gdal_path, open_raster, remote_env
from mars_pairs.store.atomic import atomic_path, atomic_write_bytes, temporary_path

Bounds = tuple[float, float, float, float]
LABEL_SUFFIXES = (".xml", ".lbl", ".LBL", ".XML")  # detached labels tried before a .img itself
ROWS_PER_READ = 1024  # rows per block read of a window (bounds memory: width x 1024 cells)


@dataclass(frozen=True)
class Positions:
    """Rover positions (map units of ``crs``, the PLACES table's CRS), in table order.

    ``names``: one ``site/drive (sol)`` text per position, to name the ones a plan leaves out.
    """

    x: np.ndarray
    y: np.ndarray
    crs: str
    names: tuple[str, ...] = ()


@dataclass(frozen=True)
class WindowResult:
    """One cut window: where it went, its bounds (raster CRS), size and if it was cached."""

    source: str
    path: Path
    bounds: Bounds
    shape: tuple[int, int]
    cached: bool
    kind: str = ""


def _column(table: dict[str, list[Any]], name: str) -> list[Any] | None:
    """A column by case-insensitive name (current PLACES tables are lower case, PDS3-era upper)."""
    for key, values in table.items():
        if key.strip().lower() == name:
            return values
    return None


def rover_positions(
    places_csv: Path,
    *,
    sols: tuple[int, int] | None = None,
    sites: tuple[int, ...] = (),
) -> Positions:
    """ROVER-row positions of a PLACES table (columns by header name, any case), filtered.

    With ``sols`` = (first, last): the rows of those sols and the last row before ``first``
    (where the rover stood when sol ``first`` began: a sol without a drive has no row of its
    own, e.g. Curiosity sol 1429 stands at site 56 drive 1632, the row of sol 1428).
    """
    from mars_pairs.geometry.places import MISSING, infer_places_crs

    try:
        raw = pacsv.read_csv(places_csv).to_pydict()
    except (OSError, ValueError) as exc:
        raise FetchError(places_csv, f"unreadable PLACES table: {exc}") from None
    cols: dict[str, list[Any]] = {}
    for col in ("frame", "site", "drive", "easting", "northing", "longitude", "sol"):
        values = _column(raw, col)
        if values is not None:
            cols[col] = values
        elif col not in ("drive", "sol"):
            raise FetchError(places_csv, f"column {col!r}: missing")
    sol_col, drive_col = cols.get("sol"), cols.get("drive")
    rows = []  # (sol or None, x, y, name, longitude)
    for i, frame in enumerate(cols["frame"]):
        if str(frame).strip().upper() != "ROVER":
            continue
        x, y = float(cols["easting"][i]), float(cols["northing"][i])
        if MISSING in (x, y) or not (math.isfinite(x) and math.isfinite(y)):
            continue
        site = int(cols["site"][i])
        if sites and site not in sites:
            continue
        sol = sol_col[i] if sol_col is not None else None
        sol = int(sol) if sol is not None else None
        drive = drive_col[i] if drive_col is not None else "?"
        rows.append((sol, x, y, f"site {site} drive {drive} (sol {sol})", cols["longitude"][i]))
    if sols is not None and sol_col is not None:
        before = [k for k, r in enumerate(rows) if r[0] is not None and r[0] < sols[0]]
        keep = [k for k, r in enumerate(rows) if r[0] is not None and sols[0] <= r[0] <= sols[1]]
        if before:
            last = max(before, key=lambda k: (rows[k][0], k))
            keep = sorted({last, *keep})
        rows = [rows[k] for k in keep]
    if not rows:
        raise FetchError(places_csv, "no ROVER rows match the sols/sites asked for")
    crs = infer_places_crs(rows[0][1], float(rows[0][4]))
    xs = np.asarray([r[1] for r in rows])
    ys = np.asarray([r[2] for r in rows])
    return Positions(xs, ys, crs, tuple(r[3] for r in rows))


# -- sources ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class SourceInfo:
    """A source raster's header: what was opened (the label, if any), grid, bands."""

    source: str
    opened: str
    driver: str
    crs: str  # WKT
    transform: tuple[float, ...]  # GDAL affine (a, b, c, d, e, f)
    width: int
    height: int
    count: int
    dtype: str
    nodata: float | None
    colorinterp: tuple[str, ...]

    @property
    def grid(self) -> RasterGrid:
        """The pixel grid the planner works on."""
        return RasterGrid(self.crs, Affine(*self.transform[:6]), self.width, self.height)

    def to_json(self) -> str:
        """The header as JSON text (NaN nodata as null-safe text)."""
        d = asdict(self)
        if d["nodata"] is not None and math.isnan(d["nodata"]):
            d["nodata"] = "nan"
        return json.dumps(d, sort_keys=True, indent=1)

    @classmethod
    def from_json(cls, text: str) -> SourceInfo:
        """Inverse of ``to_json``."""
        d = json.loads(text)
        if d["nodata"] == "nan":
            d["nodata"] = math.nan
        d["transform"] = tuple(d["transform"])
        d["colorinterp"] = tuple(d["colorinterp"])
        return cls(**d)


def _candidates(source: str) -> list[str]:
    """Paths to try for ``source``: detached labels beside a ``.img``, then the file itself."""
    stem, dot, ext = source.rpartition(".")
    if dot and ext.lower() == "img" and "/" not in ext:
        return [stem + suffix for suffix in LABEL_SUFFIXES] + [source]
    return [source]


@contextmanager
def open_source(source: str) -> Iterator[tuple[str, rasterio.io.DatasetReader]]:
    """Open ``source`` (or its detached label) as a georeferenced raster: (opened path, dataset).

    Raises ``FetchError`` naming every path tried when none opens with a CRS and a transform.
    """
    tried = []
    with remote_env():
        for path in _candidates(source):
            try:
                with warnings.catch_warnings():  # no georeferencing: the next candidate
                    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                    ds = open_raster(gdal_path(path))
            except rasterio.errors.RasterioIOError as exc:
                tried.append(f"{path}: {str(exc).splitlines()[0][:160]}")
                continue
            if ds.crs is None or ds.transform == Affine.identity():
                ds.close()
                tried.append(f"{path}: opened ({ds.driver}) but has no CRS/georeferencing")
                continue
            try:
                yield path, ds
            finally:
                ds.close()
            return
    raise FetchError(source, "cannot open a georeferenced raster; tried " + "; ".join(tried))


def source_info(source: str, sidecar: Path | None = None, *, write: bool = True) -> SourceInfo:
    """The source's header, from ``sidecar`` (JSON) when it was written for this source;
    else read from the raster (and written to ``sidecar`` when ``write``)."""
    if sidecar is not None and sidecar.is_file():
        try:
            info = SourceInfo.from_json(sidecar.read_text())
            if info.source == source:
                return info
        except (ValueError, TypeError, KeyError):
            pass
    with open_source(source) as (opened, ds):
        info = SourceInfo(
            source=source,
            opened=opened,
            driver=ds.driver,
            crs=ds.crs.to_wkt(),
            transform=tuple(ds.transform)[:6],
            width=ds.width,
            height=ds.height,
            count=ds.count,
            dtype=ds.dtypes[0],
            nodata=ds.nodata,
            colorinterp=tuple(c.name for c in ds.colorinterp),
        )
    if sidecar is not None and write:
        atomic_write_bytes(sidecar, info.to_json().encode())
    return info


# -- cutting ---------------------------------------------------------------------------------
def cut_planned(win: PlannedWindow, info: SourceInfo, out: Path) -> WindowResult:
    """Cut a planned window (source pixels) of ``info``'s raster into a COG at ``out``."""
    request = {"source": info.source, "window": [win.col_off, win.row_off, win.width, win.height]}
    cached = _cached(out, request)
    if cached is not None:
        return WindowResult(cached.source, out, cached.bounds, cached.shape, True, win.kind)
    with open_source(info.opened) as (_, src):
        if (src.width, src.height) != (info.width, info.height):
            raise FetchError(info.opened, "the raster changed size since it was planned")
        _write_window(src, Window(win.col_off, win.row_off, win.width, win.height), out, request)
    with rasterio.open(out) as done:
        return WindowResult(
            info.source, out, tuple(done.bounds), (done.height, done.width), False, win.kind
        )


def _write_window(
    src: rasterio.io.DatasetReader, win: Window, out: Path, request: dict[str, Any]
) -> None:
    """Copy ``win`` of ``src`` to a deflate COG at ``out`` (row blocks; temporary names)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = temporary_path(out, ".stage.tif")
    profile = {
        "driver": "GTiff",
        "width": int(win.width),
        "height": int(win.height),
        "count": src.count,
        "dtype": src.dtypes[0],
        "crs": src.crs,
        "transform": src.window_transform(win),
        "nodata": src.nodata,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "compress": "deflate",
    }
    try:
        with rasterio.open(stage, "w", **profile) as dst:
            for r in range(0, int(win.height), ROWS_PER_READ):
                n = min(ROWS_PER_READ, int(win.height) - r)
                part = Window(win.col_off, win.row_off + r, win.width, n)
                try:
                    data = src.read(window=part)
                except rasterio.errors.RasterioIOError as exc:
                    raise FetchError(request["source"], f"window read failed: {exc}") from None
                dst.write(data, window=Window(0, r, win.width, n))
            dst.colorinterp = src.colorinterp
            dst.update_tags(MARS_PAIRS_WINDOW=json.dumps(request, sort_keys=True))
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), atomic_path(out) as tmp:
            rasterio.shutil.copy(
                stage, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=256,
                OVERVIEWS="NONE", NUM_THREADS=1,
            )  # fmt: skip
    finally:
        stage.unlink(missing_ok=True)


def _cached(out: Path, request: dict[str, Any]) -> WindowResult | None:
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


# -- mosaic ----------------------------------------------------------------------------------
_VRT_TYPES = {
    "uint8": "Byte", "int8": "Int8", "uint16": "UInt16", "int16": "Int16", "uint32": "UInt32",
    "int32": "Int32", "float32": "Float32", "float64": "Float64",
}  # fmt: skip


def write_vrt(
    path: Path, info: SourceInfo, windows: list[PlannedWindow], files: list[Path]
) -> Path:
    """A GDAL VRT at ``path`` mosaicking window COGs (``files``, one per planned window).

    The VRT's grid is the source grid cropped to the windows' union (same pixel size and
    phase, so each window lands at whole-pixel offsets); cells outside every window are nodata
    (the source's nodata; NaN for a float raster without one). Sources are named relative to
    the VRT. Written atomically.
    """
    if not windows or len(windows) != len(files):
        raise FetchError(path, "write_vrt: expected one file per planned window")
    c0 = min(w.col_off for w in windows)
    r0 = min(w.row_off for w in windows)
    c1 = max(w.col_off + w.width for w in windows)
    r1 = max(w.row_off + w.height for w in windows)
    a, b, c, d, e, f = info.transform[:6]
    x0, y0 = Affine(a, b, c, d, e, f) * (c0, r0)
    vtype = _VRT_TYPES.get(info.dtype)
    if vtype is None:
        raise FetchError(info.source, f"data type {info.dtype} cannot be mosaicked in a VRT")
    nodata = info.nodata
    if nodata is None and info.dtype.startswith("float"):
        nodata = math.nan
    root = ET.Element("VRTDataset", rasterXSize=str(c1 - c0), rasterYSize=str(r1 - r0))
    ET.SubElement(root, "SRS").text = info.crs
    ET.SubElement(root, "GeoTransform").text = ", ".join(
        repr(float(v)) for v in (x0, a, b, y0, d, e)
    )
    for band in range(1, info.count + 1):
        el = ET.SubElement(root, "VRTRasterBand", dataType=vtype, band=str(band))
        if nodata is not None:
            ET.SubElement(el, "NoDataValue").text = "nan" if math.isnan(nodata) else repr(nodata)
        if band <= len(info.colorinterp):
            ET.SubElement(el, "ColorInterp").text = info.colorinterp[band - 1].capitalize()
        for w, file in zip(windows, files, strict=True):
            src = ET.SubElement(el, "SimpleSource")
            name = os.path.relpath(file, path.parent)
            ET.SubElement(src, "SourceFilename", relativeToVRT="1").text = name
            ET.SubElement(src, "SourceBand").text = str(band)
            ET.SubElement(src, "SourceProperties", RasterXSize=str(w.width),
                          RasterYSize=str(w.height), DataType=vtype,
                          BlockXSize="256", BlockYSize="256")  # fmt: skip
            ET.SubElement(src, "SrcRect", xOff="0", yOff="0", xSize=str(w.width),
                          ySize=str(w.height))  # fmt: skip
            ET.SubElement(src, "DstRect", xOff=str(w.col_off - c0), yOff=str(w.row_off - r0),
                          xSize=str(w.width), ySize=str(w.height))  # fmt: skip
    ET.indent(root)
    atomic_write_bytes(path, (ET.tostring(root, encoding="unicode") + "\n").encode())
    return path
