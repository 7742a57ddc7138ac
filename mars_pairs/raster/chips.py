"""Orbital chips: a square grid around the rover, north-up or heading-up, read by window.

A chip grid is ``size_px`` x ``size_px`` pixels covering ``size_m`` x ``size_m`` map units,
centred on a map point (x, y in the dataset CRS). Heading-up grids are rotated so that the
camera azimuth points up the image (row 0 towards the azimuth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.errors
from affine import Affine
from numpy.typing import ArrayLike, NDArray
from rasterio.crs import CRS
from rasterio.enums import MaskFlags, Resampling
from rasterio.warp import reproject, transform_bounds
from rasterio.warp import transform as warp_points
from rasterio.windows import Window
from rasterio.windows import transform as window_transform

from mars_pairs.errors import TerrainError
from mars_pairs.geometry.frames import crs_string
from mars_pairs.kernels.resample import sample_affine
from mars_pairs.raster.grid import NorthUp
from mars_pairs.raster.transfer import sample_at
from mars_pairs.raster.vsi import gdal_reason, open_raster

#: Most pixels ``ChipReader.read_points`` holds at once (a strip of its window).
POINT_STRIP_PIXELS = 1 << 22


@dataclass(frozen=True)
class ChipGrid:
    """A chip's pixel grid on the map: affine transform (pixel -> map), CRS and size.

    ``rotation_deg`` is the map azimuth (clockwise from grid north) of the chip's up direction.
    """

    transform: Affine
    crs: str
    size_px: int
    center_x: float
    center_y: float
    size_m: float
    rotation_deg: float = 0.0

    @classmethod
    def around(
        cls, x: float, y: float, size_m: float, size_px: int, crs: object, rotation_deg: float = 0.0
    ) -> ChipGrid:
        """A grid centred on map point (x, y) whose up direction is ``rotation_deg``."""
        res = size_m / size_px
        t = math.radians(rotation_deg)
        right = (math.cos(t), -math.sin(t))  # map direction of increasing column
        down = (-math.sin(t), -math.cos(t))  # map direction of increasing row
        a, b = res * right[0], res * down[0]
        d, e = res * right[1], res * down[1]
        half = size_px / 2.0
        c = x - (a + b) * half
        f = y - (d + e) * half
        return cls(Affine(a, b, c, d, e, f), crs_string(crs), size_px, x, y, size_m, rotation_deg)

    @property
    def resolution(self) -> float:
        """Map units per pixel."""
        return self.size_m / self.size_px

    def corners(self) -> NDArray[np.float64]:
        """Map coordinates (4, 2) of the outer corners: top-left, top-right, bottom-right, ..."""
        n = self.size_px
        return np.array([self.transform @ p for p in ((0, 0), (n, 0), (n, n), (0, n))])

    def bounds(self) -> tuple[float, float, float, float]:
        """Axis-aligned map bounds (xmin, ymin, xmax, ymax) of the chip."""
        c = self.corners()
        return (
            float(c[:, 0].min()),
            float(c[:, 1].min()),
            float(c[:, 0].max()),
            float(c[:, 1].max()),
        )

    def to_pixel(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Map points -> chip pixel coordinates (..., 2) as (column, row), pixel-edge origin."""
        inv = ~self.transform
        xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        col = inv.a * xs + inv.b * ys + inv.c
        row = inv.d * xs + inv.e * ys + inv.f
        return np.stack([col, row], axis=-1)


@lru_cache(maxsize=64)
def _same_crs_text(a: str, b: str) -> bool:
    return a == b or CRS.from_user_input(a) == CRS.from_user_input(b)


def _same_crs(a: object, b: object) -> bool:
    return _same_crs_text(crs_string(a), crs_string(b))


def _sample_grid(
    values: NDArray[np.float32], src_transform: Affine, grid: ChipGrid, nearest: bool
) -> NDArray[np.float32]:
    """Resample an array on ``src_transform`` onto ``grid`` (same CRS) with the numba kernel."""
    m = ~src_transform @ grid.transform  # chip pixel -> source pixel
    n = grid.size_px
    return sample_affine(
        np.ascontiguousarray(values, dtype=np.float32), m.a, m.b, m.c, m.d, m.e, m.f, n, n, nearest
    )


@dataclass(frozen=True)
class ValueRange:
    """The range of a band's values (after scale/offset) that maps to 0..255 in 8-bit chips.

    ``source``: "dtype" (an unscaled uint8 band: its values as they are), "declared" (the
    band's GDAL STATISTICS_MINIMUM/MAXIMUM) or "measured" (GDAL's approximate statistics).
    """

    low: float
    high: float
    source: str

    def to_uint8(self, values: NDArray[np.float32]) -> NDArray[np.uint8]:
        """``values`` scaled from [low, high] to 0..255 (NaN -> 0)."""
        if self.source == "dtype":  # the byte values as they are (truncated after bilinear)
            return np.nan_to_num(values, nan=0.0).clip(0, 255).astype(np.uint8)
        span = self.high - self.low
        scaled = (values.astype(np.float64) - self.low) * (255.0 / span if span > 0 else 0.0)
        return np.rint(np.nan_to_num(scaled, nan=0.0)).clip(0, 255).astype(np.uint8)

    def to_dict(self) -> dict[str, object]:
        """Plain values for meta.json."""
        return {"low": self.low, "high": self.high, "source": self.source}


class ChipReader:
    """An open raster that cuts chips; use as a context manager, like a rasterio dataset.

    A chip is one windowed read of the pixels it covers, then in the raster's own CRS a
    numba resampling (any rotation), in another CRS GDAL's warper. Only the blocks under the
    chip are read, never the whole raster. A pixel without data is NaN: off the raster, or
    masked by the band's GDAL mask (nodata, an alpha band's 0, an internal mask), or a
    bilinear neighbour of such a pixel. Values are the band's physical ones (its GDAL scale
    and offset applied: a DEM in metres). Any axis-aligned grid is read (``NorthUp``); a
    rotated one, or a raster that cannot be opened or read, raises TerrainError naming the
    file.
    """

    def __init__(self, path: str | Path, dataset: Any = None) -> None:
        """Open the raster at ``path``; or, with ``dataset`` (an open rasterio dataset of
        ``path``, e.g. ``Terrain.dem_dataset``), read through it: its GDAL block cache is
        shared with its other reads, and ``close`` leaves it open for its owner."""
        self.path = str(path)
        self._owned = dataset is None
        try:
            self.dataset = open_raster(self.path) if dataset is None else dataset
        except rasterio.errors.RasterioError as exc:
            raise TerrainError(f"{self.path}: cannot open the raster: {exc}") from None
        try:
            self.grid = NorthUp.of(self.dataset, self.path, "raster")
        except TerrainError:
            if self._owned:
                self.dataset.close()
            raise
        self.crs_wkt = self.dataset.crs.to_wkt() if self.dataset.crs else ""
        self._ranges: dict[int, ValueRange] = {}

    def scale_offset(self, band: int = 1) -> tuple[float, float]:
        """The band's GDAL scale and offset (physical = raw * scale + offset)."""
        scales, offsets = self.dataset.scales, self.dataset.offsets
        scale = scales[band - 1] if scales and scales[band - 1] is not None else 1.0
        offset = offsets[band - 1] if offsets and offsets[band - 1] is not None else 0.0
        return float(scale), float(offset)

    def value_range(self, band: int = 1) -> ValueRange:
        """The band's display range for 8-bit chips (see ValueRange), computed once."""
        if band not in self._ranges:
            self._ranges[band] = self._value_range(band)
        return self._ranges[band]

    def _value_range(self, band: int) -> ValueRange:
        scale, offset = self.scale_offset(band)
        if self.dataset.dtypes[band - 1] == "uint8" and (scale, offset) == (1.0, 0.0):
            return ValueRange(0.0, 255.0, "dtype")
        tags = self.dataset.tags(band)
        try:
            low = float(tags["STATISTICS_MINIMUM"])
            high = float(tags["STATISTICS_MAXIMUM"])
            source = "declared"
        except (KeyError, ValueError):
            low, high = self._measured_range(band)
            source = "measured"
        if not (math.isfinite(low) and math.isfinite(high) and high > low):
            raise TerrainError(
                f"{self.path}: band {band}: no usable value range ({source} {low}..{high})"
            )
        return ValueRange(low, high, source)

    def _measured_range(self, band: int, cells: int = 1 << 20) -> tuple[float, float]:
        """Min and max of the band's physical values on a decimated read of <= ``cells``
        (GDAL uses overviews when there are; no statistics file is written beside it)."""
        src = self.dataset
        step = max(1.0, math.sqrt(src.width * src.height / cells))
        shape = (max(1, round(src.height / step)), max(1, round(src.width / step)))
        values = src.read(band, out_shape=shape, masked=True, resampling=Resampling.nearest)
        scale, offset = self.scale_offset(band)
        data = values.astype(np.float64).filled(np.nan) * scale + offset
        data = data[np.isfinite(data)]
        if data.size == 0:
            return math.nan, math.nan
        return float(data.min()), float(data.max())

    def read_uint8(self, grid: ChipGrid, *, band: int = 1) -> NDArray[np.uint8]:
        """The chip of ``band`` scaled to 0..255 by ``value_range`` (bilinear; NaN -> 0)."""
        return self.value_range(band).to_uint8(self.read(grid, band=band))

    def read(self, grid: ChipGrid, *, nearest: bool = False, band: int = 1) -> NDArray[np.float32]:
        """The chip of ``band`` on ``grid`` (bilinear, or nearest for masks and classes)."""
        if not 1 <= band <= self.dataset.count:
            raise TerrainError(f"{self.path}: band {band}: the raster has {self.dataset.count}")
        scale, offset = self.scale_offset(band)
        try:
            values = self._read(grid, nearest, band)
        except rasterio.errors.RasterioError as exc:
            raise TerrainError(
                f"{self.path}: band {band}: cannot read a chip: {gdal_reason(exc)}"
            ) from None
        if (scale, offset) != (1.0, 0.0):
            values = values * np.float32(scale) + np.float32(offset)
        return values

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the raster in its own CRS, map units."""
        return self.grid.bounds

    def bounds_in(self, crs: object) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the raster in ``crs`` (its own bounds when the CRS
        is the raster's; else the densified envelope of their reprojection)."""
        if _same_crs(self.crs_wkt, crs):
            return self.bounds
        box = transform_bounds(self.crs_wkt, crs_string(crs), *self.bounds, densify_pts=21)
        return (float(box[0]), float(box[1]), float(box[2]), float(box[3]))

    def _read(self, grid: ChipGrid, nearest: bool, band: int) -> NDArray[np.float32]:
        same = _same_crs(self.crs_wkt, grid.crs)
        box = grid.bounds()
        if not same:  # the chip's envelope in the raster's CRS (bounds of the reprojection)
            box = transform_bounds(grid.crs, self.crs_wkt, *box, densify_pts=21)
        n = grid.size_px
        win = self._window(box)
        if win is None:
            return np.full((n, n), np.nan, dtype=np.float32)
        values = self.grid.read_nan(self.dataset, band, win)
        src_transform = window_transform(win, self.grid.transform)
        if same:
            return _sample_grid(values, src_transform, grid, nearest)
        return _reproject(values, grid, nearest, src_transform=src_transform, src_crs=self.crs_wkt)

    def read_points(
        self, x: ArrayLike, y: ArrayLike, crs: object, *, band: int = 1
    ) -> NDArray[np.float32]:
        """The band's physical values (bilinear between pixel centres, as ``read``) at map
        points (x, y) in ``crs`` (any shape; reprojected when it is not the raster's); NaN
        for a NaN point, one off the raster or next to a pixel without data. One windowed
        read of the points' bounding box, in strips of at most ``POINT_STRIP_PIXELS`` (the
        memory held stays bounded however far apart the points lie)."""
        if not 1 <= band <= self.dataset.count:
            raise TerrainError(f"{self.path}: band {band}: the raster has {self.dataset.count}")
        xs = np.asarray(x, dtype=np.float64)
        ys = np.asarray(y, dtype=np.float64)
        out = np.full(xs.shape, np.nan, dtype=np.float32)
        ok = np.isfinite(xs) & np.isfinite(ys)
        if not ok.any():
            return out
        px, py = xs[ok], ys[ok]
        if not _same_crs(self.crs_wkt, crs):
            px, py = (np.asarray(v) for v in warp_points(crs_string(crs), self.crs_wkt, px, py))
        win = self._window((px.min(), py.min(), px.max(), py.max()))
        if win is None:
            return out
        inv = ~window_transform(win, self.grid.transform)
        u = inv.a * px + inv.b * py + inv.c - 0.5  # window pixel centres at integers
        v = inv.d * px + inv.e * py + inv.f - 0.5
        values = np.full(px.shape, np.nan, dtype=np.float32)
        rows = int(win.height)
        step = max(1, POINT_STRIP_PIXELS // max(int(win.width), 1))
        first = np.clip(np.floor(v), 0, rows - 1)  # the upper row of each point's 2 x 2
        try:
            for r0 in range(0, rows, step):
                r1 = min(r0 + step + 1, rows)  # one row more: the lower rows of the 2 x 2
                sel = np.nonzero((first >= r0) & (first < r0 + step))[0]
                if not len(sel):
                    continue
                strip = Window(win.col_off, win.row_off + r0, win.width, r1 - r0)
                values[sel] = self._strip_points(band, strip, u[sel], v[sel] - r0)
        except rasterio.errors.RasterioError as exc:
            raise TerrainError(
                f"{self.path}: band {band}: cannot read points: {gdal_reason(exc)}"
            ) from None
        scale, offset = self.scale_offset(band)
        if (scale, offset) != (1.0, 0.0):
            values = values * np.float32(scale) + np.float32(offset)
        out[ok] = values
        return out

    def _strip_points(
        self, band: int, strip: Window, u: NDArray[np.float64], v: NDArray[np.float64]
    ) -> NDArray[np.float32]:
        """``read_points``' bilinear values at the strip's grid points (u, v) (column, row;
        centres at integers): NaN next to a pixel without data.

        A band whose only mask is its nodata value (or that has none) is read as it is and
        the value compared at the four neighbours of each point alone; any other mask (an
        alpha band, an internal mask) is read and the strip converted to float32 with NaN
        where it masks. The same values either way: the kernel weighs the pixels in float64
        from any dtype, and a masked neighbour makes the point NaN, whatever its weight."""
        nodata = self._plain_nodata(band)
        if nodata is None:
            data = self.grid.read(self.dataset, band, strip, masked=True)
            values = sample_at(data.astype(np.float32).filled(np.nan), u, v, nearest=False)[0]
            return np.asarray(values, dtype=np.float32)
        data = self.grid.read(self.dataset, band, strip)
        values = sample_at(data, u, v, nearest=False)[0]
        if nodata.size:  # the kernel's 2 x 2 of each point (it makes the off-grid ones NaN)
            h, w = data.shape
            # NaN points are NaN whatever their mask: fmin/fmax put them anywhere on the grid
            x = np.fmax(np.fmin(u, w - 1.0), 0.0)
            y = np.fmax(np.fmin(v, h - 1.0), 0.0)
            c0 = np.minimum(x.astype(np.intp), w - 2) if w > 1 else np.zeros(len(x), np.intp)
            r0 = np.minimum(y.astype(np.intp), h - 2) if h > 1 else np.zeros(len(y), np.intp)
            at = r0 * w + c0  # the 2 x 2's flat indices: at, at + dc, at + dr, at + dr + dc
            dc, dr = int(w > 1), w if h > 1 else 0
            flat = np.ravel(data)
            value = nodata[0]
            masked = np.zeros(len(x), dtype=bool)
            for step in (0, dc, dr, dr + dc):
                pixel = flat.take(at + step if step else at)
                masked |= np.isnan(pixel) if np.isnan(value) else pixel == value
            values[masked] = np.nan
        return np.asarray(values, dtype=np.float32)

    def _plain_nodata(self, band: int) -> NDArray[Any] | None:
        """The band's nodata value as one value of its dtype when that value is its only
        mask (an empty array: no mask at all); None for any other mask, or a nodata value
        the dtype cannot hold exactly (GDAL's mask then decides)."""
        flags = self.dataset.mask_flag_enums[band - 1]
        if flags == [MaskFlags.all_valid]:
            return np.empty(0)
        nodata = self.dataset.nodatavals[band - 1]
        if flags != [MaskFlags.nodata] or nodata is None:
            return None
        dtype = np.dtype(self.dataset.dtypes[band - 1])
        if dtype.kind not in "uif":
            return None
        with np.errstate(invalid="ignore", over="ignore"):
            value = np.array([nodata]).astype(dtype)
        same = float(value[0]) == nodata or (math.isnan(nodata) and np.isnan(value[0]))
        return value if same else None

    def _window(self, box: tuple[float, float, float, float]) -> Window | None:
        """The north-up pixel window covering map ``box`` (raster CRS) and two pixels more,
        clipped to the raster; None when less than 2 x 2 pixels remain."""
        g = self.grid
        window = g.window_of(*box)
        col0 = max(math.floor(window.col_off) - 2, 0)
        row0 = max(math.floor(window.row_off) - 2, 0)
        col1 = min(math.ceil(window.col_off + window.width) + 2, g.width)
        row1 = min(math.ceil(window.row_off + window.height) + 2, g.height)
        if col1 - col0 < 2 or row1 - row0 < 2:
            return None
        return Window(col0, row0, col1 - col0, row1 - row0)

    def close(self) -> None:
        """Close the raster (a dataset handed in stays open)."""
        if self._owned:
            self.dataset.close()

    def __enter__(self) -> ChipReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_chip(
    path: str, grid: ChipGrid, *, nearest: bool = False, band: int = 1
) -> NDArray[np.float32]:
    """One chip of a raster file (opens and closes it; use ChipReader for many chips)."""
    with ChipReader(path) as reader:
        return reader.read(grid, nearest=nearest, band=band)


def resample_array(
    values: NDArray[np.generic],
    transform: Affine,
    crs: object,
    grid: ChipGrid,
    nearest: bool = True,
) -> NDArray[np.float32]:
    """Resample an in-memory grid (e.g. a viewshed on the DEM window) onto a chip grid."""
    if _same_crs(crs, grid.crs):
        return _sample_grid(np.asarray(values, dtype=np.float32), transform, grid, nearest)
    source = np.asarray(values, dtype=np.float32)
    return _reproject(source, grid, nearest, src_transform=transform, src_crs=crs_string(crs))


def _reproject(source: Any, grid: ChipGrid, nearest: bool, **src: Any) -> NDArray[np.float32]:
    """GDAL-warp ``source`` (a float32 array, NaN = no data, with ``src`` georeferencing) onto
    a chip grid in another CRS; NaN where nothing maps."""
    out = np.full((grid.size_px, grid.size_px), np.nan, dtype=np.float32)
    reproject(
        source=source,
        destination=out,
        dst_transform=grid.transform,
        dst_crs=grid.crs,
        src_nodata=np.nan,
        dst_nodata=np.nan,
        resampling=Resampling.nearest if nearest else Resampling.bilinear,
        tolerance=0.0,
        **src,
    )
    return out


def coverage(values: NDArray[np.floating]) -> float:
    """The fraction (0..1) of a chip's pixels with data: finite values (``ChipReader.read``
    gives NaN off the raster and where the raster's mask says no data)."""
    return float(np.isfinite(values).mean()) if values.size else 0.0
