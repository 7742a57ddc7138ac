"""Datasets built from a generated mission with ``support.configs``'s builder, for the tests of
a finished folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mars_pairs.pipeline.build.run import run_build
from support.configs import build_config

# the small build of the store and CLI tests: 64 m chips of 32 px, 2 samples a shard
SMALL: dict[str, dict[str, Any]] = {"chips": {"size_px": 32}, "output": {"shard_size": 2}}


def build(mission: Path, out: Path, *, resume: bool = False, **overrides: Any) -> Path:
    """Build ``mission`` into ``out`` with one worker (``overrides`` as for
    ``support.configs.config_doc``); asserts no failure row; returns ``out``."""
    config = build_config(mission, out, **overrides)
    summary = run_build(config, workers=1, progress=False, resume=resume)
    assert summary.failures == 0
    return out


def small_sections(**sections: dict[str, Any] | None) -> dict[str, Any]:
    """``SMALL`` updated by ``sections`` (key by key), as keyword overrides."""
    merged: dict[str, Any] = {k: dict(v) for k, v in SMALL.items()}
    for name, values in sections.items():
        merged[name] = None if values is None else {**merged.get(name, {}), **values}
    return merged


def build_small(mission: Path, out: Path, resume: bool = False, **sections: Any) -> Path:
    """The small build (``SMALL``, updated by ``sections``) of ``mission`` into ``out``."""
    return build(mission, out, resume=resume, **small_sections(**sections))
