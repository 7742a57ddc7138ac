"""One observation -> one dataset sample: the stages in order, each one call.

Stages (named in failure rows and timed): label, image, locate, terrain, viewshed, raycast,
chips, encode, and dense when ``output.members`` names optional members.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mars_pairs.errors import MarsPairsError, StageError
from mars_pairs.geometry.mapcam import MapCamera
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.sample.chips import correspondence, cut_chips, localization_fields
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.pipeline.sample.dense import dense_members
from mars_pairs.pipeline.sample.encode import encode_members
from mars_pairs.pipeline.sample.ground import ground_image
from mars_pairs.pipeline.sample.record import manifest_row, sample_meta
from mars_pairs.pipeline.sample.stages import Stages
from mars_pairs.pipeline.sample.view import compute_view


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
        with stage("locate"):
            pose = ctx.places.locate(obs)
            camera = MapCamera.from_observation(obs, pose, ctx.crs_wkt)
        view = compute_view(obs, pose, camera, ctx, stage)
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
                    view, grid, chips, ground, out.members, stride, radius, (ctx.ortho, ctx.dem)
                )
        with stage("encode"):
            row = manifest_row(obs, pose, view, grid, ctx, cover)
            meta = sample_meta(row, obs, view, grid, ctx, ground.size)
            meta["ground_image"] = ground.meta
            if out.members or ctx.config.chips.offset_m is not None:
                meta.update(localization_fields(view, grid), **dense_meta)
            members = encode_members(chips, correspondence(view, grid), meta) | dense
    except (MarsPairsError, ValueError, OSError) as exc:
        raise StageError(stage.name, exc) from exc
    row["ground_member"] = ground.name
    return Sample(row["key"], row, {ground.name: ground.data, **members}, stage.seconds)
