"""Synthetic missions generated once per session, keyed by their parameters.

``MissionCache(base)(seed=..., stops=..., ...)`` generates ``synth.generate_mission`` into a
folder under ``base`` the first time a parameter set is asked for and returns the same folder
after; tests read these folders and never write into them. A test that changes a mission (adds a
label, edits a raster) takes ``copy(dest, **params)``: its own copy of the cached one.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from mars_pairs.synth import generate_mission

DEFAULTS: dict[str, Any] = {"mission": "m2020", "size": "small"}


class MissionCache:
    """Generated missions under ``base``, one folder per parameter set."""

    def __init__(self, base: Path) -> None:
        self.base = base
        self._made: dict[tuple[tuple[str, Any], ...], Path] = {}

    def __call__(self, *, seed: int, stops: int, images_per_stop: int, **params: Any) -> Path:
        """The mission of these ``generate_mission`` parameters (``mission="m2020"``,
        ``size="small"`` unless given), generated on first use. Read only."""
        full = {**DEFAULTS, **params, "seed": seed, "stops": stops,
                "images_per_stop": images_per_stop}  # fmt: skip
        key = tuple(sorted(full.items()))
        if key not in self._made:
            root = self.base / "-".join(f"{k}{v}" for k, v in key)
            generate_mission(root, **full)
            self._made[key] = root
        return self._made[key]

    def copy(self, dest: Path, **params: Any) -> Path:
        """A private copy at ``dest`` of the mission of ``params`` (for tests that change it)."""
        shutil.copytree(self(**params), dest)
        return dest
