"""Footprint and view statistics of a view (map CRS; areas and ranges in true metres)."""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely

from mars_pairs.pipeline.sample.view import View

Spans = tuple[np.ndarray, np.ndarray, np.ndarray]  # row_spans: rows, first and last columns


def row_spans(mask: np.ndarray) -> Spans:
    """The rows of ``mask`` with a set cell, and each one's first and last set column."""
    rows = np.flatnonzero(mask.any(axis=1))
    sub = mask[rows]
    first = np.argmax(sub, axis=1)
    last = sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    return rows, first, last


def footprint_polygon(view: View, spans: Spans | None = None) -> shapely.Polygon | None:
    """Convex hull of the visible cells (their corners) and the camera position, map CRS.
    ``spans``: ``row_spans(view.mask)`` when the caller has it."""
    rows, first, last = row_spans(view.mask) if spans is None else spans
    if len(rows) == 0:
        return None
    cols = np.concatenate([first - 0.5, last + 0.5, first - 0.5, last + 0.5])
    rr = np.concatenate([rows - 0.5, rows - 0.5, rows + 0.5, rows + 0.5])
    x, y = view.window.colrow_to_xy(cols, rr)
    centre = view.camera.center_map
    points = shapely.multipoints(
        np.column_stack([np.append(x, centre[0]), np.append(y, centre[1])])
    )
    assert isinstance(points, shapely.MultiPoint)  # (N, 2) coordinates: one geometry
    hull = shapely.convex_hull(points)
    return hull if isinstance(hull, shapely.Polygon) else hull.buffer(0.5)


def view_statistics(view: View, spans: Spans | None = None) -> dict[str, Any]:
    """Visible cell count, area (true m2) and farthest visible range (m), ray hit fraction.
    ``spans``: ``row_spans(view.mask)`` when the caller has it."""
    visible = int(np.count_nonzero(view.mask))
    cam = view.camera
    # map units -> true metres through the local Jacobian (scale factors, R / (R + h))
    area_scale = 1.0 / abs(float(np.linalg.det(cam.jacobian[:2, :2])))
    cell_area = abs(view.window.transform.a * view.window.transform.e)
    max_range = 0.0
    if visible:
        # map_to_local is affine, so distance from the camera is convex along a row and the
        # farthest visible cell of a row is one of its visible span's two ends: exact
        rows, first, last = row_spans(view.mask) if spans is None else spans
        x, y = view.window.colrow_to_xy(np.concatenate([first, last]), np.tile(rows, 2))
        local = cam.map_to_local(np.column_stack([x, y, np.full_like(x, cam.center_map[2])]))
        centre = cam.map_to_local(cam.center_map)
        max_range = float(np.hypot(local[:, 0] - centre[0], local[:, 1] - centre[1]).max())
    hit_fraction = None
    if view.hits is not None:
        hit_fraction = float(np.isfinite(view.hits[:, 0]).mean())
    return {
        "visible_cells": visible,
        "viewshed_area_m2": float(visible * cell_area * area_scale),
        "max_visible_range_m": max_range,
        "ray_hit_fraction": hit_fraction,
    }
