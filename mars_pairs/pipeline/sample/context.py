"""What the observations of a build share, opened once per worker process."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mars_pairs.geometry.places import Places
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.raster.chips import ChipGrid, ChipReader
from mars_pairs.raster.terrain import DemWindow, Terrain

if TYPE_CHECKING:
    from mars_pairs.terrain_labels import LabelSource


@dataclass
class SampleContext:
    """What the observations of a build share, opened once per worker process."""

    config: BuildConfig
    places: Places
    terrain: Terrain
    ortho: ChipReader
    dem: ChipReader
    crs_wkt: str = ""
    terrain_labels: LabelSource | None = None  # inputs.terrain_labels, indexed once
    _window: DemWindow | None = None
    _window_key: tuple[int, int, float] | None = None
    _chips: tuple[ChipGrid, np.ndarray, np.ndarray] | None = None

    @classmethod
    def open(cls, config: BuildConfig) -> SampleContext:
        """Open the PLACES table and the rasters named by ``config``."""
        places = Places.from_csv(config.inputs.places)
        labels = None
        if config.inputs.terrain_labels is not None:
            from mars_pairs.pipeline.sample.terrain import open_labels

            labels = open_labels(config.inputs.terrain_labels)
        terrain = Terrain.open(config.inputs.dem)
        return cls(
            config,
            places,
            terrain,
            ChipReader(config.inputs.ortho),
            ChipReader(config.inputs.dem, terrain.dem_dataset),  # the DEM's blocks read once
            terrain.crs.to_wkt(),
            labels,
        )

    def dem_window(self, x: float, y: float, radius: float, snap: float = 32.0) -> DemWindow:
        """A DEM window holding everything within ``radius`` of map point (x, y).

        The window is centred on (x, y) snapped to a ``snap``-unit grid and reaches ``snap``
        further, so the images of one stop share one read, and a sample never depends on
        which images a worker built before it (same window for the same position).
        """
        key = (round(x / snap), round(y / snap), radius)
        if self._window is None or key != self._window_key:
            x0, y0 = key[0] * snap, key[1] * snap
            self._window = self.terrain.read_dem_window(x0, y0, radius + snap, check_observer=False)
            self._window_key = key
        return self._window

    def chip_values(self, grid: ChipGrid) -> tuple[np.ndarray, np.ndarray]:
        """The ortho's and the DEM's values on ``grid`` (``ChipReader.read``: float32, NaN
        where no data), read-only: the last grid's are kept, so the images of one stop (one
        rover position, one chip grid) share one read of each raster."""
        if self._chips is None or self._chips[0] != grid:
            ortho, dem = self.ortho.read(grid), self.dem.read(grid)
            ortho.flags.writeable = False
            dem.flags.writeable = False
            self._chips = (grid, ortho, dem)
        return self._chips[1], self._chips[2]

    def close(self) -> None:
        """Close the rasters."""
        self.terrain.close()
        self.ortho.close()
        self.dem.close()
