"""Every Parquet the tool writes with geometries is GeoParquet that geopandas reads with its
CRS: the manifest (``footprint`` primary, ``rover_point``, ``chip_box``) and ``mars-pairs
query --format parquet``; the CRS has a name; GeoJSON names its Mars CRS."""

from __future__ import annotations

import json
from pathlib import Path

import geopandas
import pyarrow.parquet as pq
import pytest
import shapely
from pyproj import CRS

from mars_pairs.cli import main
from mars_pairs.geometry.body import M2020_PLACES_CRS, MSL_PLACES_CRS
from mars_pairs.store.geoparquet import crs_name, named_crs
from support.builds import build_small

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

EVERYWHERE = ("--bbox", "-180", "-90", "180", "90")


@pytest.fixture(scope="module")
def built(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_small(small_mission, tmp_path_factory.mktemp("geo") / "ds")


def test_mars_crs_names() -> None:
    name = crs_name(M2020_PLACES_CRS)
    assert name.startswith("Mars 2000 Equidistant Cylindrical (lat_ts 18.4663")
    assert "sphere R 3396190 m" in name
    assert CRS.from_json_dict(named_crs(M2020_PLACES_CRS)).equals(CRS(M2020_PLACES_CRS))
    msl = named_crs(MSL_PLACES_CRS)  # eqc clon 0 on the sphere: the IAU code itself
    assert msl["id"] == {"authority": "IAU", "code": 49910, "version": 2015}
    assert CRS.from_json_dict(msl).equals(CRS(MSL_PLACES_CRS))


def test_the_manifest_is_geoparquet_with_three_named_geometry_columns(built: Path) -> None:
    geo = json.loads(pq.read_schema(built / "manifest.parquet").metadata[b"geo"])
    assert geo["primary_column"] == "footprint"
    assert set(geo["columns"]) == {"footprint", "rover_point", "chip_box"}
    assert geo["columns"]["rover_point"]["geometry_types"] == ["Point"]
    names = {c["crs"]["name"] for c in geo["columns"].values()}
    assert len(names) == 1 and "unknown" not in names.pop()
    frame = geopandas.read_parquet(built / "manifest.parquet")
    info = json.loads((built / "dataset.json").read_text())
    assert frame.crs == CRS(info["crs"]) and frame.geometry.name == "footprint"
    for column in ("rover_point", "chip_box"):
        assert frame[column].crs == frame.crs
    table = pq.read_table(built / "manifest.parquet").to_pylist()
    for row, point, box in zip(table, frame["rover_point"], frame["chip_box"], strict=True):
        assert (point.x, point.y) == (row["easting"], row["northing"])
        assert box.bounds == pytest.approx(
            (row["chip_xmin"], row["chip_ymin"], row["chip_xmax"], row["chip_ymax"])
        )
    xs = [r["easting"] for r in table]
    assert geo["columns"]["rover_point"]["bbox"][0] == min(xs)


def test_query_parquet_is_geoparquet(built: Path, tmp_path: Path) -> None:
    out = tmp_path / "q.parquet"
    assert main(["query", str(built), *EVERYWHERE, "--format", "parquet", "--out", str(out)]) == 0
    frame = geopandas.read_parquet(out)
    manifest = geopandas.read_parquet(built / "manifest.parquet")
    assert frame.crs == manifest.crs and frame.crs is not None
    assert len(frame) == len(manifest) > 0
    assert sorted(frame["key"]) == sorted(manifest["key"])
    geo = json.loads(pq.read_schema(out).metadata[b"geo"])
    assert geo["columns"]["footprint"]["bbox"] == pytest.approx(
        list(manifest.geometry.total_bounds)
    )
    # a filtered query: the bbox is the selection's
    x, y = manifest["easting"].iloc[0], manifest["northing"].iloc[0]
    box = [str(v) for v in (x - 0.5, y - 0.5, x + 0.5, y + 0.5)]
    assert main(["query", str(built), "--bbox-map", *box, "--format", "parquet", "--out",
                 str(out)]) == 0  # fmt: skip
    one = geopandas.read_parquet(out)
    at = manifest[(manifest["easting"] == x) & (manifest["northing"] == y)]
    assert sorted(one["key"]) == sorted(at["key"]) and len(one) < len(manifest)
    geo = json.loads(pq.read_schema(out).metadata[b"geo"])
    assert geo["columns"]["rover_point"]["bbox"] == [x, y, x, y]


def test_query_geojson_names_its_mars_crs(built: Path, tmp_path: Path) -> None:
    out = tmp_path / "q.geojson"
    assert main(["query", str(built), *EVERYWHERE, "--format", "geojson", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["crs"]["properties"]["name"] == "IAU_2015:49900"
    props = doc["features"][0]["properties"]
    assert not {"footprint", "rover_point", "chip_box", "bbox"} & set(props)
    frame = geopandas.read_file(out)  # GDAL reads the Mars CRS from the crs member
    assert frame.crs is not None and frame.crs.ellipsoid.semi_major_metre == 3396190.0
    assert "Mars" in frame.crs.name
    assert shapely.get_num_geometries(frame.geometry.iloc[0]) == 1
