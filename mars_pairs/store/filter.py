"""What a manifest query asks: :class:`ManifestFilter`, one validated value shared by
:meth:`mars_pairs.Manifest.filter`, the torch datasets and ``mars-pairs query``.

Coordinates are always longitude first: ``bbox_lonlat`` is (west, south, east, north) in
degrees east/north (planetocentric, Mars sphere), ``near`` is (lon, lat, radius_m),
``polygon_lonlat`` a lon/lat geometry; ``bbox_map`` (xmin, ymin, xmax, ymax) and
``polygon_map`` are in the dataset CRS (map metres). ``by`` names what a place filter tests:
``rover`` (the rover position, a point: the default), ``footprint`` (the viewshed footprint
polygon intersects the place) or ``chip`` (the orbital chip's square intersects the place).

The filter's own values are checked when it is made (a bad box, a negative radius, a sol
range backwards: :class:`~mars_pairs.errors.ArgumentError` with one line naming the
argument). :func:`checked` then holds it against what a dataset holds
(:class:`DatasetValues`): a mission, instrument or split the dataset does not have is an
ArgumentError listing the valid values (names are a closed set: an unknown one is a typo);
a sol range outside its sols, or a place filter that misses the dataset's extent, is a
:class:`FilterWarning` giving the dataset's sols or its extent in lon/lat and map metres (a
range may rightly be empty: the query is valid, its answer 0 rows); a ``near`` point given
in the old latitude-first order is read swapped, with a FilterWarning, when only the swapped
point lies in the dataset's extent.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry.body import MARS_RADIUS_M, great_circle_m
from mars_pairs.store.filter_args import BY as BY
from mars_pairs.store.filter_args import By as By
from mars_pairs.store.filter_args import geometry, integers, numbers, strings

#: the place filters, each at most once
PLACE_KEYS = ("bbox_lonlat", "bbox_map", "near", "polygon_lonlat", "polygon_map")
#: the manifest columns naming a sample's mission, instrument, split
NAME_KEYS = ("mission", "instrument", "split")
#: vertices of the polygon standing for a ``near`` circle when a footprint or chip is tested
CIRCLE_VERTICES = 256
#: longest edge (degrees) of a lon/lat shape before it is projected to the map
DENSIFY_DEG = 0.01


class FilterWarning(UserWarning):
    """A filter that is valid but surely wrong or empty (it misses the dataset's extent, or a
    point given latitude first was read swapped); the message says which, and the extent."""


Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class ManifestFilter:
    """A validated manifest query: every given predicate must hold (none: every row).

    ``bbox_lonlat``: (west, south, east, north) degrees east/north, south <= north, latitudes
    in [-90, 90]; west > east crosses the 180th meridian (longitudes match modulo 360, so
    -180..180 and 0..360 data alike). ``bbox_map``: (xmin, ymin, xmax, ymax) in the dataset
    CRS, min <= max. ``near``: (lon, lat, radius_m), radius > 0, great circle on the Mars
    sphere. ``polygon_lonlat`` / ``polygon_map``: a valid (Multi)Polygon, shapely or WKT, in
    lon/lat degrees / the dataset CRS. ``mission``, ``instrument``, ``split``: a value or a
    list of values (any of them). ``sol``: inclusive (first, last), first <= last. ``by``:
    what a place filter tests, ``rover`` (default), ``footprint`` or ``chip``.

    Numbers may be Python, numpy or pandas scalars (the tuples numpy arrays or pandas
    Series); they are stored as floats (ints for ``sol``), names as tuples of str and
    polygons as shapely geometries. Anything else, a NaN, a bad size or range is an
    ArgumentError naming the argument.
    """

    bbox_lonlat: Box | None = None
    bbox_map: Box | None = None
    near: tuple[float, float, float] | None = None
    polygon_lonlat: Any = None
    polygon_map: Any = None
    mission: tuple[str, ...] | None = None
    instrument: tuple[str, ...] | None = None
    sol: tuple[int, int] | None = None
    split: tuple[str, ...] | None = None
    by: By = "rover"

    #: the keyword arguments a filter takes (``polygon``: the map-units ``polygon_map``)
    KEYS: ClassVar[tuple[str, ...]] = (
        "bbox_lonlat",
        "bbox_map",
        "near",
        "polygon_lonlat",
        "polygon_map",
        "polygon",
        "mission",
        "instrument",
        "sol",
        "split",
        "by",
    )

    def __post_init__(self) -> None:
        put = object.__setattr__
        if self.bbox_lonlat is not None:
            w, s, e, n = numbers(self.bbox_lonlat, 4, "bbox_lonlat")
            _latitude("bbox_lonlat", "S", s)
            _latitude("bbox_lonlat", "N", n)
            if s > n:
                raise ArgumentError(
                    f"bbox_lonlat: S ({s:g}) is north of N ({n:g}); the order is W S E N"
                )
            put(self, "bbox_lonlat", (w, s, e, n))
        if self.bbox_map is not None:
            x0, y0, x1, y1 = numbers(self.bbox_map, 4, "bbox_map")
            if x0 > x1 or y0 > y1:
                raise ArgumentError(
                    f"bbox_map: expected XMIN <= XMAX and YMIN <= YMAX, got {(x0, y0, x1, y1)}"
                )
            put(self, "bbox_map", (x0, y0, x1, y1))
        if self.near is not None:
            lon, lat, radius = numbers(self.near, 3, "near")
            _latitude("near", "LAT", lat, hint=" (the order is LON LAT RADIUS_M)")
            if not radius > 0.0:
                raise ArgumentError(f"near: RADIUS_M: expected a positive radius, got {radius:g}")
            put(self, "near", (lon, lat, radius))
        for name in ("polygon_lonlat", "polygon_map"):
            value = getattr(self, name)
            if value is not None:
                put(self, name, _polygon(value, name))
        if self.polygon_lonlat is not None:
            _degrees(self.polygon_lonlat)
        for name in NAME_KEYS:
            value = getattr(self, name)
            if value is not None:
                put(self, name, tuple(strings(value, name)))
        if self.sol is not None:
            first, last = integers(self.sol, 2, "sol")
            if first > last:
                raise ArgumentError(f"sol: FIRST ({first}) is after LAST ({last})")
            put(self, "sol", (first, last))
        if self.by not in BY:
            raise ArgumentError(f"by: expected one of {', '.join(BY)}, got {self.by!r}")

    @classmethod
    def of(cls, arguments: Mapping[str, Any]) -> ManifestFilter:
        """The filter of keyword ``arguments`` (unset ones None); an unknown name is an
        ArgumentError listing the known ones. ``polygon`` is ``polygon_map`` (map units)."""
        unknown = sorted(set(arguments) - set(cls.KEYS))
        if unknown:
            known = ", ".join(k for k in cls.KEYS if k != "polygon")
            raise ArgumentError(f"unknown filter argument(s) {unknown}; the filters are {known}")
        given = {k: v for k, v in arguments.items() if v is not None}
        if "polygon" in given:
            if "polygon_map" in given:
                raise ArgumentError("polygon: give polygon_map or polygon (the same), not both")
            given["polygon_map"] = given.pop("polygon")
        return cls(**given)

    @property
    def places(self) -> tuple[str, ...]:
        """The place filters this filter sets."""
        return tuple(k for k in PLACE_KEYS if getattr(self, k) is not None)

    def given(self) -> dict[str, Any]:
        """The set arguments (``by`` when a place filter is set), for messages and reprs."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "by"}
        out = {k: v for k, v in out.items() if v is not None}
        if self.places:
            out["by"] = self.by
        return out


def _latitude(name: str, part: str, lat: float, hint: str = "") -> None:
    if not -90.0 <= lat <= 90.0:
        raise ArgumentError(f"{name}: {part}: latitude {lat:g} is outside [-90, 90]{hint}")


def _polygon(value: Any, name: str) -> Any:
    """A non-empty, valid Polygon or MultiPolygon with finite coordinates (shapely or WKT)."""
    import shapely

    if getattr(value, "is_empty", False) or (
        isinstance(value, str) and value.strip().upper().endswith("EMPTY")
    ):
        raise ArgumentError(f"{name}: an empty geometry ({value!s}) selects nothing")
    try:
        geom = geometry(value)
    except ArgumentError as exc:
        raise ArgumentError(str(exc).replace("polygon:", f"{name}:", 1)) from None
    if geom.geom_type not in ("Polygon", "MultiPolygon"):
        raise ArgumentError(f"{name}: expected a Polygon or MultiPolygon, got {geom.geom_type}")
    if not np.isfinite(shapely.get_coordinates(geom)).all():
        raise ArgumentError(f"{name}: coordinates must be finite numbers")
    if not shapely.is_valid(geom):
        raise ArgumentError(f"{name}: not a valid polygon ({shapely.is_valid_reason(geom)})")
    return geom


def _degrees(geom: Any) -> None:
    """ArgumentError when a lon/lat polygon's coordinates are not degrees (map units?)."""
    x0, y0, x1, y1 = geom.bounds
    if x0 < -360.0 or x1 > 360.0 or y0 < -90.0 or y1 > 90.0:
        raise ArgumentError(
            f"polygon_lonlat: coordinates ({x0:g}, {y0:g})..({x1:g}, {y1:g}) are not lon/lat "
            "degrees (map units? pass them as polygon_map, --polygon-map)"
        )


# -- what a dataset holds ----------------------------------------------------------------------
@dataclass
class DatasetValues:
    """What a dataset's manifest holds, read lazily (each column once) from its rows:
    ``names(column)`` the distinct missions, instruments or splits (splits with those the
    dataset.json configures: ``extra_splits()``), ``sols()`` the (first, last) sol,
    ``extent(by)`` the lon/lat and map boxes of the rover points, footprints or chips.

    ``scan(columns)`` reads manifest columns (the whole dataset, unfiltered); ``crs`` is the
    dataset CRS (text; None when unknown); ``where`` names the dataset in messages."""

    scan: Callable[[list[str]], pa.Table]
    crs: str | None
    where: str
    extra_splits: Callable[[], Iterable[str]] = tuple
    _cache: dict[str, Any] = field(default_factory=dict)

    def _get(self, key: str, compute: Callable[[], Any]) -> Any:
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    def names(self, column: str) -> list[str]:
        """The distinct non-null values of ``column`` (sorted)."""
        import pyarrow.compute as pc

        def compute() -> list[str]:
            values = pc.unique(self.scan([column])[column]).to_pylist()
            found = {str(v) for v in values if v is not None}
            if column == "split":
                found |= {str(v) for v in self.extra_splits()}
            return sorted(found)

        return list(self._get(f"names:{column}", compute))

    def sols(self) -> tuple[int, int] | None:
        """(first, last) sol of the rows; None for no row with a sol."""

        def compute() -> tuple[int, int] | None:
            import pyarrow.compute as pc

            mm = pc.min_max(self.scan(["sol"])["sol"]).as_py()
            return None if mm["min"] is None else (int(mm["min"]), int(mm["max"]))

        return self._get("sols", compute)  # type: ignore[no-any-return]  # (a cache of Any)

    def extent(self, by: By) -> tuple[Box | None, Box | None]:
        """(lon/lat box (W, S, E, N) degrees, map box (xmin, ymin, xmax, ymax) in the dataset
        CRS) of what ``by`` tests over every row; None where unknown (no rows, no CRS)."""
        found = self._get(f"extent:{by}", lambda: self._extent(by))
        return found  # type: ignore[no-any-return]  # (a cache of Any)

    def _extent(self, by: By) -> tuple[Box | None, Box | None]:
        import pyarrow.compute as pc

        def box(table: pa.Table, names: tuple[str, str, str, str]) -> Box | None:
            lo = [pc.min_max(table[n]).as_py()["min"] for n in names[:2]]
            hi = [pc.min_max(table[n]).as_py()["max"] for n in names[2:]]
            if None in lo or None in hi:
                return None
            return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

        if by == "rover":
            t = self.scan(["longitude", "latitude", "easting", "northing"])
            return (
                box(t, ("longitude", "latitude", "longitude", "latitude")),
                box(t, ("easting", "northing", "easting", "northing")),
            )
        if by == "footprint":
            t = self.scan(["bbox"]).column("bbox").combine_chunks()
            t = pa.table({n: t.field(n) for n in ("xmin", "ymin", "xmax", "ymax")})
        else:
            t = self.scan(["chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax"])
            t = t.rename_columns(["xmin", "ymin", "xmax", "ymax"])
        mapped = box(t, ("xmin", "ymin", "xmax", "ymax"))
        if mapped is None or self.crs is None:
            return None, mapped
        from mars_pairs.geometry.frames import map_to_lonlat

        gx, gy = np.meshgrid(
            np.linspace(mapped[0], mapped[2], 9), np.linspace(mapped[1], mapped[3], 9)
        )
        lon, lat = map_to_lonlat(gx.ravel(), gy.ravel(), self.crs)
        return (float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())), mapped

    def describe(self, by: By) -> str:
        """The extent of what ``by`` tests, in lon/lat degrees and map metres."""
        lonlat, mapped = self.extent(by)
        what = {"rover": "rover positions", "footprint": "footprints", "chip": "chips"}[by]
        parts = []
        if lonlat is not None:
            w, s, e, n = lonlat
            parts.append(f"lon {w:.5f}..{e:.5f}, lat {s:.5f}..{n:.5f} degrees")
        if mapped is not None:
            x0, y0, x1, y1 = mapped
            parts.append(f"map x {x0:.0f}..{x1:.0f}, y {y0:.0f}..{y1:.0f} m")
        return f"{self.where}'s {what} span " + ("; ".join(parts) or "nothing (no rows)")


def checked(spec: ManifestFilter, values: DatasetValues) -> ManifestFilter:
    """``spec`` held against what the dataset holds: ArgumentError for a mission,
    instrument or split it lacks (listing its values); FilterWarning for a sol range
    outside its sols or a place filter missing its extent. Returns ``spec``."""
    for name in NAME_KEYS:
        asked = getattr(spec, name)
        if asked is None:
            continue
        known = values.names(name)
        missing = [v for v in asked if v not in known]
        if missing:
            plural = {"mission": "missions", "instrument": "instruments", "split": "splits"}
            listed = ", ".join(known) or "none (no rows)"
            raise ArgumentError(
                f"{name}: {values.where} has no {name} {missing[0]!r}; "
                f"its {plural[name]} are {listed}"
            )
    if spec.sol is not None:
        held = values.sols()
        first, last = spec.sol
        if held is None or last < held[0] or first > held[1]:
            span = "none" if held is None else f"{held[0]}..{held[1]}"
            warnings.warn(
                f"sol: {first}..{last} holds none of {values.where}'s sols (they are {span}): "
                "0 rows",
                FilterWarning,
                stacklevel=3,
            )
    for name in spec.places:
        if _misses(spec, name, values):
            warnings.warn(
                f"{name}: {_shown(getattr(spec, name))} misses the dataset (by={spec.by}, "
                f"0 rows): {values.describe(spec.by)}",
                FilterWarning,
                stacklevel=3,
            )
    return spec


def near_in_order(near: Any, values: DatasetValues) -> Any:
    """``near`` as given, or swapped to (lon, lat, radius) with a FilterWarning when it is
    clearly latitude first (the old order): the given point misses the dataset's rover extent
    (widened by the radius) and the swapped one lies in it."""
    if near is None:
        return near
    a, b, radius = numbers(near, 3, "near")
    if not radius > 0.0:
        return near  # the filter's own check says why
    box, _ = values.extent("rover")
    if box is None:
        return near
    if _point_in(box, a, b, radius) or not _point_in(box, b, a, radius):
        return near
    warnings.warn(
        f"near: ({a:g}, {b:g}) is read as LAT LON (the old order), the point lies in "
        f"{values.where} only that way: pass LON LAT RADIUS_M, i.e. ({b:g}, {a:g}, {radius:g})",
        FilterWarning,
        stacklevel=3,
    )
    return (b, a, radius)


def _point_in(box: Box, lon: float, lat: float, radius_m: float) -> bool:
    if not -90.0 <= lat <= 90.0:
        return False
    dlat = math.degrees(radius_m / MARS_RADIUS_M)
    dlon = dlat / max(math.cos(math.radians(min(abs(lat) + dlat, 90.0))), 1e-9)
    w, s, e, n = box
    return s - dlat <= lat <= n + dlat and _lon_overlap(lon - dlon, lon + dlon, w, e)


def _lon_overlap(w1: float, e1: float, w2: float, e2: float) -> bool:
    """Whether longitude ranges [w1 eastward to e1] and [w2, e2] (w2 <= e2) meet, modulo 360."""
    span = e1 - w1 if e1 >= w1 else e1 - w1 + 360.0
    if span >= 360.0 or e2 - w2 >= 360.0:
        return True
    w1 = (w1 - w2) % 360.0 + w2  # into [w2, w2 + 360)
    return w1 <= e2 or w1 + span >= w2 + 360.0


def _misses(spec: ManifestFilter, name: str, values: DatasetValues) -> bool:
    """Whether the place filter ``name`` is disjoint from the extent of what spec.by tests."""
    lonlat, mapped = values.extent(spec.by)
    value = getattr(spec, name)
    if name == "bbox_lonlat" and lonlat is not None:
        w, s, e, n = value
        return n < lonlat[1] or s > lonlat[3] or not _lon_overlap(w, e, lonlat[0], lonlat[2])
    if name == "near" and lonlat is not None:
        lon, lat, radius = value
        return not _point_in(lonlat, lon, lat, radius)
    if name == "polygon_lonlat" and lonlat is not None:
        x0, y0, x1, y1 = value.bounds
        return y1 < lonlat[1] or y0 > lonlat[3] or not _lon_overlap(x0, x1, lonlat[0], lonlat[2])
    if name in ("bbox_map", "polygon_map") and mapped is not None:
        x0, y0, x1, y1 = value if name == "bbox_map" else value.bounds
        return bool(x1 < mapped[0] or x0 > mapped[2] or y1 < mapped[1] or y0 > mapped[3])
    return False


def _shown(value: Any) -> str:
    if isinstance(value, tuple):
        return "(" + ", ".join(f"{v:g}" for v in value) + ")"
    x0, y0, x1, y1 = value.bounds
    return f"{value.geom_type} bounds ({x0:g}, {y0:g}, {x1:g}, {y1:g})"


# -- predicates ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Predicates:
    """A filter as pyarrow terms (pushed down into the scan) and exact tests (callables
    table -> boolean mask, applied after it, reading ``columns``)."""

    terms: tuple[Any, ...]
    exact: tuple[Any, ...]
    uses: tuple[str, ...]


#: columns holding the map box of what ``by`` tests (footprint: its GeoParquet covering)
_BOX_COLUMNS = {
    "footprint": (("bbox", "xmin"), ("bbox", "ymin"), ("bbox", "xmax"), ("bbox", "ymax")),
    "chip": ("chip_xmin", "chip_ymin", "chip_xmax", "chip_ymax"),
}
_SHAPE_COLUMN = {"footprint": "footprint", "chip": "chip_box"}


def predicates(spec: ManifestFilter, crs: str | None) -> Predicates:
    """The scan terms and exact tests of ``spec``; ``crs`` (the dataset CRS) projects lon/lat
    places onto the map when a footprint or chip is tested (ArgumentError when None)."""
    import pyarrow.dataset as ds

    f = ds.field
    terms: list[Any] = []
    exact: list[Any] = []
    uses: list[str] = []
    if spec.by == "rover":
        if spec.bbox_lonlat is not None:
            w, s, e, n = spec.bbox_lonlat
            terms.append((f("latitude") >= s) & (f("latitude") <= n))
            lon_term = longitude_range(f("longitude"), w, e)
            if lon_term is not None:
                terms.append(lon_term)
            uses += ["latitude", "longitude"]
        if spec.near is not None:
            lon, lat, radius = spec.near
            dlat = math.degrees(radius / MARS_RADIUS_M)
            coslat = max(math.cos(math.radians(min(abs(lat) + dlat, 90.0))), 1e-9)
            dlon = dlat / coslat
            terms.append((f("latitude") >= lat - dlat) & (f("latitude") <= lat + dlat))
            if dlon < 180.0:
                lon_term = longitude_range(f("longitude"), lon - dlon, lon + dlon)
                if lon_term is not None:
                    terms.append(lon_term)
            exact.append(NearPredicate(lat, lon, radius))
            uses += ["latitude", "longitude"]
        if spec.polygon_lonlat is not None:
            x0, y0, x1, y1 = spec.polygon_lonlat.bounds
            terms.append((f("latitude") >= y0) & (f("latitude") <= y1))
            lon_term = longitude_range(f("longitude"), x0, x1)
            if lon_term is not None:
                terms.append(lon_term)
            exact.append(PointPredicate(_wkb(spec.polygon_lonlat), ("longitude", "latitude")))
            uses += ["latitude", "longitude"]
        for box in (spec.bbox_map, _bounds(spec.polygon_map)):
            if box is not None:
                x0, y0, x1, y1 = box
                terms.append(
                    (f("easting") >= x0)
                    & (f("easting") <= x1)
                    & (f("northing") >= y0)
                    & (f("northing") <= y1)
                )
                uses += ["easting", "northing"]
        if spec.polygon_map is not None:
            exact.append(PointPredicate(_wkb(spec.polygon_map), ("easting", "northing")))
    else:
        cols = _BOX_COLUMNS[spec.by]
        for shape in map_shapes(spec, crs):
            x0, y0, x1, y1 = shape.bounds  # boxes that meet the shape's bounds
            terms.append(
                (f(*_path(cols[2])) >= x0)
                & (f(*_path(cols[0])) <= x1)
                & (f(*_path(cols[3])) >= y0)
                & (f(*_path(cols[1])) <= y1)
            )
            exact.append(ShapePredicate(_wkb(shape), _SHAPE_COLUMN[spec.by]))
            uses += [_SHAPE_COLUMN[spec.by], *{c if isinstance(c, str) else c[0] for c in cols}]
    for name in NAME_KEYS:
        value = getattr(spec, name)
        if value is not None:
            terms.append(f(name).isin(list(value)))
            uses.append(name)
    if spec.sol is not None:
        first, last = spec.sol
        terms.append((f("sol") >= first) & (f("sol") <= last))
        uses.append("sol")
    return Predicates(tuple(terms), tuple(exact), tuple(dict.fromkeys(uses)))


def _path(column: Any) -> tuple[str, ...]:
    return (column,) if isinstance(column, str) else tuple(column)


def _bounds(geom: Any) -> Box | None:
    bounds = None if geom is None else tuple(float(v) for v in geom.bounds)
    return bounds  # type: ignore[return-value]  # (shapely's bounds: always 4 numbers)


def _wkb(geom: Any) -> bytes:
    import shapely

    return bytes(shapely.to_wkb(geom))


def map_shapes(spec: ManifestFilter, crs: str | None) -> list[Any]:
    """Each place filter of ``spec`` as a shapely geometry in the dataset CRS (map units):
    lon/lat boxes and polygons densified (edges of at most :data:`DENSIFY_DEG`) and projected,
    a ``near`` circle as the polygon of :data:`CIRCLE_VERTICES` points at the radius along
    great circles (inscribed: its edges lie within r(1 - cos(pi/N)), 0.008 % of r, inside)."""
    import shapely

    shapes: list[Any] = []
    if spec.bbox_map is not None:
        shapes.append(shapely.box(*spec.bbox_map))
    if spec.polygon_map is not None:
        shapes.append(spec.polygon_map)
    groups: list[list[Any]] = []  # lon/lat shapes; a group's parts are one place
    if spec.bbox_lonlat is not None:
        w, s, e, n = spec.bbox_lonlat
        if e < w:  # across the 180th meridian: the two sides
            groups.append([shapely.box(w, s, 180.0, n), shapely.box(-180.0, s, e, n)])
        else:
            groups.append([shapely.box(w, s, e, n)])
    if spec.polygon_lonlat is not None:
        groups.append([spec.polygon_lonlat])
    if spec.near is not None:
        groups.append([_circle(*spec.near)])
    if groups and crs is None:
        raise ArgumentError(
            f"by: {spec.by}: the dataset has no CRS, so a lon/lat place cannot be tested "
            "against its map geometries; use by='rover'"
        )
    if groups:
        from mars_pairs.geometry.frames import lonlat_to_map

        def project(xy: np.ndarray) -> np.ndarray:
            x, y = lonlat_to_map(xy[:, 0], xy[:, 1], crs)
            return np.column_stack([x, y])

        for group in groups:
            parts = [shapely.transform(shapely.segmentize(g, DENSIFY_DEG), project) for g in group]
            shapes.append(parts[0] if len(parts) == 1 else shapely.union_all(parts))
    return shapes


def _circle(lon: float, lat: float, radius_m: float) -> Any:
    """The lon/lat polygon of the points at ``radius_m`` (great circle, Mars sphere) from
    (lon, lat) degrees, :data:`CIRCLE_VERTICES` of them."""
    import shapely

    d = radius_m / MARS_RADIUS_M
    phi, lam = math.radians(lat), math.radians(lon)
    theta = np.linspace(0.0, 2.0 * np.pi, CIRCLE_VERTICES, endpoint=False)
    lat2 = np.arcsin(np.sin(phi) * np.cos(d) + np.cos(phi) * np.sin(d) * np.cos(theta))
    lon2 = lam + np.arctan2(
        np.sin(theta) * np.sin(d) * np.cos(phi), np.cos(d) - np.sin(phi) * np.sin(lat2)
    )
    return shapely.Polygon(np.column_stack([np.degrees(lon2), np.degrees(lat2)]))


def longitude_range(column: Any, west: float, east: float) -> Any:
    """Longitudes from ``west`` eastward to ``east`` (degrees east), modulo 360: ``west >
    east`` crosses the 180th meridian (or 0 for 0..360 data). An expression of plain ranges
    (row-group statistics still prune), matching values stored as -180..180 or 0..360;
    None when the range covers every longitude."""
    span = east - west if east >= west else east - west + 360.0
    if span >= 360.0:
        return None
    west -= 360.0 * math.floor((west + 180.0) / 360.0)  # into [-180, 180); exact if there
    # the range's copies that can meet stored values in [-180, 360)
    shifts = [0.0] + [-360.0] * (west + span >= 180.0) + [360.0] * (west < 0.0)
    expression = None
    for k in shifts:
        term = (column >= west + k) & (column <= west + span + k)
        expression = term if expression is None else expression | term
    return expression


@dataclass(frozen=True)
class NearPredicate:
    """Rows whose rover position is within ``radius_m`` (great circle) of (lat, lon)."""

    lat: float
    lon: float
    radius_m: float
    columns: tuple[str, ...] = ("latitude", "longitude")

    def __call__(self, table: pa.Table) -> pa.Array:
        d = great_circle_m(
            self.lat, self.lon, table["latitude"].to_numpy(), table["longitude"].to_numpy()
        )
        return pa.array(d <= self.radius_m)


@dataclass(frozen=True)
class PointPredicate:
    """Rows whose point (the two ``columns``: x, y) lies in the geometry ``wkb``; lon/lat
    points are compared modulo 360 from the geometry's west edge."""

    wkb: bytes
    columns: tuple[str, str]

    def __call__(self, table: pa.Table) -> pa.Array:
        import shapely

        geom = shapely.from_wkb(self.wkb)
        x = table[self.columns[0]].to_numpy().astype(np.float64)
        y = table[self.columns[1]].to_numpy().astype(np.float64)
        if self.columns[0] == "longitude":
            west = geom.bounds[0]
            x = (x - west) % 360.0 + west
        return pa.array(shapely.intersects_xy(geom, x, y))


@dataclass(frozen=True)
class ShapePredicate:
    """Rows whose geometry column ``column`` (WKB, map units) meets the geometry ``wkb``
    (rows without one: no)."""

    wkb: bytes
    column: str

    @property
    def columns(self) -> tuple[str, ...]:
        return (self.column,)

    def __call__(self, table: pa.Table) -> pa.Array:
        import shapely

        geom = shapely.from_wkb(self.wkb)
        shapes = shapely.from_wkb(table[self.column].to_numpy(zero_copy_only=False))
        return pa.array(np.asarray(shapely.intersects(geom, shapes), dtype=bool))
