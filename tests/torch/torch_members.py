"""Helpers shared by the torch tests: member suffixes and the manifest's keys."""

from __future__ import annotations

from pathlib import Path

from mars_pairs import Manifest

SUFFIX = {
    "ortho": "ortho.png",
    "dem": "dem.npy",
    "viewshed": "viewshed.png",
    "corr": "corr.npy",
    "meta": "meta.json",
}


def all_keys(root: Path) -> set[str]:
    return set(Manifest.open(root).to_table(columns=["key"]).column("key").to_pylist())
