"""The manifest row and meta.json of a sample."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import shapely

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.attitude import image_centre_pointing_deg
from mars_pairs.geometry.places import Pose
from mars_pairs.observation import Observation
from mars_pairs.pipeline.sample.chips import ChipCoverage
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.footprint import footprint_polygon, row_spans, view_statistics
from mars_pairs.pipeline.sample.key import sample_key
from mars_pairs.pipeline.sample.view import View
from mars_pairs.pipeline.splitting import split_rule
from mars_pairs.raster.chips import ChipGrid
from mars_pairs.store.geoparquet import footprint_bounds
from mars_pairs.store.splits import hilbert_index

_MAGIC = re.compile(r"[*?[]")


def labels_root(patterns: Sequence[str]) -> str:
    """The folder the label globs ``patterns`` (absolute) start from: the common folder of
    their leading components without a wildcard. ``label_path`` is relative to it."""
    return _labels_root(tuple(patterns))


@lru_cache(maxsize=16)
def _labels_root(patterns: tuple[str, ...]) -> str:
    """``labels_root`` of a build's patterns, worked out once (every sample asks)."""
    heads = []
    for pattern in patterns:
        parts = Path(pattern).parts
        fixed = []
        for part in parts[:-1]:
            if _MAGIC.search(part):
                break
            fixed.append(part)
        heads.append(str(Path(*fixed)) if fixed else os.sep)
    return os.path.commonpath(heads) if heads else os.sep


def relative_label_path(label: str | Path, patterns: Sequence[str]) -> str:
    """``label`` relative to ``labels_root(patterns)``, with ``/``: the same on every machine
    that holds the labels under one root, and no machine's absolute path in the dataset."""
    return Path(os.path.relpath(str(label), labels_root(patterns))).as_posix()


def manifest_row(
    obs: Observation,
    pose: Pose,
    view: View,
    grid: ChipGrid,
    ctx: SampleContext,
    cover: ChipCoverage,
) -> dict[str, Any]:
    """The manifest row (member locations are added when the shard is written); ``cover``:
    the chips' coverage fractions. ``label_path`` is relative to the labels root
    (``labels_root``); ``rover_point`` and ``chip_box`` are WKB in the dataset CRS.

    ``azimuth_deg``/``elevation_deg``: the ray through the image centre, SITE_FRAME (azimuth
    clockwise from true north, elevation up, degrees), from the camera model and the pose's
    attitude; ``label_azimuth_deg``/``label_elevation_deg``: the label's own derived pointing
    (the camera's, not the centre of a subframe), None when the label has none.
    """
    cfg = ctx.config
    label_path = relative_label_path(obs.label_path, cfg.inputs.labels)
    rover_x, rover_y = (float(v) for v in view.camera.origin_map[:2])
    if pose.quaternion is None:  # MapCamera.from_observation refuses it before this
        raise PlacesError(f"{obs.label_path}: no rover attitude in the label or PLACES table")
    az, el = image_centre_pointing_deg(obs.camera, obs.width, obs.height, pose.quaternion)
    hfov, vfov = obs.hfov_deg, obs.vfov_deg  # the label's; else the camera model's
    if hfov is None or vfov is None:
        model_hfov, model_vfov = obs.camera.fov_deg(obs.width, obs.height)
        hfov = model_hfov if hfov is None else hfov
        vfov = model_vfov if vfov is None else vfov
    spans = row_spans(view.mask)
    footprint = footprint_polygon(view, spans)
    xmin, ymin, xmax, ymax = grid.bounds()
    rule = split_rule(cfg, ctx.crs_wkt, ctx.terrain.bounds, ctx.terrain.res)
    split = rule.assign(rover_x, rover_y)
    hilbert = int(hilbert_index([rover_x], [rover_y], ctx.terrain.bounds)[0])
    return {
        "key": sample_key(obs), "mission": obs.mission, "instrument": obs.instrument,
        "product_id": obs.product_id, "label_path": label_path, "sol": obs.sol,
        "site": obs.rmc.site, "drive": obs.rmc.drive, "pose": obs.rmc.pose,
        "time": obs.start_time, "latitude": pose.latitude, "longitude": pose.longitude,
        "easting": rover_x, "northing": rover_y, "elevation_m": pose.elevation_m,
        "azimuth_deg": az, "elevation_deg": el,
        "label_azimuth_deg": obs.azimuth_deg, "label_elevation_deg": obs.elevation_deg,
        "hfov_deg": hfov, "vfov_deg": vfov,
        "width": obs.width, "height": obs.height, "localization": pose.source,
        "places_pose": pose.pose, "places_match": pose.match,
        "dem_offset_m": view.dem_offset_m,
        **view_statistics(view, spans),
        "footprint": None if footprint is None else shapely.to_wkb(footprint),
        "bbox": footprint_bounds(footprint),
        "rover_point": shapely.to_wkb(shapely.Point(rover_x, rover_y)),
        "chip_box": shapely.to_wkb(shapely.Polygon(grid.corners())),
        "chip_xmin": xmin, "chip_ymin": ymin, "chip_xmax": xmax, "chip_ymax": ymax,
        "chip_rotation_deg": grid.rotation_deg, "split": split, "hilbert": hilbert,
        "ortho_coverage": cover.ortho, "dem_coverage": cover.dem,
    }  # fmt: skip


def sample_meta(
    row: dict[str, Any],
    obs: Observation,
    view: View,
    grid: ChipGrid,
    ctx: SampleContext,
    ground_size: tuple[int, int],
) -> dict[str, Any]:
    """meta.json: the row's plain values plus what a reader needs to use the members."""
    binary = ("footprint", "rover_point", "chip_box", "time")
    meta = {k: v for k, v in row.items() if k not in binary}
    meta.update(
        time=obs.start_time.isoformat() if obs.start_time else None,
        crs=ctx.crs_wkt,
        chip_transform=list(grid.transform)[:6],
        ray_stride=ctx.config.geometry.ray_stride,
        ground_size=list(ground_size),
        observer_height_m=view.height,
        camera_center_map=[float(v) for v in view.camera.center_map],
        camera_model_type=obs.camera.model_type,
        ortho_range=ctx.ortho.value_range().to_dict(),
    )
    return meta
