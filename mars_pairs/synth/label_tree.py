"""Planning inputs at any scale: a tree of empty label files and tiny rasters, no images.

Enough for ``plan_build`` (and a build whose every label fails at the label stage): the
planning benchmark and tests generate 100,000 label paths in seconds with it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mars_pairs.pipeline.config import BuildConfig, parse_config

#: Mars equirectangular (metres), the synthetic missions' CRS.
MARS_EQC = "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"


def write_label_tree(root: Path, count: int, per_dir: int | None = 100) -> str:
    """Write ``count`` empty labels under ``root``: ``per_dir`` per sol folder
    (``sol/00000/ids/ZLF_00000_0000.xml``, the archive's per-sol layout) or all in one folder
    (``per_dir`` None); returns the glob pattern that matches them."""
    if per_dir is None:
        folder = root / "flat"
        folder.mkdir(parents=True, exist_ok=True)
        for i in range(count):
            _touch(folder / f"ZLF_{i:07d}.xml")
        return str(folder / "*.xml")
    for i in range(count):
        sol, j = divmod(i, per_dir)
        folder = root / "sol" / f"{sol:05d}" / "ids"
        if j == 0:
            folder.mkdir(parents=True, exist_ok=True)
        _touch(folder / f"ZLF_{sol:05d}_{j:04d}.xml")
    return str(root / "sol" / "*" / "ids" / "*.xml")


def plan_config(
    root: Path, labels: str | list[str], out: Path, shard_size: int = 64
) -> BuildConfig:
    """A build config over ``labels`` (glob patterns) with an 8 x 8 DEM and ortho at 1 m and
    an empty PLACES table written under ``root``; the dataset goes to ``out``."""
    import rasterio
    from rasterio.transform import from_origin

    root.mkdir(parents=True, exist_ok=True)
    profile = {
        "driver": "GTiff",
        "width": 8,
        "height": 8,
        "count": 1,
        "dtype": "float32",
        "crs": MARS_EQC,
        "transform": from_origin(0.0, 8.0, 1.0, 1.0),
    }
    for name in ("dem", "ortho"):
        with rasterio.open(root / f"{name}.tif", "w", **profile) as dst:
            dst.write(np.zeros((1, 8, 8), np.float32))
    (root / "places.csv").write_text("")
    doc = {
        "inputs": {
            "labels": labels,
            "places": str(root / "places.csv"),
            "dem": str(root / "dem.tif"),
            "ortho": str(root / "ortho.tif"),
        },
        "output": {"dir": str(out), "shard_size": shard_size},
    }
    return parse_config(doc, root)


def _touch(path: Path) -> None:
    os.close(os.open(path, os.O_CREAT | os.O_WRONLY, 0o644))
