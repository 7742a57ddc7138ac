"""``mars-pairs export-qgis --chips``: each sample's ortho, DEM and viewshed chips as
GeoTIFFs that GDAL (QGIS) places where the manifest says the chip is, in the dataset CRS."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
from PIL import Image
from pyproj import CRS

from mars_pairs.cli import main
from mars_pairs.store.shards import MemberLocation, read_member
from support.builds import build_small
from support.members import dem_metres

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _member(root: Path, row: dict, name: str) -> bytes:
    loc = MemberLocation(row[f"{name}_shard"], row[f"{name}_offset"], row[f"{name}_size"])
    return read_member(root, loc)


@pytest.mark.parametrize("orientation", ["north-up", "heading-up"])
def test_chip_geotiffs_sit_on_the_chip_in_the_dataset_crs(
    small_mission: Path, tmp_path: Path, orientation: str
) -> None:
    root = build_small(small_mission, tmp_path / "ds", chips={"orientation": orientation})
    gpkg = tmp_path / "qgis" / "layers.gpkg"
    assert main(["export-qgis", str(root), str(gpkg), "--chips"]) == 0
    folder = tmp_path / "qgis" / "layers_chips"
    crs = CRS(json.loads((root / "dataset.json").read_text())["crs"])
    rows = pq.read_table(root / "manifest.parquet").to_pylist()
    assert len(list(folder.glob("*.tif"))) == 3 * len(rows) > 0
    for row in rows:
        meta = json.loads(_member(root, row, "meta"))
        dem = dem_metres(_member(root, row, "dem")).astype(np.float32)  # GDAL's reading
        ortho = np.asarray(Image.open(io.BytesIO(_member(root, row, "ortho"))))
        for name in ("ortho", "dem", "viewshed"):
            with rasterio.open(folder / f"{row['key']}_{name}.tif") as src:
                assert CRS(src.crs.to_wkt()) == crs
                assert list(src.transform)[:6] == pytest.approx(meta["chip_transform"])
                corners = np.array([src.transform * c for c in ((0, 0), (32, 0), (32, 32),
                                                                 (0, 32))])  # fmt: skip
                box = (*corners.min(axis=0), *corners.max(axis=0))
                assert box == pytest.approx(
                    (row["chip_xmin"], row["chip_ymin"], row["chip_xmax"], row["chip_ymax"])
                )
                if orientation == "north-up":
                    assert tuple(src.bounds) == pytest.approx(box)
                values = src.read(1)
            if name == "dem":
                np.testing.assert_array_equal(values, dem)
            if name == "ortho":
                np.testing.assert_array_equal(values, ortho)
