"""A plain folder of terrain masks: ``<root>/<product id>.png``, one single-band 8-bit PNG per
ground image on its pixel grid, with the class table given in the config
(``inputs.terrain_labels.classes``: mask value -> class name; 255 is no label) and an
optional range limit (``max_range_m``, metres from the camera: the carry onto the map keeps
nothing farther)."""

from __future__ import annotations

from pathlib import Path

from mars_pairs.errors import TerrainLabelError
from mars_pairs.terrain_labels.classes import ClassTable
from mars_pairs.terrain_labels.masks import TerrainLabel, read_classes


class FolderLabels:
    """Terrain masks named by product id in one folder."""

    format = "folder"

    def __init__(self, root: Path, table: ClassTable, max_range_m: float | None = None) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise TerrainLabelError(f"{self.root}: terrain label folder is not a folder")
        self.table = table
        self.max_range_m = max_range_m
        self.unmatched: list[Path] = []

    def product_ids(self) -> list[str]:
        """Every id a mask names, sorted."""
        return sorted(p.stem for p in self.root.glob("*.png"))

    def read(self, product_id: str, size: tuple[int, int]) -> TerrainLabel:
        """The mask of ``product_id`` for its image of ``size`` (width, height)."""
        path = self.root / f"{product_id}.png"
        if not path.is_file():
            raise TerrainLabelError(f"{path}: no terrain mask for product {product_id}")
        classes = read_classes(path, self.table, size)
        return TerrainLabel(product_id, classes, self.table, path, max_range_m=self.max_range_m)
