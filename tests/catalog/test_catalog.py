"""The footprint catalogue on a generated mission: every label accounted for, each footprint
against the build's viewshed chip of the same image, ``saw`` against the
``viewshed --label`` GeoTIFF read with rasterio, resume to identical bytes, the engines
agreeing, GeoParquet read by geopandas, pairs against brute force, malformed points refused."""

from __future__ import annotations

import glob
import hashlib
import io
import json
import tarfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
import shapely
from affine import Affine
from PIL import Image
from rasterio import features

from mars_pairs.cli.main import main
from mars_pairs.errors import ArgumentError, ConfigError
from mars_pairs.geometry.frames import map_to_lonlat
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.store.catalog import Catalog
from mars_pairs.store.pairs import Footprints, pairs_table
from mars_pairs.store.query import Manifest
from support.configs import build_config

SECTIONS = {
    "geometry": {"radius": 100},
    "chips": {"size_m": 64, "size_px": 128},
    "output": {"shard_size": 3},
}


@pytest.fixture(scope="module")
def mission(missions):  # type: ignore[no-untyped-def]
    return missions(seed=5, stops=3, images_per_stop=3)


@pytest.fixture(scope="module")
def built(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(catalogue folder, dataset folder) of the mission, one worker each."""
    base = tmp_path_factory.mktemp("catalog")
    config = build_config(mission, base / "ds", **SECTIONS)
    run_build(config, progress=False)
    run_catalog(config, base / "cat", progress=False)
    return base / "cat", base / "ds"


def _digests(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_every_label_is_a_row_or_a_failure(built: tuple[Path, Path], mission: Path) -> None:
    cat, _ = built
    labels = glob.glob(str(mission / "labels" / "*.xml"))
    rows = pq.read_table(cat / "catalog.parquet")
    failures = pq.read_table(cat / "failures.parquet")
    assert rows.num_rows + failures.num_rows == len(labels)
    assert rows.num_rows > 0
    assert sorted(_digests(cat)) == [
        "README.md",
        "catalog.json",
        "catalog.parquet",
        "collection.json",
        "failures.parquet",
        "items.ndjson",
        "items.parquet",
        "pairs.parquet",
    ]


def chip_comparison(cat: Path, ds: Path) -> dict[str, tuple[float, int, float]]:
    """key -> (IoU over the chip's extent, the chip's pixels in view, the farthest (map
    units) a pixel where the two disagree lies from the footprint's boundary) of the
    footprint rasterized on the chip grid (pixel centres) and the build's viewshed chip."""
    catalog = Catalog.open(cat)
    geoms = dict(zip(catalog.table["key"].to_pylist(), catalog.geometry, strict=True))
    out = {}
    for shard in sorted((ds / "shards").glob("*.tar")):
        with tarfile.open(shard) as tar:
            for name in tar.getnames():
                if not name.endswith(".meta.json"):
                    continue
                key = name[: -len(".meta.json")]
                meta = json.loads(tar.extractfile(name).read())  # type: ignore[union-attr]
                png = tar.extractfile(f"{key}.viewshed.png").read()  # type: ignore[union-attr]
                chip = np.asarray(Image.open(io.BytesIO(png))) > 0
                transform = Affine(*meta["chip_transform"])
                geom = geoms[key]
                mine = np.zeros_like(chip)
                if geom is not None:
                    mine = features.rasterize([geom], out_shape=chip.shape, transform=transform) > 0
                union = int((chip | mine).sum())
                iou = 1.0 if union == 0 else float((chip & mine).sum() / union)
                rows, cols = np.nonzero(chip != mine)
                far = 0.0
                if len(rows):
                    x, y = transform * (cols + 0.5, rows + 0.5)  # type: ignore[operator]
                    edge = geom.boundary if geom is not None else None
                    far = (
                        np.inf
                        if edge is None
                        else float(shapely.distance(edge, shapely.points(x, y)).max())
                    )
                out[key] = (iou, int(chip.sum()), far)
    return out


def test_footprint_matches_the_builds_viewshed_chip(built: tuple[Path, Path]) -> None:
    """Against the chip the build cut for the same image: IoU >= 0.95 over the chip's extent
    for every image with a chip pixel in view (a view of a few pixels too: the footprint's
    edge is the view test's, traced to a few mm), and for every image each pixel where the
    two disagree lies within one DEM cell of the footprint's boundary."""
    cat, ds = built
    found = chip_comparison(cat, ds)
    cell = json.loads((cat / "catalog.json").read_text())["footprint"]["dem_cell"]
    assert len(found) == len(Catalog.open(cat))
    seen = {k: v[0] for k, v in found.items() if v[1] > 0}
    assert seen and min(seen.values()) >= 0.95, sorted(seen.items(), key=lambda kv: kv[1])[:3]
    assert max(v[2] for v in found.values()) <= cell


def test_saw_agrees_with_the_viewshed_geotiffs(
    built: tuple[Path, Path], mission: Path, tmp_path: Path
) -> None:
    """``Catalog.saw`` at 1,000 random points uniform over the traverse area (the
    footprints' box) against the set of images whose ``mars-pairs viewshed --label`` GeoTIFF
    (read with rasterio) marks the point's cell visible: >= 99 % equal; and at 500 points
    inside footprints (where the image edges are) no returned image whose raster is more
    than one cell from a visible cell there (the footprint follows the view test's edge
    inside a cell, the GeoTIFF gives each cell its centre's verdict: they differ inside the
    cells an image edge cuts); with
    ``per_cell`` (the view's own cells) the sets are equal at every point of both."""
    cat, _ = built
    catalog = Catalog.open(cat)
    rasters = {}
    for key, rel in zip(
        catalog.table["key"].to_pylist(), catalog.table["label_path"].to_pylist(), strict=True
    ):
        out = tmp_path / f"{key}.tif"
        argv = [
            "viewshed",
            "--dem",
            str(mission / "orbital" / "dem.tif"),
            "--label",
            str(mission / "labels" / rel),
            "--places",
            str(mission / "places" / "best_interp.csv"),
            "--radius",
            "100",
            "--out",
            str(out),
        ]
        assert main(argv) == 0
        with rasterio.open(out) as src:
            rasters[key] = (src.read(1), src.transform)
    rng = np.random.default_rng(7)
    valid = [g for g in catalog.geometry if g is not None]
    x0, y0, x1, y1 = shapely.total_bounds(np.array(valid, dtype=object))
    points = [(rng.uniform(x0, x1), rng.uniform(y0, y1)) for _ in range(1000)]
    while len(points) < 1500:
        g = valid[rng.integers(len(valid))]
        bx0, by0, bx1, by1 = g.bounds
        p = (rng.uniform(bx0, bx1), rng.uniform(by0, by1))
        if g.contains(shapely.Point(p)):
            points.append(p)
    xs, ys = np.array(points).T
    lons, lats = map_to_lonlat(xs, ys, json.dumps(catalog.crs))
    agree, worst, cell_differ = 0, 0.0, []
    for i, (x, y, lon, lat) in enumerate(zip(xs, ys, lons, lats, strict=True)):
        got = set(catalog.saw(float(lon), float(lat))["key"].to_pylist())
        per_cell = set(catalog.saw(float(lon), float(lat), per_cell=True)["key"].to_pylist())
        truth = set()
        for key, (codes, transform) in rasters.items():
            col, row = ~transform * (x, y)
            r, c = int(np.floor(row)), int(np.floor(col))
            if 0 <= r < codes.shape[0] and 0 <= c < codes.shape[1] and codes[r, c] == 1:
                truth.add(key)
        agree += i < 1000 and got == truth
        if per_cell != truth:
            cell_differ.append((i, sorted(per_cell ^ truth)))
        for key in got - truth:
            codes, transform = rasters[key]
            rr, cc = np.nonzero(codes == 1)
            col, row = ~transform * (x, y)
            d = np.maximum(np.abs(cc + 0.5 - col), np.abs(rr + 0.5 - row)) - 0.5
            worst = max(worst, float(d.min()) if len(d) else np.inf)
    assert agree / 1000 >= 0.99
    assert worst <= 1.0
    assert not cell_differ, cell_differ[:3]


def test_saw_gives_the_range_and_refuses_bad_points(built: tuple[Path, Path]) -> None:
    cat, _ = built
    catalog = Catalog.open(cat)
    g = catalog.geometry[0]
    c = g.representative_point()
    lon, lat = map_to_lonlat([c.x], [c.y], json.dumps(catalog.crs))
    hits = catalog.saw(float(lon[0]), float(lat[0]))
    assert catalog.table["key"][0].as_py() in hits["key"].to_pylist()
    ranges = hits["range_m"].to_numpy()
    assert np.all(ranges <= 100.5) and np.all(np.diff(ranges) >= 0)
    for bad in [(float("nan"), 1.0), (10.0, 95.0), (400.0, 0.0)]:
        with pytest.raises(ArgumentError):
            catalog.saw(*bad)


def test_cli_refuses_a_malformed_point_in_one_line(
    built: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cat, _ = built
    assert main(["query", str(cat), "--saw", "77.4", "95"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "latitude 95.0 outside [-90, 90]" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["--saw", "77.4", "x"],
        ["--saw", "77.4"],
        ["--bbox", "1", "2", "3"],
        ["--near", "a", "b", "c"],
    ],
    ids=["not-a-number", "one-number", "three-numbers", "words"],
)
def test_cli_refuses_a_malformed_argument_in_one_line(
    built: tuple[Path, Path], capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    cat, _ = built
    with pytest.raises(SystemExit) as exit_:
        main(["query", str(cat), *argv])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mars-pairs query: error: argument --"), err


def test_cli_saw_per_cell_gives_the_api_answer(built: tuple[Path, Path], tmp_path: Path) -> None:
    cat, _ = built
    catalog = Catalog.open(cat)
    c = catalog.geometry[0].representative_point()
    lon, lat = map_to_lonlat([c.x], [c.y], json.dumps(catalog.crs))
    point = [f"{float(lon[0])!r}", f"{float(lat[0])!r}"]
    want = catalog.saw(float(lon[0]), float(lat[0]), per_cell=True)["key"].to_pylist()
    out = tmp_path / "saw.parquet"
    argv = ["query", str(cat), "--saw", *point, "--per-cell", "--format", "parquet", "--out"]
    assert main([*argv, str(out)]) == 0
    assert want and pq.read_table(out)["key"].to_pylist() == want
    assert main(["query", str(cat), "--overlaps", want[0], "--per-cell"]) == 2  # --saw only


def test_overlaps_ranked_by_iou_and_pairs_equal_brute_force(built: tuple[Path, Path]) -> None:
    cat, _ = built
    catalog = Catalog.open(cat)
    pairs = pq.read_table(cat / "pairs.parquet")
    geoms, keys = catalog.geometry, catalog.table["key"].to_pylist()
    brute = {
        tuple(sorted((keys[i], keys[j])))
        for i in range(len(keys))
        for j in range(i + 1, len(keys))
        if geoms[i] is not None
        and geoms[j] is not None
        and shapely.intersection(geoms[i], geoms[j]).area > 0
    }
    found = set(zip(pairs["key_a"].to_pylist(), pairs["key_b"].to_pylist(), strict=True))
    assert found == brute and len(found) > 0
    key = pairs["key_a"][0].as_py()
    ranked = catalog.overlaps(key)["iou"].to_numpy()
    assert len(ranked) > 0 and np.all(np.diff(ranked) <= 0)


def test_resume_after_a_kill_and_the_pool_write_the_same_bytes(
    mission: Path, built: tuple[Path, Path], tmp_path: Path
) -> None:
    """A catalogue killed after its first chunk (parts left as a kill leaves them) resumed,
    and one made by two worker processes, are byte for byte the one-worker catalogue."""
    cat, _ = built
    config = build_config(mission, tmp_path / "unused", **SECTIONS)
    resumed = tmp_path / "resumed"
    from mars_pairs.pipeline.catalog import run as catalog_run

    real = catalog_run._commit
    calls = []

    def commit_then_die(out, result, seen):  # type: ignore[no-untyped-def]
        if calls:
            raise KeyboardInterrupt  # killed after the first chunk committed
        calls.append(1)
        real(out, result, seen)

    catalog_run._commit = commit_then_die  # type: ignore[assignment]
    try:
        with pytest.raises(KeyboardInterrupt):
            run_catalog(config, resumed, progress=False)
    finally:
        catalog_run._commit = real  # type: ignore[assignment]
    assert (resumed / "parts" / "catalog-000000.parquet").is_file()
    summary = run_catalog(config, resumed, progress=False, resume=True)
    assert summary.chunks_resumed == 1
    assert _digests(resumed) == _digests(cat)
    pooled = tmp_path / "pooled"
    run_catalog(config, pooled, workers=2, progress=False)
    assert _digests(pooled) == _digests(cat)


def test_refuses_a_foreign_folder(mission: Path, tmp_path: Path) -> None:
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "notes.txt").write_text("mine")
    config = build_config(mission, tmp_path / "unused", **SECTIONS)
    with pytest.raises(ConfigError, match=r"notes\.txt"):
        run_catalog(config, tmp_path / "x", progress=False)
    assert (tmp_path / "x" / "notes.txt").read_text() == "mine"


def test_geopandas_reads_geometry_and_crs(built: tuple[Path, Path]) -> None:
    gpd = pytest.importorskip("geopandas")
    cat, _ = built
    frame = gpd.read_parquet(cat / "catalog.parquet")
    assert frame.geometry.name == "footprint"
    assert frame.crs is not None and "Mars" in frame.crs.name
    assert set(frame.geom_type.dropna()) <= {"Polygon", "MultiPolygon"}
    present = frame.geometry[~frame.geometry.isna()]
    assert len(present) and present.is_valid.all()


def test_manifest_filter_saw_on_a_dataset(built: tuple[Path, Path]) -> None:
    """``Manifest.filter(saw=(lon, lat))``: the rows whose manifest footprint holds the point."""
    _, ds = built
    table = pq.read_table(ds / "manifest.parquet")
    first = next(i for i, w in enumerate(table["footprint"].to_pylist()) if w is not None)
    geom = shapely.from_wkb(table["footprint"][first].as_py())
    c = geom.representative_point()
    crs = Manifest.open(ds).crs
    lon, lat = map_to_lonlat([c.x], [c.y], crs)
    got = Manifest.open(ds).filter(saw=(float(lon[0]), float(lat[0]))).to_table()
    expected = {
        k
        for k, w in zip(table["key"].to_pylist(), table["footprint"].to_pylist(), strict=True)
        if w is not None and shapely.from_wkb(w).intersects(c)
    }
    assert set(got["key"].to_pylist()) == expected and table["key"][first].as_py() in expected


def test_pairs_on_synthetic_footprints_match_brute_force() -> None:
    rng = np.random.default_rng(1)
    n = 300
    cx, cy = rng.uniform(0, 500, n), rng.uniform(0, 500, n)
    geoms = np.array(
        [shapely.Point(x, y).buffer(rng.uniform(5, 30)) for x, y in zip(cx, cy, strict=True)]
    )
    fp = Footprints(
        keys=np.array([f"k{i:04d}" for i in range(n)], dtype=object),
        geometry=geoms,
        area_m2=shapely.area(geoms),
        lon=cx / 59000,
        lat=cy / 59000,
        z=np.zeros(n),
        azimuth=rng.uniform(0, 360, n),
        position=np.array([str(i // 3) for i in range(n)], dtype=object),
    )
    table = pairs_table(fp, batch_rows=37)
    found = set(zip(table["key_a"].to_pylist(), table["key_b"].to_pylist(), strict=True))
    brute = {
        (f"k{i:04d}", f"k{j:04d}")
        for i in range(n)
        for j in range(i + 1, n)
        if geoms[i].intersection(geoms[j]).area > 0
    }
    assert found == brute
    iou = table["iou"].to_numpy()
    assert np.all((iou > 0) & (iou <= 1))


def test_saw_per_cell_reads_the_views_cells(built: tuple[Path, Path]) -> None:
    """``saw(per_cell=True)`` answers from ``view_cells``: an image is returned at every point
    of a cell its record sets, whatever the point's place in the cell, and a catalogue
    without the column is refused."""
    cat, _ = built
    catalog = Catalog.open(cat)
    record = catalog.table["view_cells"][0].as_py()
    box = np.unpackbits(np.frombuffer(record["bits"], dtype=np.uint8))
    box = box[: record["rows"] * record["cols"]].reshape(record["rows"], record["cols"])
    grid = Affine(record["dx"], 0.0, record["x0"], 0.0, record["dy"], record["y0"])
    key = catalog.table["key"][0].as_py()
    r, c = (int(v[0]) for v in np.nonzero(box))
    for fx, fy in ((0.02, 0.03), (0.97, 0.5), (0.5, 0.98)):
        x, y = grid * (c + fx, r + fy)
        lon, lat = map_to_lonlat([x], [y], json.dumps(catalog.crs))
        assert key in catalog.saw(float(lon[0]), float(lat[0]), per_cell=True)["key"].to_pylist()
    r, c = (int(v[0]) for v in np.nonzero(box == 0))
    x, y = grid * (c + 0.5, r + 0.5)
    lon, lat = map_to_lonlat([x], [y], json.dumps(catalog.crs))
    assert key not in catalog.saw(float(lon[0]), float(lat[0]), per_cell=True)["key"].to_pylist()
    bare = Catalog(cat, catalog.table.drop_columns(["view_cells"]), catalog.crs)
    with pytest.raises(ArgumentError, match="view_cells"):
        bare.saw(float(lon[0]), float(lat[0]), per_cell=True)


def _lonlat_box_on_map(
    catalog: Catalog, box: tuple[float, float, float, float]
) -> shapely.Geometry:
    """The lon/lat box as a map polygon, projected here with pyproj (edges of 200 points)."""
    from pyproj import CRS, Transformer

    w, s, e, n = box
    t = np.linspace(0.0, 1.0, 200)
    lon = np.concatenate([w + (e - w) * t, np.full(200, e), e + (w - e) * t, np.full(200, w)])
    lat = np.concatenate([np.full(200, s), s + (n - s) * t, np.full(200, n), n + (s - n) * t])
    crs = CRS.from_json_dict(catalog.crs)
    to_map = Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    x, y = to_map.transform(lon, lat)
    return shapely.Polygon(np.column_stack([x, y]))


def _boxes(catalog: Catalog) -> list[tuple[float, float, float, float]]:
    """Boxes around pieces of the catalogue: one around a footprint's representative point,
    one crossing a footprint's edge between its bbox and the polygon, one off the data."""
    crs = json.dumps(catalog.crs)
    boxes = []
    for g in catalog.geometry[:4]:
        if g is None:
            continue
        c = g.representative_point()
        lon, lat = map_to_lonlat([c.x], [c.y], crs)
        d = 2e-5
        boxes.append((float(lon[0]) - d, float(lat[0]) - d, float(lon[0]) + d, float(lat[0]) + d))
        x0, y0, x1, y1 = g.bounds  # a corner of the bbox: often outside the polygon
        (lo0, lo1), (la0, la1) = map_to_lonlat(
            [x0, x0 + (x1 - x0) / 4], [y0, y0 + (y1 - y0) / 4], crs
        )
        boxes.append((float(lo0), float(la0), float(lo1), float(la1)))
    lon, lat = map_to_lonlat([catalog.geometry[0].centroid.x], [0.0], crs)
    boxes.append((float(lon[0]) + 5, -10.0, float(lon[0]) + 6, -9.0))
    return boxes


def test_bbox_equals_an_independent_polygon_test(built: tuple[Path, Path]) -> None:
    cat, _ = built
    catalog = Catalog.open(cat)
    keys = catalog.table["key"].to_pylist()
    total = 0
    for box in _boxes(catalog):
        shape = _lonlat_box_on_map(catalog, box)
        want = [
            k
            for k, g in zip(keys, catalog.geometry, strict=True)
            if g is not None and g.intersects(shape)
        ]
        got = catalog.bbox(*box)["key"].to_pylist()
        assert got == want, box
        total += len(want)
    assert total > 0
    # the polygon, not its bbox: a box meeting a footprint's bbox only is no hit
    corner_only = [
        box
        for box in _boxes(catalog)
        if not catalog.bbox(*box).num_rows
        and any(
            g is not None and shapely.box(*g.bounds).intersects(_lonlat_box_on_map(catalog, box))
            for g in catalog.geometry
        )
    ]
    assert corner_only, "no test box meets a footprint's bbox but not the footprint"


def test_cli_bbox_gives_the_api_answer_and_refuses_bad_boxes(
    built: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat, _ = built
    catalog = Catalog.open(cat)
    box = _boxes(catalog)[0]
    want = catalog.bbox(*box)["key"].to_pylist()
    out = tmp_path / "box.parquet"
    argv = ["query", str(cat), "--bbox", *(repr(v) for v in box), "--format", "parquet"]
    assert main([*argv, "--out", str(out)]) == 0
    assert want and pq.read_table(out)["key"].to_pylist() == want
    capsys.readouterr()
    for bad, message in [
        (["1", "10", "2", "5"], "--bbox: S (10) is north of N (5)"),
        (["1", "-95", "2", "5"], "--bbox: S: latitude -95 is outside [-90, 90]"),
    ]:
        assert main(["query", str(cat), "--bbox", *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    with pytest.raises(ArgumentError, match=r"^bbox: S"):
        catalog.bbox(0.0, 10.0, 1.0, 5.0)
    with pytest.raises(ArgumentError, match=r"^bbox:"):
        catalog.bbox(float("nan"), 0.0, 1.0, 5.0)
    assert main(["query", str(cat), "--bbox", *map(str, box), "--sol", "1", "2"]) == 2
