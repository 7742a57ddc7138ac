"""One orbital terrain map from many images: the votes of every sample's ``terrain_on_map``
merged on the ortho's grid.

Grid: the ortho raster's own (its CRS, transform and pixel size), cut to the window holding
every merged chip (the traverse), pixel edges on the ortho's. Each sample votes once per map
cell: the class of its chip pixel under the cell's centre (map x, y through the chip's
affine), when that chip pixel carries a class (not 255). ``VoteGrid`` counts votes per class
in 256 x 256 tiles, only where some chip reached (a traverse crosses a map diagonally: most of
its bounding box is never seen); ``tile_bands`` gives the three uint8 bands of a tile: 1 the
majority class (the lowest class value wins a tie), 2 the number of votes (images that saw the
cell; capped at 254), 3 the agreement, the majority's share of the votes in percent (0..100).
255 in every band where no image saw the ground (the nodata value). Written as a
Cloud-Optimized GeoTIFF (GDAL's COG driver, DEFLATE, 256 px blocks, overviews by mode,
unseen tiles left sparse) through a temporary name and a rename.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.crs import CRS
from rasterio.windows import Window

from mars_pairs.store.atomic import atomic_path

NODATA = 255
MAX_VOTES = 254
TILE = 256


@dataclass
class VoteGrid:
    """Votes per class value (``classes``, ascending) on a ``height`` x ``width`` window of
    the ortho grid (``transform``: the window's affine, pixel edges, north-up), kept per
    ``TILE`` x ``TILE`` tile: ``tiles[(ti, tj)]`` (K, TILE, TILE) uint8 counts (saturating at
    ``MAX_VOTES``)."""

    classes: tuple[int, ...]
    transform: Affine
    crs: CRS
    height: int
    width: int
    tiles: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)

    @classmethod
    def covering(
        cls, ortho_transform: Affine, crs: CRS, bounds: tuple[float, float, float, float],
        classes: tuple[int, ...],
    ) -> VoteGrid:  # fmt: skip
        """An empty grid on the ortho's pixels covering ``bounds`` (xmin, ymin, xmax, ymax,
        map units); the ortho must be north-up (no rotation terms)."""
        if ortho_transform.b != 0.0 or ortho_transform.d != 0.0:
            raise ValueError("the ortho's transform is rotated: a terrain map needs north-up")
        inv = ~ortho_transform
        ca, ra = inv * (bounds[0], bounds[3])
        cb, rb = inv * (bounds[2], bounds[1])
        c0, r0 = math.floor(min(ca, cb)), math.floor(min(ra, rb))
        width = max(1, math.ceil(max(ca, cb)) - c0)
        height = max(1, math.ceil(max(ra, rb)) - r0)
        transform = ortho_transform * Affine.translation(c0, r0)
        return cls(tuple(classes), transform, crs, height, width)

    def add(self, on_map: np.ndarray, chip_transform: Affine) -> int:
        """Add one sample's votes: ``on_map`` (S, S) uint8 classes on the chip grid of
        ``chip_transform`` (chip pixel edges -> map x, y). Returns the cells it voted in."""
        s = on_map.shape
        labelled = np.nonzero(on_map != NODATA)
        if not len(labelled[0]):
            return 0
        inv_grid = ~self.transform
        # the labelled chip pixels' extent -> the grid cells they can reach
        r_lo, r_hi = labelled[0].min(), labelled[0].max() + 1
        c_lo, c_hi = labelled[1].min(), labelled[1].max() + 1
        corners = [chip_transform * (x, y) for x in (c_lo, c_hi) for y in (r_lo, r_hi)]
        cr = np.array([inv_grid * c for c in corners])
        j0, i0 = (max(int(v), 0) for v in np.floor(cr.min(axis=0)))
        j1, i1 = np.ceil(cr.max(axis=0)).astype(int)
        j1, i1 = min(j1, self.width), min(i1, self.height)
        if j0 >= j1 or i0 >= i1:
            return 0
        ii, jj = np.mgrid[i0:i1, j0:j1]
        t, inv_chip = self.transform, ~chip_transform
        x = t.c + (jj + 0.5) * t.a
        y = t.f + (ii + 0.5) * t.e
        u = np.floor(inv_chip.a * x + inv_chip.b * y + inv_chip.c).astype(np.int64)
        v = np.floor(inv_chip.d * x + inv_chip.e * y + inv_chip.f).astype(np.int64)
        inside = (u >= 0) & (v >= 0) & (u < s[1]) & (v < s[0])
        cls_at = np.full(ii.shape, NODATA, dtype=np.uint8)
        cls_at[inside] = on_map[v[inside], u[inside]]
        voted = 0
        for ti in range(i0 // TILE, (i1 - 1) // TILE + 1):
            for tj in range(j0 // TILE, (j1 - 1) // TILE + 1):
                a0, a1 = max(i0, ti * TILE), min(i1, (ti + 1) * TILE)
                b0, b1 = max(j0, tj * TILE), min(j1, (tj + 1) * TILE)
                part = cls_at[a0 - i0 : a1 - i0, b0 - j0 : b1 - j0]
                if not (part != NODATA).any():
                    continue
                tile = self.tiles.get((ti, tj))
                if tile is None:
                    tile = self.tiles[(ti, tj)] = np.zeros((len(self.classes), TILE, TILE),
                                                           dtype=np.uint8)  # fmt: skip
                view = tile[:, a0 - ti * TILE : a1 - ti * TILE, b0 - tj * TILE : b1 - tj * TILE]
                for n, value in enumerate(self.classes):
                    hit = (part == value) & (view[n] < MAX_VOTES)
                    view[n][hit] += 1
                    voted += int(hit.sum())
        return voted

    def votes(self) -> np.ndarray:
        """Votes per cell over the seen tiles, flattened (for counts)."""
        if not self.tiles:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([t.sum(axis=0, dtype=np.int64).ravel() for t in self.tiles.values()])


def tile_bands(counts: np.ndarray, classes: tuple[int, ...]) -> np.ndarray:
    """(3, H, W) uint8 bands of (K, H, W) vote counts: majority class, votes (capped),
    agreement percent; 255 where unseen."""
    total = counts.sum(axis=0, dtype=np.int64)
    best = counts.argmax(axis=0)
    top = np.take_along_axis(counts, best[None], axis=0)[0].astype(np.int64)
    seen = total > 0
    out = np.full((3, *total.shape), NODATA, dtype=np.uint8)
    out[0][seen] = np.asarray(classes, dtype=np.uint8)[best[seen]]
    out[1][seen] = np.minimum(total[seen], MAX_VOTES).astype(np.uint8)
    out[2][seen] = np.rint(100.0 * top[seen] / total[seen]).astype(np.uint8)
    return out


def write_map(path: Path, grid: VoteGrid, class_names: dict[int, str]) -> Path:
    """Write ``grid``'s bands to ``path`` as a COG (band descriptions and the class table as
    tags); returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = path.with_name(f".{path.name}.stage.tif")
    profile = {
        "driver": "GTiff", "width": grid.width, "height": grid.height, "count": 3,
        "dtype": "uint8", "crs": grid.crs, "transform": grid.transform, "nodata": NODATA,
        "tiled": True, "blockxsize": TILE, "blockysize": TILE, "compress": "deflate",
        "sparse_ok": True,
    }  # fmt: skip
    try:
        with rasterio.open(stage, "w", **profile) as dst:
            for (ti, tj), counts in sorted(grid.tiles.items()):
                h = min(TILE, grid.height - ti * TILE)
                w = min(TILE, grid.width - tj * TILE)
                bands = tile_bands(counts[:, :h, :w], grid.classes)
                dst.write(bands, window=Window(tj * TILE, ti * TILE, w, h))
            for band, text in enumerate(("majority class", "votes", "agreement percent"), 1):
                dst.set_band_description(band, text)
            dst.update_tags(
                TERRAIN_CLASSES=";".join(f"{v}={n}" for v, n in sorted(class_names.items())),
                NODATA_MEANING="no image saw the ground",
            )
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), atomic_path(path) as tmp:
            rasterio.shutil.copy(
                stage, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=TILE,
                RESAMPLING="MODE", SPARSE_OK="TRUE", NUM_THREADS=1,
            )  # fmt: skip
    finally:
        stage.unlink(missing_ok=True)
    return path
