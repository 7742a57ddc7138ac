"""The catalogue's checks on a built demo: every label in catalog.parquet or failures.parquet;
each footprint against the dataset's viewshed chip of the same image (IoU over the chip's
extent); ``Catalog.saw`` against the ``mars-pairs viewshed --label`` GeoTIFF of every image
(written by the command's own function, read back with rasterio) at random points.

usage: python benchmarks/check_catalog_demo.py CONFIG CATALOG_DIR DATASET_DIR [POINTS]
"""

from __future__ import annotations

import argparse
import glob
import io
import json
import os
import sys
import tarfile
import tempfile
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import rasterio
import shapely
from affine import Affine
from PIL import Image
from rasterio import features

from mars_pairs.cli.viewshed import label_viewshed
from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.pipeline.config import load_config
from mars_pairs.raster.terrain import Terrain
from mars_pairs.store.catalog import Catalog


def chip_ious(catalog: Catalog, dataset: Path) -> dict[str, tuple[float, int]]:
    """key -> (IoU of the footprint rasterized on the chip grid and the viewshed chip, the
    chip's pixels in view)."""
    geoms = dict(zip(catalog.table["key"].to_pylist(), catalog.geometry, strict=True))
    out: dict[str, tuple[float, int]] = {}
    for shard in sorted((dataset / "shards").glob("*.tar")):
        with tarfile.open(shard) as tar:
            members = {m.name: m for m in tar.getmembers()}
            for name in members:
                if not name.endswith(".meta.json"):
                    continue
                key = name[: -len(".meta.json")]
                meta = json.loads(tar.extractfile(members[name]).read())  # type: ignore[union-attr]
                chip = (
                    np.asarray(
                        Image.open(
                            io.BytesIO(tar.extractfile(members[f"{key}.viewshed.png"]).read())
                        )
                    )
                    > 0
                )  # type: ignore[union-attr]
                transform = Affine(*meta["chip_transform"])
                geom = geoms.get(key)
                mine = np.zeros_like(chip)
                if geom is not None:
                    mine = features.rasterize([geom], out_shape=chip.shape, transform=transform) > 0
                union = (mine | chip).sum()
                iou = 1.0 if union == 0 else float((mine & chip).sum() / union)
                out[key] = (iou, int(chip.sum()))
    return out


def saw_agreement(
    config_path: Path, catalog: Catalog, n_points: int, seed: int = 0
) -> dict[str, float]:
    config = load_config(config_path)
    labels = sorted(glob.glob(config.inputs.labels[0]))
    keys = catalog.table["key"].to_pylist()
    rasters = {}
    tmp = Path(tempfile.mkdtemp(prefix="saw-check-"))
    with Terrain.open(config.inputs.dem) as terrain:
        by_product = {Path(p).stem.lower(): p for p in labels}
        for key, label_rel in zip(keys, catalog.table["label_path"].to_pylist(), strict=True):
            label = next(p for p in labels if p.endswith(label_rel))
            out = tmp / f"{key}.tif"
            args = argparse.Namespace(
                label=label,
                places=str(config.inputs.places),
                radius=config.geometry.radius,
                height=config.geometry.observer_height,
                mask=config.geometry.view_mask,
                out=str(out),
            )
            with redirect_stdout(io.StringIO()):
                label_viewshed(args, terrain)
            with rasterio.open(out) as src:
                rasters[key] = (src.read(1), src.transform, src.res[0])
        del by_product
    rng = np.random.default_rng(seed)
    valid = [g for g in catalog.geometry if g is not None]
    xmin, ymin, xmax, ymax = shapely.total_bounds(np.array(valid, dtype=object))
    # n_points uniform over the footprints' box, n_points more inside random footprints
    pts = [(rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)) for _ in range(n_points)]
    while len(pts) < 2 * n_points:
        g = valid[rng.integers(len(valid))]
        x0, y0, x1, y1 = g.bounds
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if g.contains(shapely.Point(x, y)):
            pts.append((x, y))
    xs, ys = np.array(pts).T
    lons, lats = map_to_lonlat(xs, ys, json.dumps(catalog.crs))
    agree = np.zeros(2 * n_points, dtype=bool)
    within_cell = np.zeros(2 * n_points, dtype=bool)
    cell_agree = np.zeros(2 * n_points, dtype=bool)
    cell_extra = cell_missed = 0
    cell_worst = 0.0  # cells from a returned image's visible cell, over per_cell's extras
    seen = np.zeros(2 * n_points, dtype=bool)
    worst_extra = worst_missed = 0.0
    for i, (x, y, lon, lat) in enumerate(zip(xs, ys, lons, lats, strict=True)):
        got = set(catalog.saw(float(lon), float(lat))["key"].to_pylist())
        cell_got = set(catalog.saw(float(lon), float(lat), per_cell=True)["key"].to_pylist())
        truth = set()
        for key, (codes, transform, _cell) in rasters.items():
            col, row = ~transform * (x, y)
            r, c = int(np.floor(row)), int(np.floor(col))
            if 0 <= r < codes.shape[0] and 0 <= c < codes.shape[1] and codes[r, c] == 1:
                truth.add(key)
        agree[i] = got == truth
        cell_agree[i] = cell_got == truth
        cell_extra += len(cell_got - truth)
        cell_missed += len(truth - cell_got)
        for key in cell_got - truth:
            cell_worst = max(cell_worst, _cells_to(rasters[key], x, y, visible=True))
        seen[i] = bool(truth or got)
        near = True
        for key in got ^ truth:  # the distance (cells) to the raster's nearest other verdict
            d = _cells_to(rasters[key], x, y, visible=key in got)
            near &= d <= 1.0
            if key in got:
                worst_extra = max(worst_extra, d)
            else:
                worst_missed = max(worst_missed, d)
        within_cell[i] = near
    uni, ins = slice(0, n_points), slice(n_points, 2 * n_points)
    return {
        "uniform_points": n_points,
        "uniform_seen": int(seen[uni].sum()),
        "uniform_agree": float(agree[uni].mean()),
        "uniform_seen_agree": float(agree[uni][seen[uni]].mean()),
        "inside_points": n_points,
        "inside_agree": float(agree[ins].mean()),
        "agree_up_to_one_cell": float(within_cell.mean()),
        "per_cell_uniform_agree": float(cell_agree[uni].mean()),
        "per_cell_inside_agree": float(cell_agree[ins].mean()),
        "per_cell_extra_images": cell_extra,
        "per_cell_missed_images": cell_missed,
        "per_cell_worst_extra_cells": cell_worst,
        "worst_extra_cells": worst_extra,
        "worst_missed_cells": worst_missed,
    }


def _cells_to(raster: tuple[np.ndarray, Affine, float], x: float, y: float, visible: bool) -> float:
    """Cells (Chebyshev, from the cell's edge) from map point (x, y) to the nearest cell of
    the raster marked visible (``visible``) or not; inf when there is none."""
    codes, transform, _ = raster
    col, row = ~transform * (x, y)
    rr, cc = np.nonzero(codes == 1) if visible else np.nonzero(codes != 1)
    if not len(rr):
        return float(np.inf)
    return float(np.min(np.maximum(np.abs(cc + 0.5 - col), np.abs(rr + 0.5 - row)) - 0.5))


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("config")
    parser.add_argument("catalog")
    parser.add_argument("dataset")
    parser.add_argument("points", type=int, nargs="?", default=1000)
    a = parser.parse_args()
    catalog = Catalog.open(a.catalog)
    config = load_config(a.config)
    labels = sorted(glob.glob(config.inputs.labels[0]))
    print(f"load average {os.getloadavg()[0]:.2f}")
    failures = pq.read_table(Path(a.catalog) / "failures.parquet")
    print(
        f"labels {len(labels)}; catalog rows {len(catalog)}; failure rows {failures.num_rows}; "
        f"all accounted: {len(labels) == len(catalog) + failures.num_rows}"
    )
    ious = chip_ious(catalog, Path(a.dataset))
    v = np.array([iou for iou, _ in ious.values()])
    big = np.array([iou for iou, pixels in ious.values() if pixels >= 37])
    print(
        f"chip IoU over {len(v)} images: min {v.min():.4f}, median {np.median(v):.4f}, "
        f"below 0.95: {int((v < 0.95).sum())}; over the {len(big)} with >= 37 chip pixels in "
        f"view: min {big.min():.4f}"
    )
    for name, value in saw_agreement(Path(a.config), catalog, a.points).items():
        print(f"saw {name}: {value:.4f}" if isinstance(value, float) else f"saw {name}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
