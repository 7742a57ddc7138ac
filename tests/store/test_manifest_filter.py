"""Manifest filters agree with brute force over random queries; predicates prune row groups."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from mars_pairs.geometry.body import great_circle_m
from mars_pairs.geometry.frames import M2020_PLACES_CRS, lonlat_to_map
from mars_pairs.store.atomic import write_parquet_atomic
from mars_pairs.store.geoparquet import geo_metadata
from mars_pairs.store.manifest import MANIFEST_SCHEMA, rows_to_table
from mars_pairs.store.query import Manifest
from mars_pairs.store.splits import hilbert_index

N = 3000
LON0, LAT0 = 77.45, 18.44


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    rng = np.random.default_rng(7)
    lon = LON0 + rng.uniform(-0.05, 0.05, N)
    lat = LAT0 + rng.uniform(-0.05, 0.05, N)
    x, y = lonlat_to_map(lon, lat, M2020_PLACES_CRS)
    order = np.argsort(hilbert_index(x, y, (x.min(), y.min(), x.max(), y.max())), kind="stable")
    rows = [
        {
            "key": f"k{i:05d}",
            "mission": ["m2020", "msl"][i % 2],
            "instrument": ["MCZ_LEFT", "MCZ_RIGHT", "MAST_LEFT"][i % 3],
            "sol": int(i % 700),
            "split": ["train", "val", "test"][i % 3],
            "latitude": float(lat[i]),
            "longitude": float(lon[i]),
            "easting": float(x[i]),
            "northing": float(y[i]),
        }
        for i in order
    ]
    table = rows_to_table(rows, MANIFEST_SCHEMA)
    table = table.replace_schema_metadata(geo_metadata(M2020_PLACES_CRS, None))
    root = tmp_path_factory.mktemp("manifest")
    write_parquet_atomic(table, root / "manifest.parquet", row_group_size=200)
    return root, table


def _keys(m: Manifest) -> set[str]:
    return set(m.to_table(columns=["key"]).column("key").to_pylist())


def _brute(table: pa.Table, keep: np.ndarray) -> set[str]:
    return set(np.asarray(table.column("key").to_pylist())[keep])


coords = st.floats(-0.06, 0.06)


@settings(max_examples=60, deadline=None)
@given(a=coords, b=coords, c=coords, d=coords)
def test_bbox_lonlat(
    dataset: tuple[Path, pa.Table], a: float, b: float, c: float, d: float
) -> None:
    root, table = dataset
    w, e = sorted((LON0 + a, LON0 + b))
    s, n = sorted((LAT0 + c, LAT0 + d))
    lon, lat = table["longitude"].to_numpy(), table["latitude"].to_numpy()
    keep = (lon >= w) & (lon <= e) & (lat >= s) & (lat <= n)
    assert _keys(Manifest.open(root).filter(bbox_lonlat=(w, s, e, n))) == _brute(table, keep)


@settings(max_examples=60, deadline=None)
@given(a=coords, c=coords, radius=st.floats(10.0, 4000.0))
def test_near_great_circle(
    dataset: tuple[Path, pa.Table], a: float, c: float, radius: float
) -> None:
    root, table = dataset
    lat, lon = LAT0 + c, LON0 + a
    dist = great_circle_m(lat, lon, table["latitude"].to_numpy(), table["longitude"].to_numpy())
    keep = dist <= radius
    assert _keys(Manifest.open(root).filter(near=(lon, lat, radius))) == _brute(table, keep)


@settings(max_examples=40, deadline=None)
@given(
    a=coords,
    c=coords,
    size=st.floats(100.0, 3000.0),
    sol=st.integers(0, 699),
    split=st.sampled_from(["train", "val", "test"]),
)
def test_polygon_with_attributes(
    dataset: tuple[Path, pa.Table], a: float, c: float, size: float, sol: int, split: str
) -> None:
    root, table = dataset
    cx, cy = lonlat_to_map(LON0 + a, LAT0 + c, M2020_PLACES_CRS)
    tri = shapely.Polygon([(cx - size, cy - size), (cx + size, cy - size), (cx, cy + size)])
    x, y = table["easting"].to_numpy(), table["northing"].to_numpy()
    sols = table["sol"].to_numpy()
    splits = np.asarray(table["split"].to_pylist())
    keep = shapely.intersects_xy(tri, x, y) & (sols >= sol) & (sols <= sol + 50) & (splits == split)
    got = Manifest.open(root).filter(polygon=tri.wkt, sol=(sol, sol + 50), split=split)
    assert _keys(got) == _brute(table, keep)
    assert len(got) == int(keep.sum())


@settings(max_examples=40, deadline=None)
@given(a=coords, b=coords, c=coords, d=coords, mission=st.sampled_from(["m2020", "msl"]))
def test_bbox_map_and_mission(
    dataset: tuple[Path, pa.Table], a: float, b: float, c: float, d: float, mission: str
) -> None:
    root, table = dataset
    x0, y0 = lonlat_to_map(LON0 + min(a, b), LAT0 + min(c, d), M2020_PLACES_CRS)
    x1, y1 = lonlat_to_map(LON0 + max(a, b), LAT0 + max(c, d), M2020_PLACES_CRS)
    x, y = table["easting"].to_numpy(), table["northing"].to_numpy()
    missions = np.asarray(table["mission"].to_pylist())
    keep = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (missions == mission)
    got = Manifest.open(root).filter(bbox_map=(float(x0), float(y0), float(x1), float(y1)))
    assert _keys(got.filter(mission=mission)) == _brute(table, keep)


def test_filters_compose_and_leave_the_original_alone(dataset: tuple[Path, pa.Table]) -> None:
    root, table = dataset
    full = Manifest.open(root)
    train = full.filter(split="train")
    assert len(full) == N
    assert len(train) == sum(s == "train" for s in table["split"].to_pylist())
    assert len(train.filter(mission="msl")) < len(train)


def test_location_filter_skips_row_groups(dataset: tuple[Path, pa.Table]) -> None:
    import pyarrow.dataset as ds

    root, _ = dataset
    small = (LON0 - 0.005, LAT0 - 0.005, LON0 + 0.005, LAT0 + 0.005)
    fragment = next(iter(ds.dataset(root / "manifest.parquet").get_fragments()))
    expr = (
        (ds.field("longitude") >= small[0])
        & (ds.field("longitude") <= small[2])
        & (ds.field("latitude") >= small[1])
        & (ds.field("latitude") <= small[3])
    )
    kept = fragment.split_by_row_group(filter=expr)
    total = fragment.metadata.num_row_groups
    assert len(kept) < total / 3, (len(kept), total)  # Hilbert order makes statistics useful
    assert len(Manifest.open(root).filter(bbox_lonlat=small)) > 0


def test_crs_from_geoparquet_metadata(dataset: tuple[Path, pa.Table]) -> None:
    from pyproj import CRS

    crs = Manifest.open(dataset[0]).crs
    assert crs is not None
    assert CRS.from_json(crs).equals(CRS.from_user_input(M2020_PLACES_CRS))


@pytest.fixture(scope="module")
def antimeridian(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    """Rover positions straddling 180 degrees, stored in -180..180 (as PLACES gives them)."""
    rng = np.random.default_rng(11)
    lon = (180.0 + rng.uniform(-0.05, 0.05, 800) + 180.0) % 360.0 - 180.0
    lat = rng.uniform(-0.05, 0.05, 800)
    rows = [
        {"key": f"a{i:04d}", "latitude": float(lat[i]), "longitude": float(lon[i])}
        for i in np.argsort(lon)
    ]
    table = rows_to_table(rows, MANIFEST_SCHEMA)
    root = tmp_path_factory.mktemp("antimeridian")
    write_parquet_atomic(table, root / "manifest.parquet", row_group_size=100)
    return root, table


@settings(max_examples=60, deadline=None)
@given(a=st.floats(-0.06, 0.06), b=st.floats(-0.06, 0.06), shift=st.sampled_from([0, 360, -360]))
def test_bbox_lonlat_across_the_180th_meridian(
    antimeridian: tuple[Path, pa.Table], a: float, b: float, shift: float
) -> None:
    root, table = antimeridian
    # from west eastward to east; west > east once normalised means crossing 180
    west, east = 180.0 + min(a, b) + shift, 180.0 + max(a, b) + shift
    west = (west + 180.0) % 360.0 - 180.0
    east = (east + 180.0) % 360.0 - 180.0
    lon = table["longitude"].to_numpy()
    keep = (lon - west) % 360.0 <= (east - west) % 360.0
    got = _keys(Manifest.open(root).filter(bbox_lonlat=(west, -1.0, east, 1.0)))
    assert got == _brute(table, keep)


@settings(max_examples=40, deadline=None)
@given(lon=st.floats(179.9, 180.1), radius=st.floats(1.0, 4000.0))
def test_near_across_the_180th_meridian(
    antimeridian: tuple[Path, pa.Table], lon: float, radius: float
) -> None:
    root, table = antimeridian
    lats, lons = table["latitude"].to_numpy(), table["longitude"].to_numpy()
    keep = great_circle_m(0.0, lon, lats, lons) <= radius
    assert _keys(Manifest.open(root).filter(near=(lon, 0.0, radius))) == _brute(table, keep)


def test_queries_at_180_reach_both_sides(antimeridian: tuple[Path, pa.Table]) -> None:
    root, _ = antimeridian
    for m in (
        Manifest.open(root).filter(near=(180.0, 0.0, 2000.0)),
        Manifest.open(root).filter(bbox_lonlat=(179.98, -1.0, -179.98, 1.0)),
        Manifest.open(root).filter(bbox_lonlat=(179.98, -1.0, 180.02, 1.0)),  # 0..360 style
    ):
        lon = m.to_table(columns=["longitude"])["longitude"].to_numpy()
        assert (lon > 179.0).any() and (lon < -179.0).any()


# -- arguments as users pass them ---------------------------------------------------------------
def _as_numpy64(v: float) -> object:
    return np.float64(v)


def _as_numpy32(v: float) -> object:
    return np.float32(v)


def _as_pandas(v: float) -> object:
    import pandas as pd

    return pd.Series([v], dtype="Float64").iloc[0]  # a pandas nullable scalar


@pytest.mark.parametrize("scalar", [_as_numpy64, _as_numpy32, _as_pandas])
def test_every_filter_takes_numpy_and_pandas_scalars(
    dataset: tuple[Path, pa.Table], scalar: object
) -> None:
    import pandas as pd

    root, _ = dataset
    convert = scalar  # type: ignore[assignment]
    box = (LON0 - 0.02, LAT0 - 0.01, LON0 + 0.01, LAT0 + 0.02)
    x, y = lonlat_to_map([box[0], box[2]], [box[1], box[3]], M2020_PLACES_CRS)
    cases = {
        "bbox_lonlat": box,
        "bbox_map": (float(x[0]), float(y[0]), float(x[1]), float(y[1])),
        "near": (LON0, LAT0, 900.0),
        "sol": (100, 250),
    }
    m = Manifest.open(root)
    for name, plain in cases.items():
        expected = _keys(m.filter(**{name: plain}))
        assert 0 < len(expected) < N, name
        for value in (
            tuple(convert(v) for v in plain),  # type: ignore[operator]
            np.asarray(plain),
            pd.Series(plain),
            list(plain),
        ):
            if name == "sol" and isinstance(value, tuple):
                value = tuple(np.int64(v) for v in plain)
            assert _keys(m.filter(**{name: value})) == expected, (name, value)
    for name, plain in (("mission", "msl"), ("split", ["val", "test"])):
        expected = _keys(m.filter(**{name: plain}))
        for value in (np.str_("msl"), np.array(["val", "test"]), pd.Series(["val", "test"])):
            if (name == "mission") == isinstance(value, np.str_):
                assert _keys(m.filter(**{name: value})) == expected, (name, value)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bbox_lonlat": (1.0, 2.0, 3.0)}, "bbox_lonlat: expected 4 numbers, got 3"),
        ({"bbox_lonlat": (1.0, 2.0, "3", 4.0)}, "bbox_lonlat: expected a number"),
        ({"near": (18.0, 77.0, float("nan"))}, "near: expected a finite number"),
        ({"near": "18 77 10"}, "near: expected 3 numbers"),
        ({"sol": (1.5, 3)}, "sol: expected whole numbers"),
        ({"sol": (True, 3)}, "sol: expected a number"),
        ({"mission": 3}, "mission: expected a string"),
        ({"split": ["train", 1]}, "split: expected strings"),
        ({"polygon": "POLYGON ((0 0, 1"}, "polygon_map: not WKT"),
        ({"polygon": 12}, "polygon_map: expected a shapely geometry"),
    ],
)
def test_bad_filter_arguments_name_the_argument(
    dataset: tuple[Path, pa.Table], kwargs: dict, match: str
) -> None:
    from mars_pairs.errors import ArgumentError, MarsPairsError

    root, _ = dataset
    with pytest.raises(ArgumentError, match=match) as err:
        Manifest.open(root).filter(**kwargs)
    assert isinstance(err.value, MarsPairsError)
    assert isinstance(err.value, TypeError) and isinstance(err.value, ValueError)
