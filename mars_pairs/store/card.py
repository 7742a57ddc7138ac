"""The dataset card: ``README.md`` of a built dataset folder (what it is, how it was built,
sources and citations, licence, counts, splits, columns, members, how to load it).

The card is Markdown written from the build's own facts (config, counts, schema, CRS), with no
time stamp: the same build writes the same bytes."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from mars_pairs.store.splits import BUFFER, TRAIN
from mars_pairs.store.wids_index import shard_list_name, split_index_name

#: Licence of a dataset built from NASA PDS products (United States Government works).
PUBLIC_DOMAIN = "CC0-1.0"
#: Licence of a dataset built from the synthetic mission: the project's own.
PROJECT_LICENSE = "MIT"

#: column -> (units, frame) for the card's column table; columns not listed show "-".
COLUMN_DOCS: dict[str, tuple[str, str]] = {
    "key": ("-", "WebDataset sample key (mission_productid)"),
    "label_path": ("-", "the label's path relative to the labels root (dataset.json)"),
    "sol": ("sol", "mission sol of the observation"),
    "time": ("UTC", "observation start time"),
    "latitude": ("degrees", "planetocentric, Mars sphere R 3396190 m"),
    "longitude": ("degrees east", "planetocentric, Mars sphere"),
    "easting": ("m", "dataset CRS (rover position)"),
    "northing": ("m", "dataset CRS (rover position)"),
    "elevation_m": ("m", "above the areoid (PLACES)"),
    "azimuth_deg": ("degrees", "image centre ray, SITE_FRAME, clockwise from north"),
    "elevation_deg": ("degrees", "image centre ray, SITE_FRAME, up from the horizon"),
    "label_azimuth_deg": ("degrees", "the label's own pointing"),
    "label_elevation_deg": ("degrees", "the label's own pointing"),
    "hfov_deg": ("degrees", "camera field of view"),
    "vfov_deg": ("degrees", "camera field of view"),
    "width": ("pixels", "ground image"),
    "height": ("pixels", "ground image"),
    "dem_offset_m": ("m", "DEM at the rover origin minus PLACES elevation"),
    "viewshed_area_m2": ("m²", "dataset CRS"),
    "visible_cells": ("cells", "DEM cells visible"),
    "max_visible_range_m": ("m", "from the camera"),
    "ray_hit_fraction": ("0..1", "strided rays that hit the terrain"),
    "footprint": ("WKB polygon", "dataset CRS (GeoParquet primary geometry)"),
    "bbox": ("m", "dataset CRS: the footprint's bounds (GeoParquet covering)"),
    "rover_point": ("WKB point", "dataset CRS (GeoParquet geometry)"),
    "chip_box": ("WKB polygon", "dataset CRS: the chip's corners (GeoParquet geometry)"),
    "chip_xmin": ("m", "dataset CRS, the chip's axis-aligned bounds"),
    "chip_ymin": ("m", "dataset CRS"),
    "chip_xmax": ("m", "dataset CRS"),
    "chip_ymax": ("m", "dataset CRS"),
    "chip_rotation_deg": ("degrees", "0 north-up; heading-up: the camera azimuth"),
    "ortho_coverage": ("0..1", "ortho chip pixels with data"),
    "dem_coverage": ("0..1", "DEM chip pixels with data"),
    "hilbert": ("-", "Hilbert index of the rover position (row order)"),
}

#: member -> (file name, format, units) of the shard members.
MEMBER_DOCS: dict[str, tuple[str, str, str]] = {
    "ground": ("ground.jpg / ground.png", "the original image bytes (IMG products: PNG)",
               "the product's pixel values"),
    "ortho": ("ortho.png", "uint8 greyscale chip", "ortho values scaled by meta.ortho_range"),
    "dem": ("dem.tif", "uint16 [H, W] TIFF (zstd), m = offset_m + scale_m * value",
            "m above the areoid within meta.dem_encoding.max_error_m (3.9 mm at the finest "
            "quantum, 2^-7 m); 65535: no data"),
    "viewshed": ("viewshed.png", "uint8 chip, 0 / 255", "visible from the camera"),
    "corr": ("corr.npy", "float32 [2, H/k, W/k]",
             "chip pixel (column, row) of every k-th ground pixel's ray hit; NaN: no hit"),
    "meta": ("meta.json", "JSON", "the row's plain values, crs (WKT), chip_transform "
             "(affine a..f, chip pixel -> map x, y)"),
}  # fmt: skip

#: The camera data set of each mission (NASA PDS, with its DOI).
MISSION_SOURCES = {
    "msl": "- Curiosity Mastcam RDR, MSL-M-MASTCAM-4-RDR-IMG-V1.0, NASA Planetary Data System, "
    "doi:10.17189/1520328",
    "m2020": "- Perseverance Mastcam-Z calibrated products, NASA Planetary Data System, "
    "doi:10.17189/bs6b-4782",
}
SOURCES_REAL = (
    *MISSION_SOURCES.values(),
    "- PLACES rover localizations (best_interp / localized_interp tables), NASA PDS "
    "Cartography and Imaging Sciences Node",
    "- Orbital DEM and orthoimage: HiRISE (NASA / JPL / University of Arizona) digital "
    "terrain models and orthoimages, as produced with USGS Astrogeology (ISIS)",
)
SOURCES_SYNTHETIC = (
    "- The synthetic mission of mars-pairs (`mars_pairs.synth`): generated terrain, "
    "orthoimage, traverse, PLACES table, camera labels and images; no real data",
)


@dataclass(frozen=True)
class CardFacts:
    """What the card says about one build. ``config`` is dataset.json's (relative paths),
    ``counts`` its counts, ``splits`` its split report; ``crs_name`` the named dataset CRS;
    ``license`` an SPDX id; ``synthetic`` whether the inputs are the synthetic mission."""

    version: str
    config: Mapping[str, Any]
    counts: Mapping[str, Any]
    splits: Mapping[str, Any]
    crs_name: str
    license: str
    synthetic: bool
    schema: pa.Schema
    shards: Sequence[str]
    failures_by_reason: Mapping[str, int]


def sources(synthetic: bool, missions: Sequence[str] = ()) -> tuple[str, ...]:
    """The card's source lines: the synthetic mission, or the PDS data sets of ``missions``
    (every one when none is known), PLACES and the HiRISE maps."""
    if synthetic:
        return SOURCES_SYNTHETIC
    known = [MISSION_SOURCES[m] for m in sorted(set(missions)) if m in MISSION_SOURCES]
    return tuple(line for line in SOURCES_REAL if line not in MISSION_SOURCES.values() or
                 not known or line in known)  # fmt: skip


def default_license(synthetic: bool) -> str:
    """CC0-1.0 for NASA PDS data (public domain), the project's licence for synthetic data."""
    return PROJECT_LICENSE if synthetic else PUBLIC_DOMAIN


def _type(t: pa.DataType) -> str:
    if pa.types.is_struct(t):
        return "struct<" + ", ".join(f"{f.name}: {f.type}" for f in t) + ">"
    return str(t)


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
    return lines


def dataset_card(facts: CardFacts) -> str:
    """The README.md text of a dataset folder (Markdown, ends with a newline)."""
    cfg = facts.config
    inputs = cfg.get("inputs", {})
    chips, geometry, output = cfg.get("chips", {}), cfg.get("geometry", {}), cfg.get("output", {})
    counts = facts.counts
    kind = "synthetic" if facts.synthetic else "real NASA PDS"
    if facts.synthetic:
        license_text = (
            f"`{facts.license}`. Every input is generated by mars-pairs' synthetic mission; "
            "the data carry the project's licence."
        )
    else:
        license_text = (
            f"`{facts.license}`. The NASA PDS products (images, labels, PLACES, HiRISE maps) "
            "are United States Government works in the public domain; this derived dataset "
            "is dedicated to the public domain as well. Cite the sources below."
        )
    lines = [
        "---",
        f"license: {facts.license.lower()}",
        "tags: [mars, geospatial, cross-view, webdataset, geoparquet]",
        *_hf_configs(facts),
        "---",
        "",
        "# mars-pairs dataset",
        "",
        f"Paired ground / orbital samples built by mars-pairs {facts.version} from {kind} "
        "data: each sample is a rover mast-camera image with orbital chips around the rover "
        "(orthoimage, DEM, viewshed of the camera) and per-pixel correspondence between the "
        "image and the chips, computed from the camera model and the PLACES rover position.",
        "",
        "## How it was built",
        "",
        f"- mars-pairs {facts.version}: `mars-pairs build --config "
        f"{cfg.get('source') or 'CONFIG'}` (the config is in `dataset.json`, `config`; "
        "paths relative to this folder)",
        f"- labels: {', '.join(f'`{p}`' for p in inputs.get('labels', []))}",
        f"- PLACES: `{inputs.get('places')}`; DEM: `{inputs.get('dem')}`; "
        f"ortho: `{inputs.get('ortho')}`",
        f"- view radius {geometry.get('radius')} m, viewshed `{geometry.get('viewshed')}`, "
        f"ray stride {geometry.get('ray_stride')} px",
        f"- chips: {chips.get('size_m')} m at {chips.get('size_px')} px, "
        f"`{chips.get('orientation')}`; {output.get('shard_size')} samples per chunk, a chunk's "
        "samples of each split in a shard of their own",
        f"- CRS: {facts.crs_name} (WKT in `dataset.json`, PROJJSON in the manifest's GeoParquet "
        "metadata)",
        "",
        "## Sources",
        "",
        *sources(facts.synthetic, list(counts.get("by_mission") or {})),
        "",
        "## Licence",
        "",
        license_text,
        "",
        "## Counts and splits",
        "",
        f"{counts.get('samples', 0)} samples, {counts.get('failures', 0)} failures "
        "(`failures.parquet`: one row per observation that gave no sample).",
        "",
    ]
    by_split = counts.get("by_split") or {}
    if by_split:
        lines += _table(["split", "samples"], sorted(by_split.items()))
        lines.append("")
    by_mission = counts.get("by_mission") or {}
    if by_mission:
        lines += _table(["mission", "samples"], sorted(by_mission.items()))
        lines.append("")
    if facts.failures_by_reason:
        lines += _table(["failed at (error)", "count"], sorted(facts.failures_by_reason.items()))
        lines.append("")
    style = facts.splits.get("style") if isinstance(facts.splits, Mapping) else None
    if style:
        lines += [
            f"Splits: `{style}` (spatial, leak-checked; details in `dataset.json`, `splits`).",
            "",
        ]
    lines += [
        "## Files",
        "",
        "- `manifest.parquet`: one row per sample, GeoParquet 1.1 (geometry columns "
        "`footprint` (primary), `rover_point`, `chip_box`), Hilbert-ordered",
        "- `failures.parquet`: the observations that gave no sample and why",
        f"- `shards/`: {len(facts.shards)} WebDataset tar shards (`<key>.<member>`), each "
        "of one split's samples (`shard-<chunk>-<split>.tar`)",
        "- `shards-<split>.txt`: the shards of one split, one a line (WebDataset's shard list)",
        "- `shardindex.json`, `shardindex-<split>.json`: wids indexes of all shards and of one "
        "split's",
        "- `dataset.json`: config, versions, CRS, chip spec, counts, split report",
        "- `croissant.json`: Croissant 1.0 metadata (MLCommons)",
        *(
            [
                f"- `pairs.parquet`: the {counts['pairs']} pairs of samples whose footprints "
                "overlap, with both splits and `cross_split` (positives: within one split)"
            ]
            if "pairs" in counts
            else []
        ),
        "",
        "## Columns (manifest.parquet)",
        "",
    ]
    rows = []
    for f in facts.schema:
        if f.name.split("_")[0] in MEMBER_DOCS and f.name.endswith(
            ("_shard", "_offset", "_size", "_crc32c")
        ):
            continue
        units, frame = COLUMN_DOCS.get(f.name, ("-", "-"))
        rows.append((f"`{f.name}`", _type(f.type), units, frame))
    rows.append(
        (
            "`<member>_shard/_offset/_size/_crc32c`",
            "string/int64",
            "bytes",
            "where each member lies in its shard, CRC-32C of its bytes",
        )
    )
    lines += _table(["column", "type", "units", "frame"], rows)
    lines += ["", "## Members (shards/*.tar)", ""]
    lines += _table(["member", "format", "units"], [(f"`{n}`", f, u) for n, f, u in
                                                    MEMBER_DOCS.values()])  # fmt: skip
    lines += [
        "",
        "## Loading",
        "",
        "Run in this folder. Each split has shards of its own; `shards-train.txt` lists the "
        "train split's.",
        "",
        "```python",
        "# mars-pairs (PyTorch): decoded, georeferenced tensors",
        "from mars_pairs.torch import MarsPairsDataset",
        'ds = MarsPairsDataset(".", fields=("ground", "ortho", "dem", "viewshed"), split="train")',
        "",
        "# webdataset: one split's shards as they are",
        "import webdataset as wds",
        f'with open("{shard_list_name(TRAIN)}") as f:',
        "    train_shards = f.read().split()",
        "samples = wds.WebDataset(train_shards, shardshuffle=False)",
        "",
        "# wids (indexed, random access): one split",
        "import wids",
        f'train = wids.ShardListDataset("{split_index_name(TRAIN)}")',
        "",
        "# Hugging Face datasets: this folder, one split per split (the card's `configs`)",
        "import os",
        "from datasets import load_dataset",
        'pairs = load_dataset(os.path.abspath("."))  # a DatasetDict: train, val, test, ...',
        'rows = load_dataset("parquet", data_files="manifest.parquet", split="train")',
        "",
        "# geopandas: the manifest with its CRS (footprints; rover_point and chip_box too)",
        "import geopandas as gpd",
        'gdf = gpd.read_parquet("manifest.parquet")',
        "```",
        "",
    ]
    return "\n".join(lines)


#: The order of the splits in the card's ``configs`` (others between test and the buffer).
_SPLIT_ORDER = {TRAIN: 0, "val": 1, "test": 2, BUFFER: 4}


def _hf_configs(facts: CardFacts) -> list[str]:
    """The front matter's Hugging Face ``configs``: one ``data_files`` entry per split with
    samples (its shards' glob), so ``datasets.load_dataset(folder)`` gives each split; the
    buffer (when kept) is a split of its own."""
    splits = sorted(facts.counts.get("by_split") or {}, key=lambda s: (_SPLIT_ORDER.get(s, 3), s))
    if not splits:
        return []
    lines = ["configs:", "- config_name: default", "  data_files:"]
    for split in splits:
        lines += [f"  - split: {split}", f"    path: shards/shard-*-{split}.tar"]
    return lines
