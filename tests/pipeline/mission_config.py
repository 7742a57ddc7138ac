"""A cheap build config over a generated mission (small chips, few rays), for pool tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mission_inputs import mission_inputs

from mars_pairs.pipeline.config import BuildConfig, parse_config


def cheap_config(mission: Path, out: Path, **sections: Any) -> BuildConfig:
    """The mission's inputs, 64 m chips of 64 px, radius 300 m, every 32nd ray; ``sections``
    update the config's sections (e.g. ``output={"shard_size": 1}``)."""
    doc: dict[str, Any] = {
        "inputs": mission_inputs(mission),
        "geometry": {"radius": 300, "ray_stride": 32},
        "chips": {"size_m": 64, "size_px": 64},
        "output": {"dir": str(out)},
        "splits": {"block_m": 100},
    }
    for name, values in sections.items():
        doc[name] = {**doc.get(name, {}), **values}
    return parse_config(doc, mission)
