"""One observation -> one dataset sample: the stages in order, each one call.

Stages (named in failure rows and timed): label, image, terrain_labels (with
``inputs.terrain_labels``), locate, terrain, viewshed, raycast, chips, dense when
``output.members`` names optional members, terrain_on_map (with terrain labels), encode.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError, MarsPairsError, StageError
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.geometry.places import Pose
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.sample.chips import correspondence, cut_chips, localization_fields
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.dense import dense_members
from mars_pairs.pipeline.sample.encode import encode_members
from mars_pairs.pipeline.sample.ground import ground_image
from mars_pairs.pipeline.sample.record import manifest_row, sample_meta
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.terrain import terrain_members
from mars_pairs.pipeline.sample.view import (
    View,
    anchor_view,
    line_of_sight,
    ray_grid_shape,
    ray_hits,
    sight_of_hits,
    strided_rays,
)


@dataclass
class Sample:
    """A built sample: its manifest row (without member locations), member bytes, timings."""

    key: str
    row: dict[str, Any]
    members: dict[str, bytes] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


def build_sample(label: Path, ctx: SampleContext) -> Sample:
    """Run every stage for one label; raises StageError naming the failing stage."""
    stage = Stages()
    try:
        with stage("label"):
            obs = read_observation(label)
        with stage("image"):  # decoded and checked; obs re-expressed for a resized image
            keep = "ground_on_map" in ctx.config.output.members
            ground = ground_image(obs, ctx.config.output.image_encoding, keep_pixels=keep)
            obs = ground.observation
        classes = None
        if ctx.terrain_labels is not None:
            with stage("terrain_labels"):  # the mask for this product, checked against its image
                classes = ctx.terrain_labels.read(obs.product_id, ground.size)
        with stage("locate"):
            pose = ctx.places.locate(obs)
            camera = MapCamera.from_observation(obs, pose, ctx.crs_wkt)
        view = view_stages(pose, camera, ctx, stage)
        with stage("chips"):
            grid, chips, cover = cut_chips(view, ctx, obs)
        out = ctx.config.output
        dense: dict[str, bytes] = {}
        dense_meta: dict[str, Any] = {}
        if out.members:
            with stage("dense"):
                stride = out.dense_stride or ctx.config.geometry.ray_stride
                radius = ctx.config.geometry.radius
                dense, dense_meta = dense_members(
                    view, grid, chips, ground, out.members, stride, radius, ctx.ortho
                )
        terrain: dict[str, bytes] = {}
        counts: dict[str, int] = {}
        if classes is not None:
            with stage("terrain_on_map"):
                spec = ctx.config.inputs.terrain_labels
                limit = None if spec is None else spec.max_range_m
                terrain, counts, terrain_meta = terrain_members(classes, view, grid, chips, limit)
                dense_meta = dense_meta | terrain_meta
        with stage("encode"):
            row = manifest_row(obs, pose, view, grid, ctx, cover) | counts
            meta = sample_meta(row, obs, view, grid, ctx, ground.size)
            meta["ground_image"] = ground.meta
            if out.members or ctx.config.chips.offset_m is not None:
                meta.update(localization_fields(view, grid))
            meta.update(dense_meta)
            members = encode_members(chips, correspondence(view, grid), meta) | dense | terrain
    except (MarsPairsError, ValueError, OSError) as exc:
        raise StageError(stage.name, exc) from exc
    row["ground_member"] = ground.name
    return Sample(row["key"], row, {ground.name: ground.data, **members}, stage.seconds)


def view_stages(pose: Pose, camera: MapCamera, ctx: SampleContext, stage: Stages) -> View:
    """The view's stages in order, each timed by ``stage``: terrain (``camera``, in the DEM's
    CRS, anchored on the DEM and the DEM window read), viewshed (line of sight, for
    ``geometry.viewshed`` wedge or both) and raycast (the strided pixels' ray hits, for raycast
    or both; with raycast alone the cells the hits land in are the sight)."""
    geo = ctx.config.geometry
    with stage("terrain"):
        anchored = anchor_view(
            camera, pose, ctx.terrain, ctx.dem_window, geo.radius, geo.observer_height,
            geo.view_mask,
        )  # fmt: skip
    sight, hits, rays = None, None, None
    if geo.viewshed in ("wedge", "both"):
        with stage("viewshed"):
            sight = line_of_sight(anchored, max(ctx.terrain.res))
    if geo.viewshed in ("raycast", "both"):
        with stage("raycast"):
            rays = strided_rays(anchored.camera, geo.ray_stride)
            hits = ray_hits(anchored, geo.ray_stride, rays)
            if sight is None:
                sight = sight_of_hits(hits, anchored.window)
    if sight is None:
        raise ConfigError(f"geometry.viewshed: unknown method {geo.viewshed!r}")
    shape = ray_grid_shape(anchored.camera, geo.ray_stride)
    return View.seeing(anchored, sight, hits, shape, rays)
