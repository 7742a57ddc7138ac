"""The build's split rule and the splits section of dataset.json (map units of the DEM CRS)."""

from __future__ import annotations

import math
import warnings
from collections import Counter
from collections.abc import Sequence
from typing import Any

import pyarrow as pa

from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store.leakage import leak_report, rounded
from mars_pairs.store.splits import (
    BUFFER,
    EmptySplitWarning,
    SplitRule,
    empty_split_warnings,
    make_rule,
    map_scale_bound,
)


def split_rule(
    cfg: BuildConfig, crs_wkt: str, bounds: Sequence[float], res: Sequence[float]
) -> SplitRule:
    """The build's split rule: the config's splits, chip size and view radius, and the DEM's
    map scale over its ``bounds`` (W, S, E, N) and cell size ``res`` (x, y), map units."""
    box = (float(bounds[0]), float(bounds[1]), float(bounds[2]), float(bounds[3]))
    scale = map_scale_bound(crs_wkt, box)
    cell = math.hypot(float(res[0]), float(res[1]))
    return make_rule(cfg.splits, cfg.chips.size_m, cfg.geometry.radius, scale, cell)


def splits_report(config: BuildConfig, manifest: pa.Table, dropped: int) -> dict[str, Any]:
    """:func:`splits_section` of the manifest table ``manifest``."""
    counts = dict(Counter(manifest["split"].to_pylist()))
    return splits_section(config, counts, leak_report(manifest, config.chips.size_m), dropped)


def splits_section(
    config: BuildConfig, by_split: dict[str, int], leak: dict[str, Any], dropped: int
) -> dict[str, Any]:
    """The split rule's buffer and reach, the buffer's count (``by_split``: the manifest's
    samples a split, and ``dropped`` in the buffer), the measured leak check ``leak``
    (``store.leakage.leak_report``) and ``warnings``: a sentence per configured split left
    empty (each also an EmptySplitWarning, see ``store.splits.empty_split_warnings``)."""
    from mars_pairs.raster.vsi import open_raster

    with open_raster(config.inputs.dem) as src:
        rule = split_rule(config, src.crs.to_wkt(), tuple(src.bounds), src.res)
    in_buffer = int(by_split.get(BUFFER, 0))
    cfg = config.splits
    empty = empty_split_warnings(cfg.style, cfg.ratios, cfg.areas, cfg.block_m, dict(by_split))
    for text in empty:
        warnings.warn(f"{config.output.dir}: {text}", EmptySplitWarning, stacklevel=2)
    return {
        "style": config.splits.style,
        "guard": config.splits.guard,
        "buffer_m": rule.buffer_m,
        "reach_m": rounded(rule.reach),
        "guaranteed": rule.guaranteed,
        "buffer_policy": config.splits.buffer_policy,
        "in_buffer": in_buffer + dropped,
        "dropped_in_buffer": dropped,
        **leak,
        "warnings": empty,
    }
