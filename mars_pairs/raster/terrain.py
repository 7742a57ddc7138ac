"""DEM and orthoimage access through rasterio: windowed reads in any projected Mars CRS.

Frames and units:

- *raster CRS*: the DEM's own projected CRS; x, y in its map units (metres for the Mars
  equirectangular maps), cell centres at ``transform @ (col + 0.5, row + 0.5)``.
- *lon/lat*: planetocentric latitude and east-positive longitude in degrees on the Mars sphere
  (``MARS_LONLAT`` = ``+proj=longlat +R=3396190``).
- Elevations are DEM values in metres (heights above the areoid for HiRISE DTMs); nodata is NaN.

Only the window a request needs is read, never the whole raster, so any GDAL path or URL works
(``/vsicurl/https://...`` included). Any axis-aligned grid is read (north-up, south-up,
east-left: ``raster.grid.NorthUp``); every transform and array here is north-up (row 0 north).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import rasterio
from affine import Affine
from numpy.typing import ArrayLike, NDArray
from pyproj import CRS
from rasterio.enums import Resampling
from rasterio.warp import reproject, transform_bounds
from rasterio.windows import Window, from_bounds
from rasterio.windows import transform as window_transform

from mars_pairs.errors import TerrainError
from mars_pairs.geometry.body import MARS_ELEVATION_M
from mars_pairs.geometry.frames import MARS_LONLAT, crs_string, map_to_map
from mars_pairs.raster.crs import check_map_crs
from mars_pairs.raster.grid import NorthUp
from mars_pairs.raster.vsi import gdal_reason, open_raster

Bounds = tuple[float, float, float, float]


@dataclass(frozen=True)
class DemWindow:
    """A DEM sub-array with its georeferencing.

    ``data``: float32 (rows, cols) elevations in metres, NaN where the DEM has no data.
    ``transform``: affine map from (col, row) pixel-corner coordinates to raster-CRS x, y.
    ``crs``: the raster CRS (a ``rasterio.crs.CRS``). ``window``: the DEM's north-up pixel
    window the data was read from (``Terrain.read_dem_window``), None when unknown.
    """

    data: NDArray[np.float32]
    transform: Affine
    crs: Any
    window: Window | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the window."""
        rows, cols = self.data.shape
        return rows, cols

    @property
    def res(self) -> tuple[float, float]:
        """Pixel size (x, y) in map units, both positive."""
        return abs(self.transform.a), abs(self.transform.e)

    @property
    def bounds(self) -> Bounds:
        """(left, bottom, right, top) of the window in raster-CRS map units."""
        return _bounds_of(self.transform, self.shape)

    def xy_to_colrow(self, x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Map x, y -> fractional (col, row) with cell centres at integers."""
        col, row = ~self.transform @ (np.asarray(x, float), np.asarray(y, float))
        return np.asarray(col) - 0.5, np.asarray(row) - 0.5

    def colrow_to_xy(self, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (col, row), centres at integers -> map x, y of the raster CRS."""
        colrow = (np.asarray(col, float) + 0.5, np.asarray(row, float) + 0.5)
        x, y = self.transform @ colrow  # type: ignore[operator]  # affine's hints: floats, not arrays
        return np.asarray(x), np.asarray(y)

    def centres_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Map x, y of every cell centre (raster CRS), broadcastable to the window's shape:
        (1, cols) and (rows, 1) arrays on an unrotated grid, (rows, cols) arrays otherwise;
        the values of ``colrow_to_xy`` on ``np.indices``, bit for bit, without its two full
        float64 grids of indices (a 4001 x 4001 window: over 10x less time)."""
        rows, cols = self.shape
        tr = self.transform
        if tr.b == 0.0 and tr.d == 0.0:  # x depends on the column only, y on the row only
            x, _ = self.colrow_to_xy(np.arange(cols), np.zeros(cols))
            _, y = self.colrow_to_xy(np.zeros(rows), np.arange(rows))
            return x[None, :], y[:, None]
        rr, cc = np.indices((rows, cols))
        return self.colrow_to_xy(cc, rr)


@dataclass(frozen=True)
class OrthoWindow:
    """An orthoimage sub-array resampled onto a grid of the DEM's raster CRS.

    ``data``: (bands, rows, cols) in the ortho's dtype; ``valid``: bool (rows, cols), False
    where the ortho has no data or the request falls off the ortho; ``transform`` and ``crs``
    as in ``DemWindow`` (the DEM's raster CRS).
    """

    data: np.ndarray
    valid: NDArray[np.bool_]
    transform: Affine
    crs: Any

    @property
    def bounds(self) -> Bounds:
        """(left, bottom, right, top) in raster-CRS map units."""
        return _bounds_of(self.transform, self.data.shape[-2:])


def _bounds_of(transform: Affine, shape: tuple[int, ...]) -> Bounds:
    """(left, bottom, right, top) of a north-up or south-up grid of ``shape`` (rows, cols)."""
    x0, y0 = transform @ (0, 0)
    x1, y1 = transform @ (shape[1], shape[0])
    return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)


def _out(a: np.ndarray, like: Any) -> Any:
    """Return a Python float for scalar inputs, an array otherwise."""
    return float(a) if np.ndim(like) == 0 else np.asarray(a, float)


class Terrain:
    """A DEM (and optional orthoimage) opened with rasterio; use as a context manager.

    >>> with Terrain.open("dem.tif", ortho="ortho.tif") as t:   # doctest: +SKIP
    ...     win = t.read_dem_window(x, y, 2000.0)
    """

    def __init__(self, dem_path: str | Path, ortho: str | Path | None = None) -> None:
        self.dem_path = str(dem_path)
        self.ortho_path = None if ortho is None else str(ortho)
        self._dem: Any = None
        self._ortho: Any = None
        self._open()

    @classmethod
    def open(cls, dem_path: str | Path, ortho: str | Path | None = None) -> Terrain:
        """Open a DEM (any GDAL path or URL) and optionally an orthoimage."""
        return cls(dem_path, ortho)

    # -- lifecycle -------------------------------------------------------------------------
    def _open(self) -> None:
        """Open the datasets and check their CRSs are projected, their grids axis-aligned, the
        DEM's blocks of a bounded size (``check_dem_blocks``) and its values elevations on
        Mars (``check_dem_values``); TerrainError naming the file otherwise."""
        self._dem = _open_raster(self.dem_path, "DEM")
        try:
            crs = self._dem.crs
            if crs is None or not crs.to_wkt():
                raise TerrainError(f"{self.dem_path}: DEM has no CRS (georeferencing missing)")
            self._grid = NorthUp.of(self._dem, self.dem_path, "DEM")
            self.crs_wkt: str = crs.to_wkt()
            self.pyproj_crs = CRS.from_wkt(self.crs_wkt)
            check_map_crs(self.pyproj_crs, self.dem_path, "DEM")
            check_dem_blocks(self._dem, self.dem_path)
            check_dem_values(self._dem, self.dem_path)
            if self.ortho_path is not None:
                self._ortho = _open_raster(self.ortho_path, "orthoimage")
                if self._ortho.crs is None or not self._ortho.crs.to_wkt():
                    raise TerrainError(f"{self.ortho_path}: orthoimage has no CRS")
                check_map_crs(CRS.from_wkt(self._ortho.crs.to_wkt()), self.ortho_path, "ortho")
                self._ortho_grid = NorthUp.of(self._ortho, self.ortho_path, "orthoimage")
        except Exception:
            self.close()
            raise

    def close(self) -> None:
        """Close the datasets (idempotent)."""
        for ds in (self._dem, self._ortho):
            if ds is not None and not ds.closed:
                ds.close()

    def __enter__(self) -> Terrain:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- metadata ----------------------------------------------------------------------------
    @property
    def dem_dataset(self) -> Any:
        """The open rasterio dataset of the DEM (for readers that share its block cache)."""
        return self._dem

    @property
    def crs(self) -> Any:
        """The DEM's raster CRS (``rasterio.crs.CRS``)."""
        return self._dem.crs

    @property
    def transform(self) -> Affine:
        """The full DEM's north-up affine transform (pixel corners -> raster-CRS x, y)."""
        return self._grid.transform

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the full DEM."""
        return self._dem.height, self._dem.width

    @property
    def bounds(self) -> Bounds:
        """(left, bottom, right, top) of the full DEM in raster-CRS map units."""
        return _bounds_of(self.transform, self.shape)

    @property
    def res(self) -> tuple[float, float]:
        """DEM pixel size (x, y) in map units."""
        return abs(self.transform.a), abs(self.transform.e)

    def contains(self, x: float, y: float) -> bool:
        """True when raster-CRS point (x, y) lies on the DEM."""
        left, bottom, right, top = self.bounds
        return left <= x <= right and bottom <= y <= top

    # -- coordinates -------------------------------------------------------------------------
    def to_raster_crs(self, xs: ArrayLike, ys: ArrayLike, src_crs: Any) -> tuple[Any, Any]:
        """Points x, y in ``src_crs`` (proj string, EPSG, WKT or CRS) -> raster-CRS x, y."""
        x, y = map_to_map(xs, ys, src_crs, self.crs_wkt)
        return _out(x, xs), _out(y, ys)

    def from_raster_crs(self, xs: ArrayLike, ys: ArrayLike, dst_crs: Any) -> tuple[Any, Any]:
        """Raster-CRS x, y -> x, y in ``dst_crs``."""
        x, y = map_to_map(xs, ys, self.crs_wkt, dst_crs)
        return _out(x, xs), _out(y, ys)

    def from_lonlat(self, lon: ArrayLike, lat: ArrayLike) -> tuple[Any, Any]:
        """Planetocentric lon, lat (degrees, Mars sphere) -> raster-CRS x, y (map units)."""
        return self.to_raster_crs(lon, lat, MARS_LONLAT)

    def to_lonlat(self, x: ArrayLike, y: ArrayLike) -> tuple[Any, Any]:
        """Raster-CRS x, y (map units) -> planetocentric lon, lat (degrees, Mars sphere)."""
        return self.from_raster_crs(x, y, MARS_LONLAT)

    # -- DEM -------------------------------------------------------------------------------
    def require_inside(self, x: float, y: float, what: str) -> None:
        """Raise TerrainError naming the file when raster-CRS point (x, y) is off the DEM.

        ``what`` names the point in the message ("observer", "camera").
        """
        if not (math.isfinite(x) and math.isfinite(y)) or not self.contains(x, y):
            left, bottom, right, top = self.bounds
            raise TerrainError(
                f"{self.dem_path}: {what} at x={x:.3f}, y={y:.3f} lies outside the DEM "
                f"(x {left:.3f}..{right:.3f}, y {bottom:.3f}..{top:.3f})"
            )

    def _read_dem(self, window: Window) -> NDArray[np.float32]:
        """Read band 1 in ``window`` as float32 metres, nodata/masked -> NaN, scale/offset;
        TerrainError naming the DEM when GDAL cannot read it (a truncated or damaged file)."""
        scale = self._dem.scales[0] if self._dem.scales else 1.0
        offset = self._dem.offsets[0] if self._dem.offsets else 0.0
        identity = scale == 1.0 and offset == 0.0
        floating = np.issubdtype(np.dtype(self._dem.dtypes[0]), np.floating)
        with reading(self.dem_path, "DEM"):  # infinite values: NaN in the same pass
            out = self._grid.read_nan(self._dem, 1, window, nonfinite=floating and identity)
        if not identity:
            out = out * np.float32(scale) + np.float32(offset)
            if floating:
                out[~np.isfinite(out)] = np.nan
        return np.asarray(out)

    def _dem_cells(self, win: Window, within: DemWindow | None) -> NDArray[np.float32]:
        """``_read_dem(win)``, sliced from ``within`` when its pixel window holds ``win``."""
        held = None if within is None else within.window
        if held is not None:
            dc, dr = int(win.col_off - held.col_off), int(win.row_off - held.row_off)
            if (dc >= 0 and dr >= 0 and dc + win.width <= held.width
                    and dr + win.height <= held.height):  # fmt: skip
                assert within is not None
                return within.data[dr : dr + int(win.height), dc : dc + int(win.width)]
        return self._read_dem(win)

    def _pixel_window(self, left: float, bottom: float, right: float, top: float) -> Window:
        """Integer pixel window covering the box, clipped to the DEM (may be empty)."""
        w = self._grid.window_of(left, bottom, right, top)
        col0 = max(0, math.floor(w.col_off))
        row0 = max(0, math.floor(w.row_off))
        col1 = min(self._dem.width, math.ceil(w.col_off + w.width))
        row1 = min(self._dem.height, math.ceil(w.row_off + w.height))
        return Window(col0, row0, max(0, col1 - col0), max(0, row1 - row0))

    def read_dem_window(
        self, x: float, y: float, radius: float, *, check_observer: bool = True
    ) -> DemWindow:
        """DEM cells within ``radius`` (map units) of raster-CRS point (x, y), clipped to the DEM.

        The window is the square [x - radius, x + radius] x [y - radius, y + radius] widened to
        whole cells (plus one cell margin). With ``check_observer`` (default), raises
        ``TerrainError`` when (x, y) is off the DEM or the DEM has no data under it.
        """
        x, y = float(x), float(y)
        if check_observer:
            self.require_inside(x, y, "observer")
        pad = float(radius) + max(self.res)
        win = self._pixel_window(x - pad, y - pad, x + pad, y + pad)
        if win.width == 0 or win.height == 0:
            raise TerrainError(f"{self.dem_path}: window around x={x}, y={y} is empty")
        data = self._read_dem(win)
        dem = DemWindow(data, window_transform(win, self.transform), self.crs, win)
        if check_observer:
            self._check_data_under(dem, x, y)
        return dem

    def _check_data_under(self, dem: DemWindow, x: float, y: float) -> None:
        """Raise TerrainError when the DEM cell under (x, y) is nodata."""
        col, row = ~dem.transform @ (x, y)
        r = min(max(math.floor(row), 0), dem.shape[0] - 1)
        c = min(max(math.floor(col), 0), dem.shape[1] - 1)
        if not np.isfinite(dem.data[r, c]):
            raise TerrainError(
                f"{self.dem_path}: DEM has no data under the observer at x={x:.3f}, y={y:.3f}"
            )

    def elevation_at(self, x: float, y: float, within: DemWindow | None = None) -> float:
        """Bilinear DEM elevation (metres) at raster-CRS (x, y); TerrainError off-DEM/nodata.

        Interpolates between cell centres; within half a cell of the DEM edge the nearest edge
        cells are used. ``within``: a window this DEM's ``read_dem_window`` read; the cells
        are taken from it when it holds them (the same values, no read).
        """
        x, y = float(x), float(y)
        self.require_inside(x, y, "point")
        col, row = ~self.transform @ (x, y)
        col, row = col - 0.5, row - 0.5
        c0 = min(max(math.floor(col), 0), max(self._dem.width - 2, 0))
        r0 = min(max(math.floor(row), 0), max(self._dem.height - 2, 0))
        patch = self._dem_cells(Window(c0, r0, 2, 2), within)
        fc = min(max(col - c0, 0.0), 1.0)
        fr = min(max(row - r0, 0.0), 1.0)
        z = _bilinear_patch(patch, fc, fr)
        if not math.isfinite(z):
            raise TerrainError(
                f"{self.dem_path}: DEM has no data at x={x:.3f}, y={y:.3f} (nodata under point)"
            )
        return z

    # -- ortho -------------------------------------------------------------------------------
    def read_ortho_window(
        self, bounds: Bounds, out_shape: tuple[int, int] | None = None
    ) -> OrthoWindow:
        """Orthoimage over ``bounds`` (left, bottom, right, top in the DEM's raster CRS).

        ``out_shape`` (rows, cols) sets the output grid; by default the ortho's native pixel
        size. An ortho in another CRS is reprojected (bilinear) onto the raster-CRS grid; one in
        the same CRS is read with a window (resampled when ``out_shape`` differs). Cells off
        the ortho or nodata have ``valid`` False and value 0.
        """
        if self._ortho is None:
            raise TerrainError(f"{self.dem_path}: no orthoimage was opened with this DEM")
        left, bottom, right, top = (float(v) for v in bounds)
        if not (right > left and top > bottom):
            raise TerrainError(f"{self.ortho_path}: empty ortho request bounds {bounds}")
        shape = out_shape or self._native_ortho_shape((left, bottom, right, top))
        dst_transform = Affine(
            (right - left) / shape[1], 0.0, left, 0.0, -(top - bottom) / shape[0], top
        )
        if crs_string(self._ortho.crs) == self.crs_wkt or self._ortho.crs == self.crs:
            data, valid = self._ortho_same_crs((left, bottom, right, top), shape)
        else:
            data, valid = self._ortho_reprojected(dst_transform, shape)
        return OrthoWindow(data, valid, dst_transform, self.crs)

    def _native_ortho_shape(self, bounds: Bounds) -> tuple[int, int]:
        """Output (rows, cols) at the ortho's own pixel size over raster-CRS ``bounds``."""
        left, bottom, right, top = bounds
        ob = transform_bounds(self.crs, self._ortho.crs, left, bottom, right, top)
        ow = self._ortho.res
        cols = max(1, round((ob[2] - ob[0]) / ow[0]))
        rows = max(1, round((ob[3] - ob[1]) / ow[1]))
        return rows, cols

    def _ortho_same_crs(
        self, bounds: Bounds, shape: tuple[int, int]
    ) -> tuple[np.ndarray, NDArray[np.bool_]]:
        """Boundless windowed read of an ortho in the DEM's CRS, resampled to ``shape``."""
        grid = self._ortho_grid
        win = from_bounds(*bounds, transform=grid.transform)
        with reading(self.ortho_path, "orthoimage"):
            data = grid.read(
                self._ortho,
                None,
                win,
                out_shape=(self._ortho.count, *shape),
                boundless=True,
                masked=True,
                resampling=Resampling.bilinear,
            )
        valid = ~np.ma.getmaskarray(data).any(axis=0)
        assert isinstance(valid, np.ndarray)  # (bands, rows, cols) reduced over the bands
        return np.ma.filled(data, 0), valid

    def _ortho_reprojected(
        self, dst_transform: Affine, shape: tuple[int, int]
    ) -> tuple[np.ndarray, NDArray[np.bool_]]:
        """Reproject the needed part of an ortho in another CRS onto the raster-CRS grid."""
        left, bottom, right, top = _bounds_of(dst_transform, shape)
        ob = transform_bounds(self.crs, self._ortho.crs, left, bottom, right, top, densify_pts=21)
        grid = self._ortho_grid
        src_win = from_bounds(*ob, transform=grid.transform).round_offsets().round_lengths()
        src_win = src_win.intersection(Window(0, 0, grid.width, grid.height))
        with reading(self.ortho_path, "orthoimage"):
            src = grid.read(self._ortho, None, src_win, masked=True)
        count = self._ortho.count
        dst = np.zeros((count, *shape), dtype=self._ortho.dtypes[0])
        dst_ok = np.zeros((count, *shape), dtype=np.uint8)
        for b in range(count):
            ok = (~np.ma.getmaskarray(src[b])).astype(np.uint8)
            kw = {
                "src_transform": window_transform(src_win, grid.transform),
                "src_crs": self._ortho.crs,
                "dst_transform": dst_transform,
                "dst_crs": self.crs,
            }
            reproject(np.ma.filled(src[b], 0), dst[b], resampling=Resampling.bilinear, **kw)
            reproject(ok, dst_ok[b], resampling=Resampling.nearest, **kw)
        valid = dst_ok.all(axis=0)
        assert isinstance(valid, np.ndarray)  # (bands, rows, cols) reduced over the bands
        return dst, valid


def _open_raster(path: str, what: str) -> Any:
    """rasterio.open with a TerrainError naming the file on failure."""
    try:
        return open_raster(path)
    except rasterio.errors.RasterioIOError as exc:
        raise TerrainError(f"{path}: cannot open {what}: {exc}") from exc


@contextlib.contextmanager
def reading(path: object, what: str) -> Iterator[None]:
    """A block reading ``path`` (a ``what``: "DEM", "orthoimage") whose rasterio errors
    become a TerrainError naming the file and GDAL's reason, not rasterio's "Read failed. See
    previous exception for details." alone."""
    try:
        yield
    except rasterio.errors.RasterioError as exc:
        raise TerrainError(
            f"{path}: cannot read the {what} (a truncated or damaged file?): {gdal_reason(exc)}"
        ) from exc


def _bilinear_patch(p: np.ndarray, fc: float, fr: float) -> float:
    """Bilinear value of a (<=2, <=2) patch at (col, row) offsets in [0, 1]; skips 0 weights."""
    total, acc = 0.0, 0.0
    for i, wr in enumerate((1.0 - fr, fr)):
        for j, wc in enumerate((1.0 - fc, fc)):
            w = wr * wc
            if w == 0.0 or i >= p.shape[0] or j >= p.shape[1]:
                continue
            acc += w * float(p[i, j])
            total += w
    return acc / total if total > 0 else float("nan")


#: the side of the decimated read the open-time range check looks at, in pixels
CHECK_SIDE_PX = 256
#: the largest compressed block (tile or strip) a DEM may have, decoded, in bytes: GDAL
#: decodes a whole block for any read inside it, so one deflate block of a 16384 x 16384
#: float32 DEM (1 MiB on disk) costs 1 GiB of memory per worker
MAX_BLOCK_BYTES = 256 << 20


def check_dem_blocks(src: Any, path: str) -> None:
    """TerrainError naming the DEM when a compressed block of band 1 decodes to more than
    MAX_BLOCK_BYTES (a decompression bomb, or a DEM written as one huge strip)."""
    rows, cols = src.block_shapes[0]
    size = rows * cols * np.dtype(src.dtypes[0]).itemsize
    if src.compression is not None and size > MAX_BLOCK_BYTES:
        raise TerrainError(
            f"{path}: DEM is compressed in blocks of {cols} x {rows} pixels ({size >> 20} MiB "
            f"each decoded, over the {MAX_BLOCK_BYTES >> 20} MiB limit): a decompression bomb "
            f"or one huge strip; re-tile it, e.g. gdal_translate -co TILED=YES "
            f"-co COMPRESS=DEFLATE {path} tiled.tif"
        )


def check_dem_values(src: Any, path: str) -> None:
    """TerrainError naming the DEM unless band 1 holds real numbers (an integer or float
    dtype: no complex) whose valid values, on a decimated read of at most CHECK_SIDE_PX
    pixels a side, lie within MARS_ELEVATION_M (3e38 m everywhere is not a Mars surface)."""
    dtype = np.dtype(src.dtypes[0])
    if dtype.kind not in "iuf":
        raise TerrainError(
            f"{path}: DEM band 1 is {dtype.name}, not real numbers (elevations in metres)"
        )
    rows = max(1, min(src.height, CHECK_SIDE_PX))
    cols = max(1, min(src.width, CHECK_SIDE_PX))
    with reading(path, "DEM"):
        data = src.read(1, out_shape=(rows, cols), masked=True)
    values = np.ma.compressed(data).astype(np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return  # all nodata: the samples fail at coverage, named
    low, high = float(values.min()), float(values.max())
    lo, hi = MARS_ELEVATION_M
    if low < lo or high > hi:
        raise TerrainError(
            f"{path}: DEM elevations {low:.6g} .. {high:.6g} m lie outside the Mars range "
            f"{lo:g} .. {hi:g} m (wrong units, nodata not declared, or not a DEM)"
        )
