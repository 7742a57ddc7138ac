"""ManifestFilter: its own checks, the loud checks against what a dataset holds, the old
coordinate order, ``by`` (rover, footprint, chip) against brute force over the geometries."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import shapely

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry.body import great_circle_m
from mars_pairs.geometry.frames import M2020_PLACES_CRS, lonlat_to_map, map_to_lonlat
from mars_pairs.store.filter import FilterWarning, ManifestFilter
from mars_pairs.store.query import Manifest
from tests.support.manifests import INSTRUMENTS, LAT0, LON0, write_place_manifest


@pytest.fixture(scope="module")
def placed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    root = tmp_path_factory.mktemp("placed")
    return root, write_place_manifest(root)


def _keys(m: Manifest) -> set[str]:
    return set(m.to_table(columns=["key"])["key"].to_pylist())


def _brute(table: pa.Table, keep: np.ndarray) -> set[str]:
    return set(np.asarray(table["key"].to_pylist())[np.asarray(keep, dtype=bool)])


def _quiet(m: Manifest, **kwargs: object) -> Manifest:
    with warnings.catch_warnings():
        warnings.simplefilter("error", FilterWarning)  # these queries are meant to hit
        return m.filter(**kwargs)


# -- the filter's own checks ---------------------------------------------------------------------
DRIFT = [
    ({"bbox_lonlat": (0, 10, 1, -10)}, r"bbox_lonlat: S \(10\) is north of N \(-10\)"),
    ({"near": (0, 0, -5)}, "near: RADIUS_M: expected a positive radius, got -5"),
    ({"sol": (9, 1)}, r"sol: FIRST \(9\) is after LAST \(1\)"),
    ({"bbox_lonlat": (0, -95, 1, 10)}, r"bbox_lonlat: S: latitude -95 is outside \[-90, 90\]"),
    ({"near": (77.4, 95, 10)}, "near: LAT: latitude 95 is outside"),
    ({"bbox_map": (10, 0, 0, 1)}, "bbox_map: expected XMIN <= XMAX"),
    ({"polygon_map": "POLYGON ((0 0, 1 1, 1 0, 0 1, 0 0))"}, "polygon_map: not a valid polygon"),
    ({"polygon_lonlat": "POINT (1 2)"}, "polygon_lonlat: expected a Polygon"),
    ({"polygon_map": "POLYGON EMPTY"}, "polygon_map: an empty geometry"),
    ({"polygon_lonlat": "POLYGON ((4e6 1e6, 4.1e6 1e6, 4e6 1.1e6, 4e6 1e6))"}, "not lon/lat"),
    ({"by": "camera"}, "by: expected one of rover, footprint, chip"),
    ({"nearby": (1, 2, 3)}, r"unknown filter argument\(s\) \['nearby'\]"),
]


@pytest.mark.parametrize(("kwargs", "match"), DRIFT)
def test_the_filter_refuses_what_the_cli_refuses(
    placed: tuple[Path, pa.Table], kwargs: dict, match: str
) -> None:
    with pytest.raises(ArgumentError, match=match) as err:
        Manifest.open(placed[0]).filter(**kwargs)
    assert "\n" not in str(err.value)
    with pytest.raises(ArgumentError, match=match):
        ManifestFilter.of(kwargs)


def test_a_filter_is_a_frozen_value_of_plain_types() -> None:
    spec = ManifestFilter.of(
        {"near": np.array([77.4, 18.4, 50.0]), "split": "train", "sol": (np.int64(3), 9)}
    )
    assert spec.near == (77.4, 18.4, 50.0) and spec.split == ("train",) and spec.sol == (3, 9)
    assert spec == ManifestFilter(near=(77.4, 18.4, 50), split=["train"], sol=[3, 9])
    with pytest.raises(AttributeError):
        spec.sol = (1, 2)  # type: ignore[misc]
    assert spec.given() == {
        "near": (77.4, 18.4, 50.0),
        "sol": (3, 9),
        "split": ("train",),
        "by": "rover",
    }


def test_one_filter_object_or_keywords(placed: tuple[Path, pa.Table]) -> None:
    m = Manifest.open(placed[0])
    spec = ManifestFilter(split="val", sol=(60, 90))
    assert _keys(m.filter(spec)) == _keys(m.filter(split="val", sol=(60, 90)))
    with pytest.raises(ArgumentError, match="not both"):
        m.filter(spec, split="val")


# -- loud: checked against what the dataset holds -------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"split": "training"}, "has no split 'training'; its splits are test, train, val"),
        ({"instrument": "NAVCAM"}, "its instruments are MCZ_LEFT, MCZ_RIGHT, NAVCAM_LEFT"),
        ({"instrument": ["MCZ_LEFT", "MAST_LEFT"]}, "has no instrument 'MAST_LEFT'"),
        ({"mission": "msl"}, "has no mission 'msl'; its missions are m2020"),
    ],
)
def test_values_the_dataset_lacks_are_errors_naming_the_valid_ones(
    placed: tuple[Path, pa.Table], kwargs: dict, match: str
) -> None:
    with pytest.raises(ArgumentError, match=match):
        Manifest.open(placed[0]).filter(**kwargs)


def test_values_the_dataset_holds_pass(placed: tuple[Path, pa.Table]) -> None:
    root, table = placed
    m = Manifest.open(root)
    got = _quiet(m, instrument=list(INSTRUMENTS[:2]), sol=(0, 60), split="val")
    inst = np.asarray(table["instrument"].to_pylist())
    sols, splits = table["sol"].to_numpy(), np.asarray(table["split"].to_pylist())
    keep = np.isin(inst, INSTRUMENTS[:2]) & (sols <= 60) & (splits == "val")
    assert _keys(got) == _brute(table, keep) and keep.sum() > 0


def test_configured_splits_are_known_without_rows(tmp_path: Path) -> None:
    import json

    write_place_manifest(tmp_path)
    (tmp_path / "dataset.json").write_text(json.dumps({"counts": {"by_split": {"buffer": 0}}}))
    assert len(Manifest.open(tmp_path).filter(split="buffer")) == 0  # known, empty: 0 rows
    with pytest.raises(ArgumentError, match="its splits are buffer, test, train, val"):
        Manifest.open(tmp_path).filter(split="holdout")


@pytest.mark.parametrize(
    "kwargs",
    [
        {"bbox_lonlat": (0.0, 0.0, 1.0, 1.0)},
        {"near": (10.0, 10.0, 100.0)},
        {"bbox_map": (0.0, 0.0, 10.0, 10.0)},
        {"polygon_map": "POLYGON ((0 0, 10 0, 10 10, 0 0))"},
        {"polygon_lonlat": "POLYGON ((0 0, 1 0, 1 1, 0 0))", "by": "footprint"},
        {"bbox_lonlat": (LON0 + 0.5, LAT0, LON0 + 0.6, LAT0 + 0.01), "by": "chip"},
    ],
)
def test_a_place_missing_the_dataset_warns_with_its_extent_in_both_units(
    placed: tuple[Path, pa.Table], kwargs: dict
) -> None:
    m = Manifest.open(placed[0])
    with pytest.warns(FilterWarning, match="misses the dataset") as caught:
        got = m.filter(**kwargs)
    text = str(caught[0].message)
    assert "lon 77.4" in text and "lat 18.4" in text and "map x 435" in text and " m" in text
    assert len(got) == 0


@pytest.mark.parametrize("sol", [(200, 300), (0, 51)])
def test_a_sol_range_outside_the_dataset_warns_with_its_sols(
    placed: tuple[Path, pa.Table], sol: tuple[int, int]
) -> None:
    with pytest.warns(FilterWarning, match=r"holds none of .*sols \(they are 52..140\): 0 rows"):
        assert len(Manifest.open(placed[0]).filter(sol=sol)) == 0
    assert len(_quiet(Manifest.open(placed[0]), sol=(0, 52))) > 0  # one sol in: quiet


def test_the_old_latitude_first_near_is_read_swapped_with_a_warning(
    placed: tuple[Path, pa.Table],
) -> None:
    m = Manifest.open(placed[0])
    expected = _quiet(m, near=(LON0, LAT0, 800.0))
    with pytest.warns(FilterWarning, match=r"read as LAT LON \(the old order\)"):
        old = m.filter(near=(LAT0, LON0, 800.0))
    assert 0 < len(expected) == len(old) and _keys(old) == _keys(expected)


def test_a_point_in_the_dataset_either_way_is_taken_as_given(tmp_path: Path) -> None:
    from mars_pairs.store.atomic import write_parquet_atomic
    from mars_pairs.store.manifest import MANIFEST_SCHEMA, rows_to_table

    # rovers at (10, 20) and (20, 10): both orders name a place the dataset holds
    rows = [
        {"key": k, "longitude": lon, "latitude": lat, "easting": 0.0, "northing": 0.0}
        for k, lon, lat in (("a", 10.0, 20.0), ("b", 20.0, 10.0))
    ]
    write_parquet_atomic(rows_to_table(rows, MANIFEST_SCHEMA), tmp_path / "manifest.parquet")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _keys(Manifest.open(tmp_path).filter(near=(10.0, 20.0, 1000.0))) == {"a"}


# -- what a place filter tests ---------------------------------------------------------------------
def _shapes(table: pa.Table, column: str) -> np.ndarray:
    return shapely.from_wkb(table[column].to_numpy(zero_copy_only=False))


@pytest.mark.parametrize("by", ["rover", "footprint", "chip"])
@pytest.mark.parametrize("seed", range(6))
def test_by_against_brute_force(placed: tuple[Path, pa.Table], by: str, seed: int) -> None:
    root, table = placed
    rng = np.random.default_rng(seed)
    x0, y0 = lonlat_to_map(LON0 + rng.uniform(-0.02, 0.01), LAT0 + rng.uniform(-0.02, 0.01),
                           M2020_PLACES_CRS)  # fmt: skip
    box = (
        float(x0),
        float(y0),
        float(x0) + rng.uniform(100, 900),
        float(y0) + rng.uniform(100, 900),
    )
    region = shapely.box(*box)
    if by == "rover":
        keep = shapely.intersects_xy(
            region, table["easting"].to_numpy(), table["northing"].to_numpy()
        )
    else:
        keep = shapely.intersects(
            region, _shapes(table, {"footprint": "footprint", "chip": "chip_box"}[by])
        )
    got = Manifest.open(root).filter(bbox_map=box, by=by)
    assert _keys(got) == _brute(table, keep)
    if by == "footprint":  # a footprint wedge starts at its rover point
        assert _keys(Manifest.open(root).filter(bbox_map=box)) <= _keys(got)


@pytest.mark.parametrize("by", ["footprint", "chip"])
@pytest.mark.parametrize("radius", [60.0, 300.0, 900.0])
def test_near_by_shape_is_the_great_circle_distance_to_the_shape(
    placed: tuple[Path, pa.Table], by: str, radius: float
) -> None:
    """Truth: each shape's boundary sampled every 0.5 m, to lon/lat, the least great-circle
    distance to the point (0 inside); rows within 0.1 % of the radius are left out."""
    root, table = placed
    lon, lat = LON0 + 0.004, LAT0 - 0.003
    cx, cy = lonlat_to_map(lon, lat, M2020_PLACES_CRS)
    shapes = _shapes(table, {"footprint": "footprint", "chip": "chip_box"}[by])
    dist = np.empty(len(shapes))
    for i, shape in enumerate(shapes):
        if shape.intersects(shapely.Point(float(cx), float(cy))):
            dist[i] = 0.0
            continue
        xy = shapely.get_coordinates(shapely.segmentize(shape.exterior, 0.5))
        plon, plat = map_to_lonlat(xy[:, 0], xy[:, 1], M2020_PLACES_CRS)
        dist[i] = great_circle_m(lat, lon, plat, plon).min()
    clear = np.abs(dist - radius) > radius * 1e-3
    got = _keys(Manifest.open(root).filter(near=(lon, lat, radius), by=by))
    keys = np.asarray(table["key"].to_pylist())
    assert got & set(keys[clear]) == set(keys[clear & (dist <= radius)])
    assert len(got) > 0


def test_lonlat_box_by_footprint_meets_the_projected_box(placed: tuple[Path, pa.Table]) -> None:
    root, table = placed
    w, s, e, n = LON0 - 0.005, LAT0 - 0.004, LON0 + 0.002, LAT0 + 0.001
    # truth: the box's edges sampled finely, projected with pyproj directly
    t = np.linspace(0.0, 1.0, 2001)
    lons = np.concatenate(
        [w + (e - w) * t, np.full_like(t, e), e - (e - w) * t, np.full_like(t, w)]
    )
    lats = np.concatenate(
        [np.full_like(t, s), s + (n - s) * t, np.full_like(t, n), n - (n - s) * t]
    )
    x, y = lonlat_to_map(lons, lats, M2020_PLACES_CRS)
    region = shapely.Polygon(np.column_stack([x, y]))
    keep = shapely.intersects(region, _shapes(table, "footprint"))
    got = Manifest.open(root).filter(bbox_lonlat=(w, s, e, n), by="footprint")
    assert _keys(got) == _brute(table, keep) and keep.sum() > 0


def test_polygon_lonlat_by_rover(placed: tuple[Path, pa.Table]) -> None:
    root, table = placed
    tri = shapely.Polygon(
        [(LON0 - 0.015, LAT0 - 0.015), (LON0 + 0.015, LAT0 - 0.01), (LON0, LAT0 + 0.015)]
    )
    keep = shapely.intersects_xy(tri, table["longitude"].to_numpy(), table["latitude"].to_numpy())
    got = _quiet(Manifest.open(root), polygon_lonlat=tri.wkt)
    assert _keys(got) == _brute(table, keep) and 0 < keep.sum() < len(keep)
    shifted = shapely.affinity.translate(tri, xoff=-360.0)  # longitudes match modulo 360
    assert _keys(_quiet(Manifest.open(root), polygon_lonlat=shifted)) == _keys(got)


def test_polygon_is_the_map_polygon(placed: tuple[Path, pa.Table]) -> None:
    root, _ = placed
    x, y = lonlat_to_map(LON0, LAT0, M2020_PLACES_CRS)
    square = shapely.box(float(x) - 500, float(y) - 500, float(x) + 500, float(y) + 500)
    m = Manifest.open(root)
    assert _keys(m.filter(polygon=square)) == _keys(m.filter(polygon_map=square.wkt)) != set()


# -- to_geopandas and repr ------------------------------------------------------------------------
def test_to_geopandas_has_the_geometries_and_the_crs(placed: tuple[Path, pa.Table]) -> None:
    pytest.importorskip("geopandas")
    from pyproj import CRS

    root, table = placed
    m = Manifest.open(root).filter(split="val")
    frame = m.to_geopandas()
    assert len(frame) == len(m) and frame.geometry.name == "footprint"
    assert CRS.from_user_input(frame.crs).equals(CRS.from_user_input(M2020_PLACES_CRS))
    assert set(frame.geom_type) == {"Polygon"}
    first = frame.sort_values("key").iloc[0]
    row = next(r for r in table.to_pylist() if r["key"] == first["key"])
    assert first["footprint"].equals(shapely.from_wkb(row["footprint"]))
    assert m.to_geopandas("rover_point").geometry.name == "rover_point"
    with pytest.raises(ArgumentError, match="geometry: expected one of"):
        m.to_geopandas("bbox")


def test_repr_shows_path_rows_splits_and_columns(placed: tuple[Path, pa.Table]) -> None:
    root, _ = placed
    text = repr(Manifest.open(root))
    assert str(root) in text and "400 rows" in text
    assert "splits: test 133, train 134, val 133" in text and "columns: key, mission" in text
    assert "filtered" in repr(Manifest.open(root).filter(split="val"))
