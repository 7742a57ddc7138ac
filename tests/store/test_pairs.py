"""Pairs of overlapping footprints (store.pairs) against an all-pairs GEOS loop, and the
overlap kernel (kernels.overlap) against areas known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest
import shapely

from mars_pairs.kernels.overlap import intersection_areas
from mars_pairs.store import pairs
from mars_pairs.store.pairs import Footprints, pairs_table


def _ragged(geoms: list[shapely.Geometry]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _, xy, (rings, geom_rings) = shapely.to_ragged_array(shapely.orient_polygons(geoms))
    return xy, rings.astype(np.int64), geom_rings.astype(np.int64)


def test_kernel_areas_known_in_closed_form() -> None:
    """A unit square and itself turned 45 degrees about its centre meet in a regular
    octagon of area 2 (sqrt 2 - 1); two squares offset by (0.5, 0.25) in 0.75; a square with
    a hole and a larger square round it in 1 - 0.25; far apart in 0. Offsets of a million map
    units change nothing."""
    for off in (0.0, 1.0e6):
        square = shapely.box(off, off, off + 1, off + 1)
        turned = shapely.affinity.rotate(square, 45.0, origin="center")
        shifted = shapely.affinity.translate(square, 0.5, 0.25)
        holed = shapely.Polygon(
            square.exterior.coords,
            [[(off + 0.25, off + 0.25), (off + 0.75, off + 0.25), (off + 0.75, off + 0.75),
              (off + 0.25, off + 0.75)]],
        )  # fmt: skip
        through = shapely.box(off - 0.1, off - 0.1, off + 1.1, off + 1.1)
        far = shapely.box(off + 5, off + 5, off + 6, off + 6)
        xy, rings, geom_rings = _ragged([square, turned, shifted, holed, through, far])
        area, ok = intersection_areas(
            xy, rings, geom_rings, np.array([0, 0, 3, 0]), np.array([1, 2, 4, 5])
        )
        assert ok.all()
        want = [2 * (math.sqrt(2) - 1), 0.375, 0.75, 0.0]
        np.testing.assert_allclose(area, want, rtol=1e-9, atol=1e-12)


def test_kernel_leaves_touching_pairs_to_geos() -> None:
    """Boxes sharing an edge, a vertex, or one edge lying along the other's: not answered."""
    a = shapely.box(0, 0, 1, 1)
    xy, rings, geom_rings = _ragged(
        [a, shapely.box(1, 0, 2, 1), shapely.box(1, 1, 2, 2), shapely.box(0.5, 0, 2, 1)]
    )
    _, ok = intersection_areas(xy, rings, geom_rings, np.array([0, 0, 0]), np.array([1, 2, 3]))
    assert not ok.any()


def _footprints() -> tuple[Footprints, list[shapely.Geometry | None]]:
    """Random star-shaped polygons (non-convex), holed polygons and multipolygons at map
    offsets in the millions, with grid-aligned boxes sharing edges and vertices, an exact
    duplicate, a touching pair and missing footprints among them."""
    rng = np.random.default_rng(7)
    x0, y0 = 3.1e6, 1.05e6
    geoms: list[shapely.Geometry | None] = []
    for _ in range(140):
        cx, cy = x0 + rng.uniform(0, 400), y0 + rng.uniform(0, 400)
        k = int(rng.integers(5, 15))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        rad = rng.uniform(5, 40, k)
        star = shapely.Polygon(np.c_[cx + rad * np.cos(ang), cy + rad * np.sin(ang)])
        star = shapely.make_valid(star) if not star.is_valid else star
        geoms.append(star)
    for i in range(30):
        cx, cy = x0 + rng.uniform(0, 400), y0 + rng.uniform(0, 400)
        outer = shapely.Point(cx, cy).buffer(rng.uniform(10, 30), 8)
        holed = outer.difference(shapely.Point(cx, cy).buffer(5, 4))
        island = shapely.Point(cx + 60, cy).buffer(8, 4)
        geoms.append(holed if i % 2 else shapely.MultiPolygon([holed, island]))
    for i in range(4):
        for j in range(4):
            geoms.append(shapely.box(x0 + 10 * i, y0 + 10 * j, x0 + 10 * i + 10, y0 + 10 * j + 10))
    geoms += [geoms[0], None, None, shapely.box(x0 + 40, y0, x0 + 50, y0 + 10)]
    geoms = [g if g is None or not g.is_empty else None for g in geoms]
    n = len(geoms)
    arr = np.empty(n, dtype=object)
    arr[:] = geoms
    area = np.array([np.nan if g is None else g.area * 1.01 for g in geoms])
    fp = Footprints(
        keys=np.array([f"k{(n - i) * 7 % 1000:04d}-{i}" for i in range(n)], dtype=object),
        geometry=arr,
        area_m2=area,
        lon=rng.uniform(77, 77.01, n),
        lat=rng.uniform(18, 18.01, n),
        z=rng.uniform(-2600, -2500, n),
        azimuth=rng.uniform(0, 360, n),
        position=np.array([str(i // 3) for i in range(n)], dtype=object),
        split=np.array([("train", "val", "test")[i % 3] for i in range(n)], dtype=object),
    )
    return fp, geoms


@pytest.mark.parametrize("kernel", [True, False])
def test_pairs_equal_an_all_pairs_geos_loop(kernel: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every pair i < j with a positive GEOS intersection area, none other; the areas (true:
    times each footprint's scale, here 1.01), IoU and splits as the loop computes them; the
    same table whatever the block size and thread count. With the kernel answering the
    small pairs, and with every area from GEOS (fewer footprints than
    ``KERNEL_MIN_FOOTPRINTS``)."""
    monkeypatch.setattr(pairs, "KERNEL_MIN_FOOTPRINTS", 0 if kernel else 10**9)
    fp, geoms = _footprints()
    table = pairs_table(fp, batch_rows=17, threads=1)
    brute: dict[tuple[str, str], tuple[float, float, str, str]] = {}
    for i, gi in enumerate(geoms):
        for j in range(i + 1, len(geoms)):
            gj = geoms[j]
            if gi is None or gj is None:
                continue
            inter = gi.intersection(gj).area
            if inter > 0:
                ki, kj = str(fp.keys[i]), str(fp.keys[j])
                si, sj = str(fp.split[i]), str(fp.split[j])  # type: ignore[index]
                (ka, sa), (kb, sb) = sorted([(ki, si), (kj, sj)])
                iou = inter / (gi.area + gj.area - inter)
                brute[(ka, kb)] = (inter * 1.01, iou, sa, sb)
    got = table.to_pylist()
    assert len(got) == len(brute) > 200
    for row in got:
        inter, iou, sa, sb = brute[(row["key_a"], row["key_b"])]
        assert math.isclose(row["intersection_m2"], inter, rel_tol=1e-9)
        assert math.isclose(row["iou"], iou, rel_tol=1e-9)
        assert (row["split_a"], row["split_b"], row["cross_split"]) == (sa, sb, sa != sb)
    for rows, threads in ((4096, 2), (5, 3)):
        assert pairs_table(fp, batch_rows=rows, threads=threads).equals(table)
    assert table.schema.field("cross_split").type == pa.bool_()
