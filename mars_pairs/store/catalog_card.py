"""README.md of a footprint catalogue folder, from its catalog.json document."""

from __future__ import annotations

from typing import Any

from mars_pairs.store.catalog_schema import CATALOG_FIELDS, PAIR_FIELDS


def catalog_card(doc: dict[str, Any]) -> str:
    """The card: what the folder holds, its counts, CRS, footprint rule and columns."""
    counts = doc["counts"]
    foot = doc["footprint"]
    lines = [
        "# Footprint catalogue",
        "",
        "Every image of the labels below with the ground it saw: the visible footprint as a "
        "(multi)polygon, the camera, its pointing and its wedge; no chips. Made by "
        f"mars-pairs {doc['versions']['mars_pairs']}.",
        "",
        f"- images: {counts['images']} (`catalog.parquet`, GeoParquet 1.1, Hilbert order)",
        f"- failures: {counts['failures']} (`failures.parquet`: label, stage, error)",
        f"- pairs of images whose footprints overlap: {counts['pairs']} (`pairs.parquet`)",
        f"- CRS: {doc['crs_name']} (map units; the WKT in `catalog.json`)",
        "- STAC: `collection.json` (a STAC 1.1 Collection, proj and ssys extensions), one Item "
        "per image with a time in `items.ndjson` and in `items.parquet` (stac-geoparquet); "
        "footprints in longitude/latitude on the Mars sphere",
        f"- footprint: {foot['source']}, radius {foot['radius_m']} m, {foot['view_mask']} "
        f"mask, simplified by {foot['simplify_tolerance']:g} map units (DEM cell "
        f"{foot['dem_cell']:g})",
        f"- license: {doc['license']}",
        "",
        "Read it with `geopandas.read_parquet('catalog.parquet')` or "
        "`mars_pairs.store.catalog.Catalog.open('.')` (`.saw(lon, lat)`, "
        "`.bbox(west, south, east, north)`, `.overlaps(key)`).",
        "",
        "## catalog.parquet",
        "",
        "| column | type |",
        "|---|---|",
        *(f"| `{name}` | {kind} |" for name, kind in CATALOG_FIELDS),
        "",
        "## pairs.parquet",
        "",
        "| column | type |",
        "|---|---|",
        *(f"| `{name}` | {kind} |" for name, kind in PAIR_FIELDS),
        "",
    ]
    if doc.get("failures_by_reason"):
        lines += ["## Failures", ""]
        lines += [f"- {k}: {v}" for k, v in sorted(doc["failures_by_reason"].items())]
        lines.append("")
    return "\n".join(lines)
