"""Terrain labels of ground images (class masks on the image's pixel grid), read by product
id from the AI4Mars layout (``ai4mars``) or a plain folder (``folder``); ``open_source``
opens the one a build config names."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from mars_pairs.terrain_labels.ai4mars import AI4MarsLabels
from mars_pairs.terrain_labels.classes import (
    AI4MARS_CLASSES,
    NO_LABEL,
    ClassTable,
    count_columns,
)
from mars_pairs.terrain_labels.folder import FolderLabels
from mars_pairs.terrain_labels.masks import TerrainLabel

FORMATS = ("ai4mars", "folder")


class LabelSource(Protocol):
    """What a build reads terrain labels through."""

    format: str
    table: ClassTable
    unmatched: list[Path]

    def product_ids(self) -> list[str]: ...

    def read(self, product_id: str, size: tuple[int, int]) -> TerrainLabel: ...


def open_source(
    format: str,
    root: Path,
    table: ClassTable | None = None,
    max_range_m: float | None = None,
    test_set: str | None = None,
) -> LabelSource:
    """The label source of ``format`` under ``root`` (``folder`` needs ``table``)."""
    if format == "ai4mars":
        return AI4MarsLabels(root) if test_set is None else AI4MarsLabels(root, test_set)
    if format == "folder":
        return FolderLabels(root, table or AI4MARS_CLASSES, max_range_m)
    raise ValueError(f"terrain label format must be one of {FORMATS}, got {format!r}")


__all__ = [
    "AI4MARS_CLASSES", "FORMATS", "NO_LABEL", "AI4MarsLabels", "ClassTable", "FolderLabels",
    "LabelSource", "TerrainLabel", "count_columns", "open_source",
]  # fmt: skip
