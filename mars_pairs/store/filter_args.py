"""Manifest filter arguments as users pass them: Python, numpy and pandas scalars, tuples,
arrays and Series; a wrong type, size or a NaN raises ArgumentError naming the argument; a
sample is named by its key or product id. (What a filter is: ``store.filter``.)"""

from __future__ import annotations

import math
from typing import Any, Literal

from mars_pairs.errors import ArgumentError, SampleKeyError

By = Literal["rover", "footprint", "chip"]
#: what a place filter may test, the first the default
BY: tuple[By, ...] = ("rover", "footprint", "chip")


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


def sample_index(name: Any, keys: Any, product_ids: Any, where: str) -> int:
    """The row of the sample a user names by key (``m2020_zl0_...``) or by product id
    (``ZL0_...``), in any case, dots or underscores.

    ``keys`` and ``product_ids`` are pyarrow arrays of the same rows (``product_ids`` may be
    None). SampleKeyError (a KeyError too) naming ``where`` when no row matches, or when a
    product id names several rows (their keys listed).
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    if not isinstance(name, str):
        raise ArgumentError(f"key: expected a sample key or product id, got {name!r}")
    text = name.strip()
    found = pc.index(keys, pa.scalar(text, keys.type)).as_py()
    if found >= 0:
        return int(found)
    folded = text.replace(".", "_").lower()
    candidates = [pc.equal(pc.utf8_lower(keys), folded)]
    if product_ids is not None:
        ids = pc.utf8_lower(product_ids.fill_null(""))
        candidates.append(pc.equal(ids, text.lower()))
        candidates.append(pc.equal(pc.replace_substring(ids, ".", "_"), folded))
    for mask in candidates:
        rows = pc.indices_nonzero(mask.fill_null(False)).to_pylist()
        if len(rows) == 1:
            return int(rows[0])
        if len(rows) > 1:
            names = ", ".join(keys.take(pa.array(rows[:5])).to_pylist())
            raise SampleKeyError(
                f"{where}: {name!r} names {len(rows)} samples ({names}): use a key"
            )
    raise SampleKeyError(
        f"{where}: no sample with key {name!r} (nor with that product id) in this dataset"
    )
