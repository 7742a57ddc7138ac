"""Manifest filter arguments as users pass them: Python, numpy and pandas scalars, tuples,
arrays and Series; a wrong type, size or a NaN raises ArgumentError naming the argument."""

from __future__ import annotations

import math
from typing import Any

from mars_pairs.errors import ArgumentError


def sequence(value: Any, n: int, name: str) -> list[Any]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise ArgumentError(f"{name}: expected {n} numbers, got {value!r}")
    items = list(value.tolist() if hasattr(value, "tolist") else value)
    if len(items) != n:
        raise ArgumentError(f"{name}: expected {n} numbers, got {len(items)}: {value!r}")
    return items


def number(value: Any, name: str) -> float:
    """A finite float of a Python, numpy or pandas real scalar (not bool, not a string)."""
    if isinstance(value, (str, bytes, bool)) or type(value).__name__ == "bool_":
        raise ArgumentError(f"{name}: expected a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ArgumentError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ArgumentError(f"{name}: expected a finite number, got {value!r}")
    return number


def numbers(value: Any, n: int, name: str) -> list[float]:
    return [number(v, name) for v in sequence(value, n, name)]


def integers(value: Any, n: int, name: str) -> list[int]:
    out = []
    for v in numbers(value, n, name):
        if v != int(v):
            raise ArgumentError(f"{name}: expected whole numbers, got {value!r}")
        out.append(int(v))
    return out


def strings(value: Any, name: str) -> list[str]:
    """One value or a non-empty list of values (a str, numpy str, list, array or Series) as
    strings."""
    if isinstance(value, str):
        return [str(value)]
    if not hasattr(value, "__iter__") or isinstance(value, bytes):
        raise ArgumentError(f"{name}: expected a string or a list of strings, got {value!r}")
    values = list(value.tolist() if hasattr(value, "tolist") else value)
    if not values:
        raise ArgumentError(f"{name}: expected a string or a non-empty list of strings, got []")
    bad = [v for v in values if not isinstance(v, str)]
    if bad:
        raise ArgumentError(f"{name}: expected strings, got {bad[0]!r}")
    return [str(v) for v in values]


def shapely_module() -> Any:
    import shapely

    return shapely


def geometry(polygon: Any) -> Any:
    shapely = shapely_module()
    try:
        geom = shapely.from_wkt(polygon) if isinstance(polygon, str) else polygon
    except shapely.errors.ShapelyError as exc:
        raise ArgumentError(f"polygon: not WKT: {exc}") from None
    if not isinstance(geom, shapely.Geometry) or geom.is_empty:
        raise ArgumentError(f"polygon: expected a shapely geometry or WKT, got {polygon!r}")
    return geom
