"""Any axis-aligned raster grid presented as its north-up equivalent.

A GeoTIFF's geotransform maps pixel (col, row) corners to map x, y: x = a col + b row + c,
y = d col + e row + f. North-up grids have a > 0, e < 0; some PDS products and GDAL
conversions are south-up (e > 0) or east-left (a < 0). ``NorthUp`` maps windows of the
north-up grid onto the raster's own pixels and flips what it reads, so the rest of the code
only ever sees a > 0, e < 0. Rotated or sheared grids (b or d not 0) are refused.

Frames and units: windows and arrays in the north-up grid's pixels (row 0 north, col 0
west); transforms from pixel corners to the raster's CRS, map units. The north-up origin is
computed in float64 from the raster's own (``c + a * width``), never through float32.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from affine import Affine
from numpy.typing import NDArray
from rasterio.enums import MaskFlags
from rasterio.windows import Window, from_bounds

from mars_pairs.errors import TerrainError
from mars_pairs.kernels.nodata import float32_nodata_nan, uint8_nodata_nan


@dataclass(frozen=True)
class NorthUp:
    """A raster's grid as north-up: ``transform`` (a > 0, e < 0), ``width`` and ``height``
    in pixels, and whether the raster's own columns run west (``flip_cols``) and its rows
    north (``flip_rows``)."""

    transform: Affine
    width: int
    height: int
    flip_cols: bool
    flip_rows: bool

    @classmethod
    def of(cls, dataset: Any, path: str, what: str) -> NorthUp:
        """The north-up view of an open rasterio ``dataset``; TerrainError naming ``path``
        when its grid is rotated, sheared or degenerate (a zero pixel size)."""
        t = dataset.transform
        a, b, c, d, e, f = (float(v) for v in (t.a, t.b, t.c, t.d, t.e, t.f))
        if b != 0.0 or d != 0.0:
            raise TerrainError(
                f"{path}: {what} grid is rotated or sheared (geotransform x = {a:g} col + "
                f"{b:g} row + {c:.3f}, y = {d:g} col + {e:g} row + {f:.3f}); only axis-aligned "
                f"grids are read: warp it to a north-up grid first, e.g. gdalwarp {path} "
                "north_up.tif"
            )
        if not (np.isfinite([a, c, e, f]).all() and a != 0.0 and e != 0.0):
            raise TerrainError(
                f"{path}: {what} geotransform has a zero or non-finite pixel size "
                f"(x size {a:g}, y size {e:g}): georeferencing missing or broken"
            )
        w, h = int(dataset.width), int(dataset.height)
        left = c + a * w if a < 0 else c
        top = f + e * h if e > 0 else f
        transform = Affine(abs(a), 0.0, left, 0.0, -abs(e), top)
        return cls(transform, w, h, a < 0, e > 0)

    @property
    def flipped(self) -> bool:
        """True when the raster's own grid is not north-up."""
        return self.flip_cols or self.flip_rows

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the raster in its CRS, map units."""
        t = self.transform
        return t.c, t.f + t.e * self.height, t.c + t.a * self.width, t.f

    @cached_property
    def _inverse(self) -> tuple[float, float, float, float, float, float]:
        """The coefficients of ``~transform`` (map -> north-up pixel), computed once."""
        inv = ~self.transform
        return inv.a, inv.b, inv.c, inv.d, inv.e, inv.f

    def window_of(self, left: float, bottom: float, right: float, top: float) -> Window:
        """The fractional north-up window of a map box: ``rasterio.windows.from_bounds`` with
        this grid's transform, the same numbers (its corners through the inverse transform,
        summed in the same order) without its array round trip; inconsistent bounds go
        through it (its WindowError)."""
        if right < left or bottom > top:
            return from_bounds(left, bottom, right, top, transform=self.transform)
        a, b, c, d, e, f = self._inverse
        corners = ((left, top), (right, top), (right, bottom), (left, bottom))
        cols = [x * a + y * b + c for x, y in corners]
        rows = [x * d + y * e + f for x, y in corners]
        col0, row0 = min(cols), min(rows)
        return Window(col0, row0, max(max(cols) - col0, 0.0), max(max(rows) - row0, 0.0))

    def own_window(self, window: Window) -> Window:
        """The raster's own pixel window holding north-up ``window`` (fractional or off the
        raster windows map the same way)."""
        col, row = window.col_off, window.row_off
        if self.flip_cols:
            col = self.width - col - window.width
        if self.flip_rows:
            row = self.height - row - window.height
        return Window(col, row, window.width, window.height)

    def orient(self, array: Any) -> Any:
        """An array read in the raster's own pixel order (rows, cols last) in north-up order,
        C-contiguous (a masked array stays masked)."""
        if self.flip_rows:
            array = array[..., ::-1, :]
        if self.flip_cols:
            array = array[..., ::-1]
        return array.copy() if self.flipped else array

    def read(self, dataset: Any, indexes: Any, window: Window, **kwargs: Any) -> Any:
        """``dataset.read(indexes, window=...)`` for a north-up ``window``, in north-up order;
        ``kwargs`` as rasterio's (``masked``, ``out_shape``, ``boundless``, ...)."""
        return self.orient(dataset.read(indexes, window=self.own_window(window), **kwargs))

    def read_nan(
        self, dataset: Any, band: int, window: Window, *, nonfinite: bool = False
    ) -> NDArray[np.float32]:
        """Band ``band`` in a north-up ``window`` as float32, NaN where its GDAL mask says no
        data: the same values as ``read(..., masked=True)`` cast to float32 and filled with
        NaN, without building the mask band and a masked array. A band without a mask, or
        whose mask is a nodata value ``nodata_mask`` tests as GDAL does (float32; an integer
        type with an integral value inside its range), is read once and compared here; any
        other (an alpha band, a per-dataset or internal mask, float64) goes through rasterio's
        masked read. With ``nonfinite``, infinite values are NaN too."""
        flags = dataset.mask_flag_enums[band - 1]
        nodata = dataset.nodatavals[band - 1]
        dtype = dataset.dtypes[band - 1]
        float32 = dtype == "float32" and nodata is not None and not math.isnan(nodata)
        if flags == [MaskFlags.nodata] and float32:  # one compiled pass
            data = self.read(dataset, band, window)
            return float32_nodata_nan(data, np.float32(nodata), nonfinite)
        if flags == [MaskFlags.all_valid]:
            out = np.asarray(self.read(dataset, band, window), dtype=np.float32)
        elif flags != [MaskFlags.nodata] or not _compared_here(dtype, nodata):
            masked = self.read(dataset, band, window, masked=True)
            out = np.asarray(masked.astype(np.float32).filled(np.nan))
        elif dtype == "uint8":  # an integral nodata in 0..255 (``_compared_here``)
            out = uint8_nodata_nan(self.read(dataset, band, window), int(nodata))
        else:
            out = with_nodata_nan(self.read(dataset, band, window), float(nodata))
        if nonfinite:
            out[~np.isfinite(out)] = np.nan
        return out


def _compared_here(dtype: str, nodata: float | None) -> bool:
    """Whether ``nodata_mask`` tests a band of ``dtype`` as GDAL does: float32, or an
    integer type with an integral ``nodata`` inside its range."""
    if nodata is None:
        return False
    if dtype == "float32":
        return True
    if dtype in ("uint8", "int8", "uint16", "int16", "uint32", "int32"):
        info = np.iinfo(dtype)
        return float(nodata).is_integer() and info.min <= nodata <= info.max
    return False


def nodata_mask(data: NDArray[Any], nodata: float) -> NDArray[np.bool_]:
    """Where ``data`` (float32, or an integer type with ``nodata`` an integer inside its
    range) equals ``nodata`` as GDAL's nodata mask band tests it: integers exactly; float32
    NaN when ``nodata`` is NaN, else ``a == b or |a - b| < eps * |a + b| * 2`` in float32
    (so near -FLT_MAX, where the sum overflows, every value below about -1e31)."""
    if np.issubdtype(data.dtype, np.integer):
        return np.asarray(data == data.dtype.type(int(nodata)))
    if np.isnan(nodata):
        return np.asarray(np.isnan(data))
    nd = np.float32(nodata)
    eps = np.float32(np.finfo(np.float32).eps)
    with np.errstate(over="ignore", invalid="ignore"):
        near = np.abs(data - nd) < eps * np.abs(data + nd) * np.float32(2)
    return np.asarray((data == nd) | near)


def with_nodata_nan(data: NDArray[Any], nodata: float) -> NDArray[np.float32]:
    """``data`` as float32 with NaN where ``nodata_mask`` is set (a new array)."""
    out = data.astype(np.float32)
    out[nodata_mask(data, nodata)] = np.nan
    return out
