"""One orbital terrain map from many images: the votes of every sample's ``terrain_on_map``
merged on the ortho's grid.

Grid: the ortho raster's own (its CRS, transform and pixel size), cut to the window holding
every merged chip (the traverse), pixel edges on the ortho's. Each sample votes once per map
cell: the class of its chip pixel nearest the cell's centre (map x, y through the chip's
affine), when that chip pixel carries a class (not 255). ``VoteGrid`` counts votes per class;
``bands`` gives the three uint8 bands of the map: 1 the majority class (the lowest class value
wins a tie), 2 the number of votes (images that saw the cell; capped at 254), 3 the agreement,
the majority's share of the votes in percent (0..100). 255 in every band where no image saw
the ground (the nodata value). Written as a Cloud-Optimized GeoTIFF (GDAL's COG driver,
DEFLATE, 256 px blocks, with overviews by mode) through a temporary name and a rename.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.crs import CRS

from mars_pairs.store.atomic import atomic_path

NODATA = 255
MAX_VOTES = 254


@dataclass
class VoteGrid:
    """Votes per class value (``classes``, ascending) on a window of the ortho grid:
    ``counts`` (K, H, W) uint16; ``transform`` the window's affine (pixel edges)."""

    classes: tuple[int, ...]
    counts: np.ndarray
    transform: Affine
    crs: CRS

    @classmethod
    def covering(
        cls, ortho_transform: Affine, crs: CRS, bounds: tuple[float, float, float, float],
        classes: tuple[int, ...],
    ) -> VoteGrid:  # fmt: skip
        """An empty grid on the ortho's pixels covering ``bounds`` (xmin, ymin, xmax, ymax,
        map units) (the ortho is north-up: no rotation terms)."""
        inv = ~ortho_transform
        ca, ra = inv * (bounds[0], bounds[3])
        cb, rb = inv * (bounds[2], bounds[1])
        c0, r0 = math.floor(min(ca, cb)), math.floor(min(ra, rb))
        width = max(1, math.ceil(max(ca, cb)) - c0)
        height = max(1, math.ceil(max(ra, rb)) - r0)
        transform = ortho_transform * Affine.translation(c0, r0)
        counts = np.zeros((len(classes), height, width), dtype=np.uint16)
        return cls(tuple(classes), counts, transform, crs)

    def add(self, on_map: np.ndarray, chip_transform: Affine) -> int:
        """Add one sample's votes: ``on_map`` (S, S) uint8 classes on the chip grid of
        ``chip_transform`` (chip pixel edges -> map x, y). Returns the cells it voted in."""
        k, h, w = self.counts.shape
        inv_chip = ~chip_transform
        # the chip's corners -> the grid cells it can reach
        s = on_map.shape
        corners = [chip_transform * (x, y) for x in (0, s[1]) for y in (0, s[0])]
        inv_grid = ~self.transform
        cr = np.array([inv_grid * c for c in corners])
        j0, i0 = np.floor(cr.min(axis=0)).astype(int)
        j1, i1 = np.ceil(cr.max(axis=0)).astype(int)
        j0, i0, j1, i1 = max(j0, 0), max(i0, 0), min(j1, w), min(i1, h)
        if j0 >= j1 or i0 >= i1:
            return 0
        ii, jj = np.mgrid[i0:i1, j0:j1]
        t = self.transform
        x = t.c + (jj + 0.5) * t.a
        y = t.f + (ii + 0.5) * t.e
        u = inv_chip.a * x + inv_chip.b * y + inv_chip.c  # chip column (pixel edges)
        v = inv_chip.d * x + inv_chip.e * y + inv_chip.f
        inside = (u >= 0) & (v >= 0) & (u < s[1]) & (v < s[0])
        cls_at = np.full(ii.shape, NODATA, dtype=np.uint8)
        cls_at[inside] = on_map[v[inside].astype(int), u[inside].astype(int)]
        voted = 0
        for n, value in enumerate(self.classes):
            hit = cls_at == value
            self.counts[n, i0:i1, j0:j1] += hit.astype(np.uint16)
            voted += int(hit.sum())
        return voted

    def bands(self) -> np.ndarray:
        """(3, H, W) uint8: majority class, votes (capped), agreement percent; 255 unseen."""
        total = self.counts.sum(axis=0, dtype=np.int64)
        best = self.counts.argmax(axis=0)
        top = np.take_along_axis(self.counts, best[None], axis=0)[0].astype(np.int64)
        seen = total > 0
        out = np.full((3, *total.shape), NODATA, dtype=np.uint8)
        out[0][seen] = np.asarray(self.classes, dtype=np.uint8)[best[seen]]
        out[1][seen] = np.minimum(total[seen], MAX_VOTES).astype(np.uint8)
        out[2][seen] = np.rint(100.0 * top[seen] / total[seen]).astype(np.uint8)
        return out


def write_map(path: Path, grid: VoteGrid, class_names: dict[int, str]) -> Path:
    """Write ``grid``'s bands to ``path`` as a COG (band descriptions and the class table as
    tags); returns ``path``."""
    data = grid.bands()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = path.with_name(f".{path.name}.stage.tif")
    profile = {
        "driver": "GTiff", "width": data.shape[2], "height": data.shape[1], "count": 3,
        "dtype": "uint8", "crs": grid.crs, "transform": grid.transform, "nodata": NODATA,
        "tiled": True, "blockxsize": 256, "blockysize": 256, "compress": "deflate",
    }  # fmt: skip
    try:
        with rasterio.open(stage, "w", **profile) as dst:
            dst.write(data)
            for band, text in enumerate(("majority class", "votes", "agreement percent"), 1):
                dst.set_band_description(band, text)
            dst.update_tags(
                TERRAIN_CLASSES=";".join(f"{v}={n}" for v, n in sorted(class_names.items())),
                NODATA_MEANING="no image saw the ground",
            )
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), atomic_path(path) as tmp:
            rasterio.shutil.copy(
                stage, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=256,
                RESAMPLING="MODE", NUM_THREADS=1,
            )  # fmt: skip
    finally:
        stage.unlink(missing_ok=True)
    return path
