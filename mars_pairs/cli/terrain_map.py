"""``mars-pairs terrain-map DIR --out map.tif``: merge the terrain classes every sample
carried onto its chip (``terrain_on_map``, built with ``inputs.terrain_labels``) into one
Cloud-Optimized GeoTIFF on the ortho's grid over the traverse (``raster.terrain_map``: band 1
majority class, band 2 votes, band 3 agreement percent; 255 where no image saw the ground).

Split aware: ``--split NAME`` (repeat) merges only those splits; ``--each-split`` writes one
map per split beside ``--out`` (``map.train.tif``, ``map.test.tif``...), so a held-out
area's map is built from its own images only."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from mars_pairs.errors import UsageError


def register(sub: Any) -> None:
    """Add the ``terrain-map`` subparser."""
    p = sub.add_parser("terrain-map", help="merge carried terrain labels into one orbital map")
    p.add_argument("dataset", help="dataset folder (built with inputs.terrain_labels)")
    p.add_argument("--out", required=True, help="output GeoTIFF (COG)")
    p.add_argument("--split", action="append", help="merge only this split (repeat)")
    p.add_argument("--each-split", action="store_true", help="one map per split: OUT.<split>.tif")
    p.set_defaults(func=run)


def _class_names(config: dict[str, Any]) -> dict[int, str]:
    from mars_pairs.terrain_labels import AI4MARS_CLASSES

    inputs = config.get("inputs") or {}
    spec = inputs.get("terrain_labels") or {}
    classes = spec.get("classes")
    if isinstance(classes, dict) and classes:
        return {int(k): str(v) for k, v in classes.items()}
    return dict(AI4MARS_CLASSES.names)


def merge_splits(root: Path, out: Path, splits: list[str] | None) -> dict[str, Any]:
    """Merge the samples of ``splits`` (None: all) of the dataset at ``root`` into ``out``;
    returns counts (samples, cells seen, cells with >= 3 votes). Members are read from the
    shards by their manifest locations (no torch), the chip affines rebuilt from the
    manifest's chip bounds and rotation (``raster.chips.ChipGrid``)."""
    import io
    import math

    import numpy as np
    import rasterio
    from PIL import Image

    from mars_pairs.raster.chips import ChipGrid
    from mars_pairs.raster.terrain_map import VoteGrid, write_map
    from mars_pairs.store.dataset_info import read_dataset_info
    from mars_pairs.store.query import Manifest
    from mars_pairs.store.shards import MemberLocation, read_member

    manifest = Manifest.open(root)
    if "terrain_on_map_offset" not in manifest.column_names:
        raise UsageError(
            f"{root}: the dataset has no terrain_on_map member (build it with "
            "inputs.terrain_labels)"
        )
    info = read_dataset_info(root, required=False)
    ortho = info.build_input(root, "ortho")
    if ortho is None or not Path(ortho).exists():
        raise UsageError(f"{root}/dataset.json: config.inputs.ortho {ortho} not found")
    with rasterio.open(ortho) as src:
        ortho_transform, crs = src.transform, src.crs
    rows = manifest.filter(split=splits) if splits else manifest
    cols = ["key", "chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax", "chip_rotation_deg",
            "terrain_on_map_shard", "terrain_on_map_offset", "terrain_on_map_size"]  # fmt: skip
    table = rows.to_table(cols).to_pylist()
    if not table:
        raise UsageError(f"{root}: no samples in split(s) {splits}")
    bounds = (
        min(r["chip_xmin"] for r in table), min(r["chip_ymin"] for r in table),
        max(r["chip_xmax"] for r in table), max(r["chip_ymax"] for r in table),
    )  # fmt: skip
    names = _class_names(info.config)
    grid = VoteGrid.covering(ortho_transform, crs, bounds, tuple(sorted(names)))
    for r in table:
        loc = MemberLocation(r["terrain_on_map_shard"], r["terrain_on_map_offset"],
                             r["terrain_on_map_size"])  # fmt: skip
        data = read_member(root, loc, name=f"{r['key']}.terrain_on_map.png")
        on_map = np.asarray(Image.open(io.BytesIO(data)))
        t = math.radians(r["chip_rotation_deg"] or 0.0)
        side = (r["chip_xmax"] - r["chip_xmin"]) / (abs(math.cos(t)) + abs(math.sin(t)))
        chip = ChipGrid.around(
            (r["chip_xmin"] + r["chip_xmax"]) / 2.0, (r["chip_ymin"] + r["chip_ymax"]) / 2.0,
            side, on_map.shape[0], crs, r["chip_rotation_deg"] or 0.0,
        )  # fmt: skip
        grid.add(on_map, chip.transform)
    write_map(out, grid, names)
    votes = grid.votes()
    return {"samples": len(table), "cells_seen": int((votes > 0).sum()),
            "cells_3_votes": int((votes >= 3).sum())}  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Write the map(s); one line per map."""
    from mars_pairs.store.query import Manifest

    root, out = Path(args.dataset), Path(args.out)
    start = time.perf_counter()
    jobs: list[tuple[Path, list[str] | None]] = [(out, args.split)]
    if args.each_split:
        manifest = Manifest.open(root)
        present = sorted(set(manifest.to_table(["split"])["split"].to_pylist()))
        wanted = [s for s in present if not args.split or s in args.split]
        jobs = [(out.with_name(f"{out.stem}.{s}{out.suffix or '.tif'}"), [s]) for s in wanted]
    for path, splits in jobs:
        got = merge_splits(root, path, splits)
        took = time.perf_counter() - start
        print(f"{path}: {got['samples']} samples, {got['cells_seen']} cells seen, "
              f"{got['cells_3_votes']} with >= 3 votes ({took:.1f} s)")  # fmt: skip
    return 0
