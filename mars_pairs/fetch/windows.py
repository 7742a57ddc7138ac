"""Window planning: which pixel windows of an orbital raster serve a set of rover positions.

Pure arithmetic, no raster I/O: positions + the source raster's grid (``RasterGrid``: CRS,
north-up affine transform, size) + a reach in ground metres -> pixel windows of that grid.

Frames and units:

- Rover positions are PLACES easting/northing (metres) in the table's own CRS (``pos_crs``).
- Each position is transformed into the raster CRS (through pyproj; the USGS Jezero mosaics
  are eqc lat_ts=0, the PLACES table eqc lat_ts=18.4663) and grown by ``reach_m`` ground
  metres times the raster CRS's largest scale factor there (``pyproj.Proj.get_factors``:
  map units per ground metre), plus ``PAD_CELLS`` cells, then snapped outward to whole
  pixels and clipped to the raster. ``reach_m`` is what the build reads around a rover:
  the view radius (``geometry.radius``) for the DEM, the chip's circumscribed circle
  (``CHIP_REACH`` x ``chips.size_m``, any heading) for the ortho, plus ``margin_m``.
- Windows are (col_off, row_off, width, height) in source pixels; bounds in raster CRS units.

Clustering: positions are taken in table order (a traverse) and each box joins the running
window while the window stays within ``FILL`` times the area the positions' boxes cover and
within ``max_cells``; the windows are then merged pairwise by the same rule (near or
overlapping windows, a return to a place), best fill first. A straight drive becomes one
window, a diagonal 20 km traverse a chain of windows along it, never one bounding box over
the whole traverse.

A window above ``max_cells`` (one position's box alone) is planned but not accepted; the error
names the config key ``fetch.orbital.max_cells``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from affine import Affine
from pyproj import CRS, Proj

from mars_pairs.errors import FetchError
from mars_pairs.geometry.frames import map_to_lonlat, map_to_map

Bounds = tuple[float, float, float, float]
CHIP_REACH = math.sqrt(0.5)  # half-diagonal of a square chip of side 1: any heading fits
PAD_CELLS = 3  # the build reads radius + 3 cells around the observer (view.py, terrain.py)
MAX_CELLS = 200_000_000  # default fetch.orbital.max_cells: 800 MB of float32 per window
MAX_CELLS_KEY = "fetch.orbital.max_cells"
FILL = 1.5  # a window may hold up to 1.5 x the cells its positions' reach covers


@dataclass(frozen=True)
class RasterGrid:
    """A source raster's grid: CRS (WKT), north-up affine (pixel corners -> map), size."""

    crs: str
    transform: Affine
    width: int
    height: int

    @property
    def res(self) -> tuple[float, float]:
        """Pixel size (x, y) in map units, both positive."""
        return abs(self.transform.a), abs(self.transform.e)


@dataclass(frozen=True)
class PlannedWindow:
    """One window of a source raster: pixels, bounds (raster CRS), positions it serves."""

    kind: str  # dem | ortho
    source: str
    col_off: int
    row_off: int
    width: int
    height: int
    bounds: Bounds
    crs: str
    positions: int
    max_cells: int

    @property
    def cells(self) -> int:
        """Pixels in the window."""
        return self.width * self.height

    @property
    def accepted(self) -> bool:
        """True when the window is within ``fetch.orbital.max_cells``."""
        return self.cells <= self.max_cells

    def describe(self) -> str:
        """One line: source, bounds, CRS, cells and the limit's verdict."""
        left, bottom, right, top = self.bounds
        verdict = "accepted" if self.accepted else f"REJECTED: above {MAX_CELLS_KEY}"
        crs = CRS.from_user_input(self.crs)
        with warnings.catch_warnings():  # WKT -> PROJ string, for a one-line CRS
            warnings.simplefilter("ignore", UserWarning)
            name = crs.to_proj4() or crs.name
        return (
            f"{self.kind} {self.width} x {self.height} = {self.cells} cells "
            f"(max_cells {self.max_cells}: {verdict}); {self.positions} positions; "
            f"x {left:.2f}..{right:.2f}, y {bottom:.2f}..{top:.2f} in {name.strip()}; "
            f"from {self.source}"
        )


@dataclass(frozen=True)
class WindowPlan:
    """The windows of one source and the positions that fell off it (indices into the input)."""

    kind: str
    source: str
    reach_m: float
    windows: tuple[PlannedWindow, ...]
    off_raster: tuple[int, ...]

    @property
    def accepted(self) -> bool:
        """True when every window is within the limit."""
        return all(w.accepted for w in self.windows)

    def check(self) -> None:
        """Raise ``FetchError`` naming ``fetch.orbital.max_cells`` if a window is above it."""
        for w in self.windows:
            if not w.accepted:
                raise FetchError(
                    w.source,
                    f"{w.kind} window of {w.width} x {w.height} = {w.cells} cells around one "
                    f"position (reach {self.reach_m:.0f} m) is above {MAX_CELLS_KEY} = "
                    f"{w.max_cells}; raise {MAX_CELLS_KEY} (or lower geometry.radius for the "
                    "DEM, chips.size_m for the ortho, fetch.orbital.margin_m)",
                )


def dem_reach_m(radius_m: float, chip_size_m: float, margin_m: float) -> float:
    """Ground metres the build reads from the DEM around a rover: view radius or chip."""
    return max(radius_m, CHIP_REACH * chip_size_m) + margin_m


def ortho_reach_m(chip_size_m: float, margin_m: float) -> float:
    """Ground metres the build reads from the ortho around a rover: the chip at any heading."""
    return CHIP_REACH * chip_size_m + margin_m


def _scale(crs: CRS, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Largest map scale factor (map units per ground metre) of ``crs`` at lon/lat (degrees)."""
    if crs.is_geographic:
        raise FetchError(crs.name, "the raster CRS is geographic; expected a projected Mars map")
    factors = Proj(crs).get_factors(lon, lat)
    scale = np.maximum(np.asarray(factors.parallel_scale), np.asarray(factors.meridional_scale))
    return np.where(np.isfinite(scale), scale, 1.0)


def position_boxes(
    x: np.ndarray, y: np.ndarray, pos_crs: str, grid: RasterGrid, reach_m: float
) -> np.ndarray:
    """(n, 4) float pixel boxes [col0, row0, col1, row1] of each position grown by the reach.

    ``x``, ``y``: metres in ``pos_crs``; the boxes are in source pixels (unclipped, unsnapped).
    """
    t = grid.transform
    if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
        raise FetchError(grid.crs[:60], f"the raster grid is not north-up: {tuple(t)[:6]}")
    rx, ry = map_to_map(x, y, pos_crs, grid.crs)
    lon, lat = map_to_lonlat(x, y, pos_crs)
    half = reach_m * _scale(CRS.from_user_input(grid.crs), lon, lat)
    pad = PAD_CELLS * max(grid.res)
    inv = ~t
    c0, r0 = inv * (rx - half - pad, ry + half + pad)
    c1, r1 = inv * (rx + half + pad, ry - half - pad)
    return np.column_stack([c0, r0, c1, r1])


def _snap(boxes: np.ndarray, grid: RasterGrid) -> np.ndarray:
    """Integer boxes grown outward to whole pixels and clipped to the raster."""
    out = np.empty(boxes.shape, dtype=np.int64)
    out[:, 0] = np.clip(np.floor(boxes[:, 0]), 0, grid.width)
    out[:, 1] = np.clip(np.floor(boxes[:, 1]), 0, grid.height)
    out[:, 2] = np.clip(np.ceil(boxes[:, 2]), 0, grid.width)
    out[:, 3] = np.clip(np.ceil(boxes[:, 3]), 0, grid.height)
    return out


def _cells(b: np.ndarray) -> np.ndarray:
    return np.asarray((b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1]))


def _union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lo = np.minimum(a[..., :2], b[..., :2])
    return np.concatenate([lo, np.maximum(a[..., 2:], b[..., 2:])], -1)


def _overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w = np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0])
    h = np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1])
    return np.asarray(np.maximum(w, 0) * np.maximum(h, 0))


def cluster_boxes(boxes: np.ndarray, max_cells: int) -> list[tuple[np.ndarray, int]]:
    """Merge integer pixel boxes (in traverse order) into windows; (box, positions) each.

    A window's *need* is the area its positions' boxes cover (tracked as each box's cells less
    its overlap with the box before it, or with the other window when two merge). Two windows
    merge when the bounding box of both is at most ``FILL`` times their joint need and at most
    ``max_cells``: first along the traverse, then pairwise, best fill first.
    """
    runs: list[list[Any]] = []  # [box, need, count, last box]
    for b in boxes:
        if runs:
            cur, need, count, last = runs[-1]
            u = _union(cur, b)
            joint = need + _cells(b) - _overlap(last, b)
            if _cells(u) <= FILL * joint and _cells(u) <= max_cells:
                runs[-1] = [u, joint, count + 1, b]
                continue
        runs.append([b.copy(), _cells(b), 1, b])
    while len(runs) > 1:
        arr = np.stack([r[0] for r in runs])
        need = np.array([r[1] for r in runs], dtype=float)
        u = _union(arr[:, None, :], arr[None, :, :])
        joint = need[:, None] + need[None, :] - _overlap(arr[:, None, :], arr[None, :, :])
        ratio = _cells(u) / np.maximum(joint, 1.0)
        ratio[np.tril_indices(len(runs))] = np.inf
        ratio[_cells(u) > max_cells] = np.inf
        i, j = np.unravel_index(int(np.argmin(ratio)), ratio.shape)
        if ratio[i, j] > FILL:
            break
        runs[i] = [u[i, j], joint[i, j], runs[i][2] + runs[j][2], runs[i][3]]
        del runs[j]
    return [(r[0], int(r[2])) for r in runs]


def plan_windows(
    x: np.ndarray,
    y: np.ndarray,
    pos_crs: str,
    grid: RasterGrid,
    reach_m: float,
    *,
    kind: str,
    source: str,
    max_cells: int = MAX_CELLS,
) -> WindowPlan:
    """The windows of ``grid`` serving positions (``x``, ``y``: metres in ``pos_crs``).

    Positions whose grown box lies wholly off the raster are listed in ``off_raster``; a
    ``FetchError`` is raised when all of them do. Windows are ordered by (row, col).
    """
    boxes = _snap(position_boxes(x, y, pos_crs, grid, reach_m), grid)
    on = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
    off = tuple(int(i) for i in np.flatnonzero(~on))
    if not on.any():
        raise FetchError(
            source, f"all {len(boxes)} rover positions ({pos_crs}) lie off the {kind} raster"
        )
    clusters = cluster_boxes(boxes[on], max_cells)
    clusters.sort(key=lambda c: (int(c[0][1]), int(c[0][0])))
    t = grid.transform
    windows = []
    for (c0, r0, c1, r1), count in clusters:
        left, top = t * (int(c0), int(r0))
        right, bottom = t * (int(c1), int(r1))
        size = (int(c1 - c0), int(r1 - r0))
        box = (left, bottom, right, top)
        windows.append(
            PlannedWindow(kind, source, int(c0), int(r0), *size, box, grid.crs, count, max_cells)
        )
    return WindowPlan(kind, source, reach_m, tuple(windows), off)
