"""A generated manifest with every place column a filter tests: rover points, footprint
wedges (WKB polygons and their bbox covering) and rotated chip squares, in the Perseverance
PLACES map CRS, around a known centre (seeded, so every run holds the same rows)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import shapely

from mars_pairs.geometry.frames import M2020_PLACES_CRS, lonlat_to_map
from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.geoparquet import geo_metadata
from mars_pairs.store.manifest import MANIFEST_SCHEMA, rows_to_table

LON0, LAT0 = 77.45, 18.44
INSTRUMENTS = ("MCZ_LEFT", "MCZ_RIGHT", "NAVCAM_LEFT")
SPLITS = ("train", "val", "test")
SOLS = (52, 140)


def write_place_manifest(root: Path, n: int = 400, seed: int = 3) -> pa.Table:
    """Write ``root/manifest.parquet`` (n rows, m2020 only, sols 52..140) and return it."""
    rng = np.random.default_rng(seed)
    lon = LON0 + rng.uniform(-0.02, 0.02, n)
    lat = LAT0 + rng.uniform(-0.02, 0.02, n)
    x, y = lonlat_to_map(lon, lat, M2020_PLACES_CRS)
    rows = []
    for i in range(n):
        az = rng.uniform(0.0, 2.0 * np.pi)
        reach = rng.uniform(50.0, 400.0)
        a, b = az - 0.3, az + 0.3
        wedge = shapely.Polygon(
            [
                (x[i], y[i]),
                (x[i] + reach * np.sin(a), y[i] + reach * np.cos(a)),
                (x[i] + reach * np.sin(b), y[i] + reach * np.cos(b)),
            ]
        )
        cx, cy = x[i] + 0.6 * reach * np.sin(az), y[i] + 0.6 * reach * np.cos(az)
        chip = shapely.affinity.rotate(
            shapely.box(cx - 60.0, cy - 60.0, cx + 60.0, cy + 60.0), float(np.degrees(az))
        )
        fx0, fy0, fx1, fy1 = wedge.bounds
        c0, c1, c2, c3 = chip.bounds
        rows.append(
            {
                "key": f"k{i:04d}",
                "mission": "m2020",
                "instrument": INSTRUMENTS[i % 3],
                "sol": int(SOLS[0] + i % (SOLS[1] - SOLS[0] + 1)),
                "split": SPLITS[i % 3],
                "latitude": float(lat[i]),
                "longitude": float(lon[i]),
                "easting": float(x[i]),
                "northing": float(y[i]),
                "footprint": shapely.to_wkb(wedge),
                "bbox": {"xmin": fx0, "ymin": fy0, "xmax": fx1, "ymax": fy1},
                "rover_point": shapely.to_wkb(shapely.Point(x[i], y[i])),
                "chip_box": shapely.to_wkb(chip),
                "chip_xmin": c0,
                "chip_ymin": c1,
                "chip_xmax": c2,
                "chip_ymax": c3,
            }
        )
    table = rows_to_table(rows, MANIFEST_SCHEMA)
    table = table.replace_schema_metadata(geo_metadata(M2020_PLACES_CRS, None))
    root.mkdir(parents=True, exist_ok=True)
    write_parquet_atomic(table, root / "manifest.parquet", row_group_size=100)
    return table
