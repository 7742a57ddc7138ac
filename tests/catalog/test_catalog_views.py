"""A footprint catalogue drawn and exported: ``overview`` and ``report`` draw its footprints and
pairs, ``export-qgis`` writes its layers in its map CRS with pair lines between the camera
centres of pairs.parquet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely

from mars_pairs.cli.main import main
from mars_pairs.errors import MarsPairsError
from mars_pairs.pipeline.catalog.run import run_catalog
from support.configs import build_config

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def cat(missions, tmp_path_factory: pytest.TempPathFactory) -> Path:  # type: ignore[no-untyped-def]
    mission = missions(seed=5, stops=3, images_per_stop=3)
    out = tmp_path_factory.mktemp("views") / "cat"
    run_catalog(build_config(mission, out, geometry={"radius": 100}), out, progress=False)
    return out


def test_overview_draws_a_catalogue(cat: Path, tmp_path: Path) -> None:
    from PIL import Image

    from mars_pairs.viz import overview

    for by in ("sol", "instrument"):
        png = overview(cat, tmp_path / f"{by}.png", colour_by=by, dpi=30)
        with Image.open(png) as im:
            assert im.size[0] > 200 and im.size[1] > 100
    with pytest.raises(MarsPairsError, match="colour_by"):
        overview(cat, tmp_path / "x.png", colour_by="split")


def test_report_page_of_a_catalogue(cat: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.html"
    assert main(["report", str(cat), "--out", str(out), "--dpi", "30"]) == 0
    page = out.read_text()
    n = pq.read_metadata(cat / "catalog.parquet").num_rows
    pairs = pq.read_metadata(cat / "pairs.parquet").num_rows
    assert f"{n} images" in page and f"{pairs} pairs" in page
    assert page.count("data:image/png;base64,") == 2
    assert 'src="http' not in page


def test_export_qgis_of_a_catalogue(cat: Path, tmp_path: Path) -> None:
    import pyogrio
    from pyproj import CRS

    out = tmp_path / "c.gpkg"
    assert main(["export-qgis", str(cat), str(out)]) == 0
    table = pq.read_table(cat / "catalog.parquet")
    pairs = pq.read_table(cat / "pairs.parquet")
    layers = {name: kind for name, kind in pyogrio.list_layers(out)}
    assert layers == {"footprints": "MultiPolygon", "camera_wedges": "Polygon",
                      "camera_positions": "Point", "pairs": "LineString"}  # fmt: skip
    geo = json.loads(table.schema.metadata[b"geo"])
    ours = CRS.from_json_dict(geo["columns"]["footprint"]["crs"])
    for name in layers:
        assert CRS.from_wkt(pyogrio.read_info(out, layer=name)["crs"]).equals(ours)
    seen = sum(v is not None for v in table["footprint"].to_pylist())
    assert pyogrio.read_info(out, layer="footprints")["features"] == seen
    assert pyogrio.read_info(out, layer="camera_positions")["features"] == table.num_rows
    _, _, wkb, attrs = pyogrio.raw.read(out, layer="pairs")
    assert len(wkb) == pairs.num_rows > 0
    xs, ys = table["camera_x"].to_pylist(), table["camera_y"].to_pylist()
    centre = dict(zip(table["key"].to_pylist(), zip(xs, ys, strict=True), strict=True))
    keys_a, keys_b = attrs[0], attrs[1]
    for line, a, b in zip(shapely.from_wkb(wkb), keys_a, keys_b, strict=True):
        np.testing.assert_allclose(shapely.get_coordinates(line), [centre[a], centre[b]])
    with pytest.raises(MarsPairsError, match="no chips"):
        from mars_pairs.export import export_geopackage

        export_geopackage(cat, tmp_path / "d.gpkg", with_chips=True)
