"""Wrong values for every key of a config schema, derived from its field types: a string for a
number, a list for a string, a mapping for a list, a bool for an integer, null where a key is
required, nan/inf, values past each bound, text past ``MAX_TEXT``."""

from __future__ import annotations

import math
import types
from collections.abc import Iterator
from dataclasses import MISSING, fields, is_dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types
from pydantic.fields import FieldInfo

from mars_pairs.pipeline.config_schema import MAX_TEXT


def _unwrap(hint: Any, meta: list[Any]) -> tuple[Any, list[Any]]:
    while get_origin(hint) is Annotated:
        inner, *extra = get_args(hint)
        for m in extra:
            meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
        hint = inner
    return hint, meta


def _bounds(meta: list[Any]) -> tuple[float | None, float | None, bool]:
    lo = hi = None
    open_lo = False
    for m in meta:
        if isinstance(m, annotated_types.Gt):
            lo, open_lo = m.gt, True
        elif isinstance(m, annotated_types.Ge):
            lo = m.ge
        elif isinstance(m, annotated_types.Le):
            hi = m.le
        elif isinstance(m, annotated_types.Lt):
            hi = m.lt
    return lo, hi, open_lo


def kind_of(cls: type, name: str) -> tuple[str, Any, list[Any], bool]:
    """(kind, the type, its metadata, required) of the field ``name`` of section ``cls``;
    kind is one of number, integer, flag, choice, text, list, mapping, section, path."""
    info = cls.__pydantic_fields__[name]  # type: ignore[attr-defined]  # a pydantic dataclass
    hint, meta = _unwrap(info.annotation, list(info.metadata))
    if get_origin(hint) in (Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        hint, meta = _unwrap(args[0], meta) if len(args) == 1 else (hint, meta)
    required = info.is_required()
    origin = get_origin(hint)
    if hint is bool:
        kind = "flag"
    elif hint is int:
        kind = "integer"
    elif hint is float:
        kind = "number"
    elif origin is Literal:
        kind = "choice"
    elif hint is str:
        kind = "text"
    elif origin is tuple and name == "sols":
        kind = "sols"
    elif origin in (tuple, list):
        kind = "list"
    elif origin is dict:
        kind = "mapping"
    elif isinstance(hint, type) and is_dataclass(hint):
        kind = "section"
    else:  # Path, Path | str: a path or URL read by the key's own validator
        kind = "path"
    return kind, hint, meta, required


def wrong_values(cls: type, name: str) -> Iterator[tuple[str, Any]]:
    """(what, value) pairs, each wrong for the key ``name`` of section ``cls``."""
    kind, hint, meta, required = kind_of(cls, name)
    if required:
        yield "null where required", None
    long_text = "x" * (MAX_TEXT + 1)
    if kind in ("number", "integer"):
        yield "text for a number", "many"
        yield "a list for a number", [1]
        yield "a mapping for a number", {"a": 1}
        yield "a bool for a number", True
        yield "nan", math.nan
        yield "inf", math.inf
        yield "-inf", -math.inf
        lo, hi, open_lo = _bounds(meta)
        if lo is not None:
            yield "below the range", lo if open_lo else lo - 1
        if hi is not None:
            yield "above the range", hi * 10 + 1
        if kind == "integer":
            yield "a float for an integer", 2.5
            yield "an integral float for an integer", 2.0
            yield "numeric text for an integer", "3"
    elif kind == "flag":
        yield "text for a bool", "yes please"
        yield "an integer for a bool", 1
        yield "a list for a bool", [True]
        yield "a mapping for a bool", {"a": True}
    elif kind == "choice":
        yield "an unknown choice", "no-such-choice"
        yield "a number for a choice", 5
        yield "a bool for a choice", True
        yield "a list for a choice", [get_args(hint)[0]]
        yield "a mapping for a choice", {"a": 1}
    elif kind in ("text", "path"):
        yield "a number for text", 5
        yield "a bool for text", True
        yield "a list for text", ["a"]
        yield "a mapping for text", {"a": "b"}
        yield "text past the bound", long_text
        yield "blank text", "   "
    elif kind == "list":
        yield "a mapping for a list", {"a": "b"}
        yield "a bool for a list", True
        yield "a list of mappings", [{"a": 1}]
        yield "a list of lists", [["a"]]
        yield "a list with text past the bound", [long_text]
    elif kind == "sols":
        yield "text for sols", "many"
        yield "a mapping for sols", {"a": 1}
        yield "three sols", [1, 2, 3]
        yield "sols out of order", [5, 1]
        yield "a bool for sols", True
    elif kind == "mapping":
        yield "a list for a mapping", [1, 2]
        yield "text for a mapping", "text"
        yield "a number for a mapping", 5
        yield "a mapping with a non-text key", {1: 1.0}
        yield "a mapping of lists", {"test": ["a", "b"]}
    elif kind == "section":
        yield "a number for a section", 5
        yield "text for a section", "text"
        yield "a list for a section", [1]
        yield "an unknown key in a section", {"no_such_key": 1}


def section_fields(cls: type) -> list[str]:
    return [f.name for f in fields(cls)]  # type: ignore[arg-type]  # a dataclass


def has_default(cls: type, name: str) -> bool:
    f = {f.name: f for f in fields(cls)}[name]  # type: ignore[arg-type]  # a dataclass
    return f.default is not MISSING or f.default_factory is not MISSING


def yaml_line_of(path: Path, line: int) -> str:
    return path.read_text().splitlines()[line - 1]
