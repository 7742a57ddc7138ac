"""Accuracy of a built dataset against independent truth (no mars_pairs geometry code).

    python benchmarks/geometry_truth.py out/demo/dataset [--stride 8] [--radius 1000]

For every sample: the fraction of its visible chip pixels that project inside its image, and
the distance between each strided pixel's ``corr`` point and the ray hit computed by
``tests/independent_truth.py`` (label fields, numpy + pyproj, a sphere ENU frame at the rover,
a ray march on the bilinear DEM). Inputs (PLACES, DEM) come from the dataset's dataset.json.
Prints a table and the summary the README quotes.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import independent_truth as truth  # noqa: E402


def _member(root: Path, row: dict, field: str) -> bytes:
    with open(root / row[f"{field}_shard"], "rb") as fh:
        fh.seek(row[f"{field}_offset"])
        return fh.read(row[f"{field}_size"])


def _chip_to_map(meta: dict, col: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c, d, e, f = meta["chip_transform"]
    return a * col + b * row + c, d * col + e * row + f


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path)
    p.add_argument("--step", type=float, default=0.25, help="ray march step, metres")
    args = p.parse_args()
    info = json.loads((args.dataset / "dataset.json").read_text())
    inputs, geometry = info["config"]["inputs"], info["config"]["geometry"]
    places, dem = inputs["places"], truth.Dem.open(inputs["dem"])
    fractions, errors = [], []
    print(f"{'key':<60} {'visible px':>10} {'inside':>7} {'corr med m':>10} {'p95 m':>7}")
    for row in pq.read_table(args.dataset / "manifest.parquet").to_pylist():
        meta = json.loads(_member(args.dataset, row, "meta"))
        vis = np.asarray(Image.open(io.BytesIO(_member(args.dataset, row, "viewshed")))) == 255
        corr = np.load(io.BytesIO(_member(args.dataset, row, "corr"))).reshape(-1, 2)
        label = Path(row["label_path"])
        rows, cols = np.nonzero(vis)
        inside = float("nan")
        if len(rows):
            x, y = _chip_to_map(meta, cols + 0.5, rows + 0.5)
            inside = truth.fraction_inside_image(
                label, places, dem, np.column_stack([x, y]), lo=-0.5
            )
            fractions.append(inside)
        hits = truth.ground_hits(
            label, places, dem, meta["ray_stride"], radius_m=geometry["radius"], step_m=args.step
        )
        x, y = _chip_to_map(meta, corr[:, 0].astype(np.float64), corr[:, 1].astype(np.float64))
        both = np.isfinite(x) & np.isfinite(hits[:, 0])
        err = np.hypot(x[both] - hits[both, 0], y[both] - hits[both, 1])
        errors.append(err)
        med = np.median(err) if len(err) else float("nan")
        p95 = np.percentile(err, 95) if len(err) else float("nan")
        print(f"{row['key']:<60} {len(rows):>10} {inside:>7.3f} {med:>10.4f} {p95:>7.4f}")
    err = np.concatenate(errors)
    print(
        f"\n{len(fractions)} samples with visible pixels: inside their image median "
        f"{np.median(fractions):.4f}, min {min(fractions):.4f}; corr vs independent hit over "
        f"{len(err)} rays: median {np.median(err):.4f} m, p95 {np.percentile(err, 95):.4f} m"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
