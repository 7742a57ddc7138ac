"""The catalogue's STAC files and its GeoParquet in other readers: the Items validate
(stac-pydantic's models, offline), their geometry is the footprint turned to lon/lat by an
independent pyproj transform, pystac and stac-geoparquet read them back, catalog.json records
every file's SHA-256, and DuckDB's spatial extension reads catalog.parquet with geometry and
CRS."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely

from mars_pairs.pipeline.catalog.run import run_catalog
from support.configs import build_config

SECTIONS = {"geometry": {"radius": 100}, "output": {"shard_size": 4}}


@pytest.fixture(scope="module")
def cat(missions, tmp_path_factory: pytest.TempPathFactory) -> Path:  # type: ignore[no-untyped-def]
    mission = missions(seed=5, stops=3, images_per_stop=3)
    out = tmp_path_factory.mktemp("stac") / "cat"
    run_catalog(build_config(mission, out, **SECTIONS), out, progress=False)
    return out


def _items(cat: Path) -> list[dict]:  # type: ignore[type-arg]
    with open(cat / "items.ndjson") as fh:
        return [json.loads(line) for line in fh]


def test_items_validate_and_name_mars(cat: Path) -> None:
    from stac_pydantic import Collection, Item

    items = _items(cat)
    rows = pq.read_table(cat / "catalog.parquet")
    assert [it["id"] for it in items] == rows["key"].to_pylist()
    for item in items:
        Item.model_validate(item)
        props = item["properties"]
        assert props["ssys:targets"] == ["Mars"]
        assert props["proj:code"] is None
        assert "Mars" in props["proj:wkt2"] and props["proj:projjson"]["type"] == "ProjectedCRS"
        assert item["assets"]["label"]["href"].endswith(".xml")
        assert {link["rel"] for link in item["links"]} >= {"via", "collection"}
    with open(cat / "collection.json") as fh:
        collection = json.load(fh)
    Collection.model_validate(collection)
    assert collection["summaries"]["ssys:targets"] == ["Mars"]


def test_geometry_is_the_footprint_in_lonlat(cat: Path) -> None:
    from pyproj import CRS, Transformer

    rows = pq.read_table(cat / "catalog.parquet")
    geo = json.loads(rows.schema.metadata[b"geo"])
    crs = CRS.from_json_dict(geo["columns"]["footprint"]["crs"])
    sphere = CRS.from_proj4("+proj=longlat +R=3396190 +no_defs")
    to_lonlat = Transformer.from_crs(crs, sphere, always_xy=True)
    feet, cameras = rows["footprint"].to_pylist(), rows["camera_point"].to_pylist()
    for item, wkb, camera in zip(_items(cat), feet, cameras, strict=True):
        foot = shapely.from_wkb(wkb if wkb is not None else camera)  # no ground: the camera
        xy = shapely.get_coordinates(foot)
        lon, lat = to_lonlat.transform(xy[:, 0], xy[:, 1])
        got = shapely.get_coordinates(shapely.geometry.shape(item["geometry"]))
        np.testing.assert_allclose(got, np.column_stack([lon, lat]), rtol=0, atol=1e-9)
        assert item["bbox"] == pytest.approx([lon.min(), lat.min(), lon.max(), lat.max()])
        # the camera's own lon/lat (the catalogue's column) lies near its footprint
        props = item["properties"]
        assert abs(props["mars_pairs:camera_lat"] - lat.mean()) < 0.01


def test_pystac_and_stac_geoparquet_read_back(cat: Path) -> None:
    import pystac
    import stac_geoparquet.arrow

    collection = pystac.Collection.from_file(str(cat / "collection.json"))
    assert collection.id == "mars-pairs-footprints"
    items = _items(cat)
    for item in items:
        read = pystac.Item.from_dict(item)
        assert read.datetime is not None and read.datetime.tzinfo is not None
    table = pq.read_table(cat / "items.parquet")
    back = list(stac_geoparquet.arrow.stac_table_to_items(table))
    assert [b["id"] for b in back] == [it["id"] for it in items]
    for b, it in zip(back, items, strict=True):
        assert shapely.geometry.shape(b["geometry"]).equals_exact(
            shapely.geometry.shape(it["geometry"]), 1e-12
        )
        assert b["properties"]["ssys:targets"] == ["Mars"]


def test_catalog_json_records_every_file(cat: Path) -> None:
    with open(cat / "catalog.json") as fh:
        record = json.load(fh)["files"]
    names = sorted(p.name for p in cat.iterdir() if p.name != "catalog.json")
    assert sorted(record) == names
    for name, entry in record.items():
        data = (cat / name).read_bytes()
        assert entry == {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}


def test_duckdb_spatial_reads_geometry_and_crs(cat: Path) -> None:
    duckdb = pytest.importorskip("duckdb")
    spatial = pytest.importorskip("duckdb_extension_spatial")
    found = sorted(Path(spatial.__file__).parent.glob("extensions/*/spatial.duckdb_extension"))
    assert found, "duckdb_extension_spatial ships no spatial.duckdb_extension"
    config = {"autoinstall_known_extensions": False, "autoload_known_extensions": False}
    con = duckdb.connect(config=config)
    con.execute(f"LOAD '{found[-1]}'")
    path = cat / "catalog.parquet"
    described = con.execute(f"DESCRIBE SELECT * FROM read_parquet('{path}')").fetchall()
    types = {row[0]: row[1] for row in described}
    assert str(types["footprint"]).startswith("GEOMETRY(") and "Mars" in types["footprint"]
    rows = con.execute(
        f"SELECT key, ST_AsWKB(footprint), ST_Area(footprint), ST_CRS(footprint) "
        f"FROM read_parquet('{path}') ORDER BY key"
    ).fetchall()
    table = pq.read_table(path).sort_by("key")
    assert [r[0] for r in rows] == table["key"].to_pylist()
    for (_, wkb, area, crs), ours in zip(rows, table["footprint"].to_pylist(), strict=True):
        if ours is None:  # no ground in view
            assert wkb is None
            continue
        geom = shapely.from_wkb(ours)
        assert shapely.from_wkb(bytes(wkb)).equals_exact(geom, 0.0)
        assert area == pytest.approx(geom.area, rel=1e-9)
        assert "Mars" in json.loads(crs)["name"]


def test_without_stac_geoparquet_the_json_stac_files_are_written_alone(
    cat: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.util

    import pyarrow as pa

    from mars_pairs.store import stac

    real = importlib.util.find_spec
    monkeypatch.setattr(
        stac.importlib.util,
        "find_spec",
        lambda name, *a: None if name == "stac_geoparquet" else real(name, *a),
    )
    folder = tmp_path / "cat"
    folder.mkdir()
    (folder / "items.parquet").write_bytes(b"an old one")
    catalog = pq.read_table(cat / "catalog.parquet")
    crs = json.loads((cat / "catalog.json").read_text())["crs"]
    doc: dict[str, object] = {"license": "CC-BY-4.0"}
    n = stac.write_stac(folder, catalog, crs, doc, cat)
    assert n == len(_items(cat))
    assert not (folder / "items.parquet").exists()  # the old one is gone, none half-written
    assert "stac-geoparquet" in str(doc["stac_parquet"])
    assert (folder / "items.ndjson").read_bytes() != b"" and (folder / "collection.json").exists()
    assert isinstance(catalog, pa.Table)
