"""Terrain-label members (``inputs.terrain_labels``): the ground image's classes and the same
classes carried onto the chip grid, with per-class pixel counts for the manifest.

- ``terrain`` (H, W) uint8 on the ground image's pixel grid: the label's class values
  (``mars_pairs.terrain_labels``), 255 where unlabelled, on the rover or past the range mask.
- ``terrain_on_map`` (S, S) uint8 on the chip grid: each visible chip pixel takes the class
  of the image pixel its terrain point projects to (nearest: labels stay labels), through the
  per-pixel correspondence of the ``ground_px`` member (``dense.ground_pixels_of_chip``: the
  viewshed chip, so occluded terrain gets nothing; sampled as
  ``raster.transfer.image_to_chip`` samples it). 255 where no
  ground pixel saw it, where the image pixel has no label, and where the chip pixel's
  terrain point lies farther than the label's range limit from the camera centre (metres in
  the camera model's local frame, with the planet's curvature as the projection has it).
- Manifest columns ``terrain_<class>_px``: the chip pixels of each class in
  ``terrain_on_map``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mars_pairs.geometry.body import MARS_RADIUS_M
from mars_pairs.pipeline.config import TerrainLabelsSpec
from mars_pairs.pipeline.sample.dense import chip_points, project_inside
from mars_pairs.pipeline.sample.encode import png_bytes
from mars_pairs.pipeline.sample.view import View
from mars_pairs.raster.chips import ChipGrid
from mars_pairs.raster.transfer import sample_at
from mars_pairs.terrain_labels import (
    AI4MARS_CLASSES,
    NO_LABEL,
    ClassTable,
    LabelSource,
    TerrainLabel,
    count_columns,
    open_source,
)


def label_table(spec: TerrainLabelsSpec) -> ClassTable:
    """The class table of the labels ``spec`` names."""
    if spec.classes is None:
        return AI4MARS_CLASSES
    return ClassTable(tuple(sorted(spec.classes.items())))


def open_labels(spec: TerrainLabelsSpec) -> LabelSource:
    """The label source ``spec`` names (indexed once per worker)."""
    return open_source(spec.format, spec.root, label_table(spec), spec.max_range_m, spec.test_set)


def carry_to_map(
    label: TerrainLabel,
    view: View,
    grid: ChipGrid,
    visible: np.ndarray,
    dem: np.ndarray,
    max_range_m: float | None,
) -> np.ndarray:
    """(S, S) uint8: ``label.classes`` carried onto the chip (nearest image pixel of each
    visible chip pixel's terrain point, ``dense.project_inside``; what
    ``raster.transfer.image_to_chip`` does through ``ground_px``), ``NO_LABEL`` where not
    seen, and (with ``max_range_m``) where the terrain point lies farther from the camera
    centre (metres, the camera model's local frame). The range is tested before projecting
    (after a cut at 1.5 times it plus 5 map units, horizontally from the camera centre): only
    the chip pixels within it are projected."""
    out = np.full(dem.shape, NO_LABEL, dtype=np.uint8)
    rows, cols = np.nonzero(visible & np.isfinite(dem))
    if not len(rows):
        return out
    camera = view.camera
    points = chip_points(grid, dem, rows, cols)
    if max_range_m is not None:  # a generous cut in map units first (the map's scale is ~1)
        cx, cy = (float(v) for v in camera.center_map[:2])
        reach = 1.5 * max_range_m + 5.0
        near = (points[:, 0] - cx) ** 2 + (points[:, 1] - cy) ** 2 <= reach * reach
        rows, cols, points = rows[near], cols[near], points[near]
    local = camera.local_points(points, MARS_RADIUS_M)
    if max_range_m is not None:
        c = np.asarray(camera.camera.c, dtype=np.float64)
        d = local - c
        near = np.einsum("ij,ij->i", d, d) <= max_range_m * max_range_m
        rows, cols, local = rows[near], cols[near], local[near]
    px, inside = project_inside(camera, local)
    values, ok = sample_at(label.classes, px[:, 0], px[:, 1], nearest=True, fill=NO_LABEL)
    keep = inside & ok
    out[rows[keep], cols[keep]] = values[keep]
    return out


def class_counts(on_map: np.ndarray, table: ClassTable) -> dict[str, int]:
    """The manifest's ``terrain_<class>_px`` columns of a ``terrain_on_map`` raster."""
    hist = np.bincount(on_map.ravel(), minlength=256)
    return {c: int(hist[v]) for c, v in zip(count_columns(table), table.values, strict=True)}


def terrain_members(
    label: TerrainLabel,
    view: View,
    grid: ChipGrid,
    chips: dict[str, Any],
    spec_max_range_m: float | None,
) -> tuple[dict[str, bytes], dict[str, int], dict[str, Any]]:
    """(members ``terrain.png`` and ``terrain_on_map.png``, the count columns, meta entries)
    of one sample. The range limit is the config's ``max_range_m``, else the label's."""
    visible = np.asarray(chips["viewshed"]) > 0
    dem = np.asarray(chips["dem"])
    limit = spec_max_range_m if spec_max_range_m is not None else label.max_range_m
    on_map = carry_to_map(label, view, grid, visible, dem, limit)
    members = {"terrain.png": png_bytes(label.classes), "terrain_on_map.png": png_bytes(on_map)}
    meta = {
        "terrain_labels": {
            "mask": label.mask_path.name,
            "rover_mask": None if label.rover_mask is None else label.rover_mask.name,
            "range_mask": None if label.range_mask is None else label.range_mask.name,
            "max_range_m": limit,
            "classes": {str(v): n for v, n in label.table.names},
            "no_label": NO_LABEL,
        }
    }
    return members, class_counts(on_map, label.table), meta
