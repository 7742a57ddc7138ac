"""The manifest is a valid GeoParquet 1.1 file: geopandas reads it, the bbox holds every
footprint and the ``bbox`` covering column bounds each row's footprint."""

from __future__ import annotations

import json
from pathlib import Path

import geopandas
import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely
from pyproj import CRS

from mars_pairs.geometry.frames import MSL_PLACES_CRS
from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.geoparquet import footprint_bounds, footprints_bbox, geo_metadata
from mars_pairs.store.manifest import MANIFEST_SCHEMA, rows_to_table


@pytest.fixture()
def manifest(tmp_path: Path) -> tuple[Path, list[shapely.Polygon | None]]:
    """Rows whose footprints reach far beyond their 256 m chips (as views of 1 km do)."""
    rng = np.random.default_rng(4)
    rows, feet = [], []
    for i in range(40):
        x, y = 8141000.0 + rng.uniform(0, 300), -272000.0 + rng.uniform(0, 300)
        az, far = rng.uniform(0, 2 * np.pi), rng.uniform(5, 900)
        t = np.linspace(az - 0.2, az + 0.2, 5)
        foot = None
        if i % 7:
            ring = zip(x + far * np.sin(t), y + far * np.cos(t), strict=True)
            foot = shapely.Polygon([(x, y), *ring])
        feet.append(foot)
        rows.append(
            {
                "key": f"k{i}", "easting": x, "northing": y, "split": "train",
                "footprint": None if foot is None else shapely.to_wkb(foot),
                "bbox": footprint_bounds(foot),
                "chip_xmin": x - 128, "chip_ymin": y - 128,
                "chip_xmax": x + 128, "chip_ymax": y + 128,
            }
        )  # fmt: skip
    table = rows_to_table(rows, MANIFEST_SCHEMA)
    table = table.replace_schema_metadata(geo_metadata(MSL_PLACES_CRS, footprints_bbox(table)))
    path = tmp_path / "manifest.parquet"
    write_parquet_atomic(table, path)
    return path, feet


def test_geopandas_reads_it_and_the_bbox_holds_every_footprint(
    manifest: tuple[Path, list[shapely.Polygon | None]],
) -> None:
    path, feet = manifest
    geo = json.loads(pq.read_schema(path).metadata[b"geo"])
    assert geo["version"] == "1.1.0"
    column = geo["columns"]["footprint"]
    assert column["covering"] == {
        "bbox": {k: ["bbox", k] for k in ("xmin", "ymin", "xmax", "ymax")}
    }
    gdf = geopandas.read_parquet(path)
    assert gdf.geometry.name == "footprint"
    assert CRS.from_user_input(gdf.crs).equals(CRS.from_user_input(MSL_PLACES_CRS))
    present = [f for f in feet if f is not None]
    assert int(gdf.geometry.notna().sum()) == len(present)
    xmin, ymin, xmax, ymax = column["bbox"]
    box = shapely.box(xmin, ymin, xmax, ymax)
    assert all(box.covers(f) for f in present)
    # tight: the bbox is the footprints' own, and reaches beyond the chips'
    assert [xmin, ymin, xmax, ymax] == pytest.approx(list(shapely.MultiPolygon(present).bounds))
    assert xmax - xmin > 256 + 300
    # each row's covering bbox bounds its own footprint
    boxes = pq.read_table(path, columns=["bbox"])["bbox"].to_pylist()
    for foot, row in zip(feet, boxes, strict=True):
        if foot is None:
            assert row is None
        else:
            assert shapely.box(row["xmin"], row["ymin"], row["xmax"], row["ymax"]).covers(foot)


def test_geopandas_filters_by_the_covering_column(
    manifest: tuple[Path, list[shapely.Polygon | None]],
) -> None:
    path, feet = manifest
    query = (8141100.0, -271900.0, 8141200.0, -271800.0)
    got = set(geopandas.read_parquet(path, bbox=query)["key"])
    box = shapely.box(*query)
    expected = {
        f"k{i}"
        for i, f in enumerate(feet)
        if f is not None and box.intersects(shapely.box(*f.bounds))
    }
    assert got == expected and 0 < len(got) < len(feet)
