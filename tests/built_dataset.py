"""A small dataset built from a generated mission, for the tests of a finished folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mission_inputs import mission_inputs

from mars_pairs.pipeline.build.run import run_build
from mars_pairs.pipeline.config import parse_config


def build_config(mission: Path, out: Path, **sections: Any) -> dict[str, Any]:
    """The config of a cheap build of ``mission`` into ``out`` (2 samples a shard);
    ``sections`` are merged into its sections."""
    doc: dict[str, Any] = {
        "inputs": mission_inputs(mission),
        "geometry": {"radius": 300, "ray_stride": 32},
        "chips": {"size_m": 64, "size_px": 32},
        "output": {"dir": str(out), "shard_size": 2},
        "splits": {"block_m": 100},
    }
    for name, values in sections.items():
        doc[name] = {**doc.get(name, {}), **values}
    return doc


def build_small(mission: Path, out: Path, resume: bool = False, **sections: Any) -> Path:
    """Build ``mission`` into ``out`` (one worker, no failure expected); returns ``out``."""
    config = parse_config(build_config(mission, out, **sections), base=mission)
    summary = run_build(config, workers=1, progress=False, resume=resume)
    assert summary.failures == 0
    return out
