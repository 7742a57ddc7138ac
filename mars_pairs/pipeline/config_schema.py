"""One schema for every config section: the value types, the generic reader, the reference page.

A section is a frozen pydantic dataclass (``@dataclass(frozen=True, config=SCHEMA)``) whose
fields carry everything about a key once: its type (``Number``, ``Integer``, ``Flag``,
``Text``, ``Literal[...]`` choices, a path type), its bounds (``Field(gt=..., le=...)``), its
default, and its documentation (the string literal under the field, as for a module
attribute). pydantic validates (``extra="forbid"``: an unknown key is refused;
``allow_inf_nan=False``: ``.nan``/``.inf`` are refused; strict types: a bool is no number, a
number no text, a float no integer); ``read_section`` turns the first of its errors into one
``ConfigError`` line naming ``section.key``, what was expected and the value given, and, for a
mapping read by ``read_yaml`` (its ``YamlMapping``), the line and column of the key
(``ConfigError.line``). ``reference_markdown`` writes the reference page of a list of sections
from the same fields.

A key given as YAML ``null`` is the key left out (its default; "required key is missing"
for a key without one). Relative paths resolve against the ``base`` folder given to
``read_section`` (the config file's folder); a path-typed value that is already a ``Path`` is
kept (``dataclasses.replace`` re-validates a section without a base).
"""

from __future__ import annotations

import ast
import inspect
import itertools
import math
import re
import reprlib
import textwrap
import types
from collections.abc import Callable, Iterator, Sequence
from dataclasses import MISSING, fields, is_dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, Union, get_args, get_origin

import annotated_types
from pydantic import (
    BeforeValidator,
    ConfigDict,
    Strict,
    StringConstraints,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
)
from pydantic.fields import FieldInfo

from mars_pairs.errors import ConfigError

#: The pydantic settings every config section is read with.
SCHEMA = ConfigDict(extra="forbid", allow_inf_nan=False)

#: Longest text value (a path, a URL, a licence id, a glob) a config may give, in characters.
MAX_TEXT = 4096

_NUMBER_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][+-]?[0-9]+", re.ASCII)


def _number_text(value: Any) -> Any:
    """``"1e3"`` (YAML 1.1 reads an exponent without a dot as text) as the number it is."""
    if isinstance(value, str) and _NUMBER_TEXT.fullmatch(value.strip()):
        return float(value)
    return value


class Expected:
    """Field metadata: how the reference page and the error messages say what a key takes,
    for a key whose type alone does not say it (a path, a glob, a list of names)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return f"Expected({self.text!r})"


#: A finite number (an integer is taken as a float; a bool or other text is refused).
Number = Annotated[float, Strict(), BeforeValidator(_number_text)]
#: An integer (a float such as ``2.0``, a bool or text is refused).
Integer = Annotated[int, Strict()]
#: ``true`` or ``false`` (YAML's booleans; ``1``, ``"yes"`` as text are refused).
Flag = Annotated[bool, Strict(), Expected("true or false")]
#: Non-blank text of at most ``MAX_TEXT`` characters.
Text = Annotated[str, Strict(), StringConstraints(min_length=1, max_length=MAX_TEXT, pattern=r"\S")]


class YamlMapping(dict[Any, Any]):
    """A mapping read from YAML, with where its keys were: ``lines[key]`` is (line, column)
    of the key, 1-based; ``start`` is the mapping's own (line, column)."""

    lines: dict[Any, tuple[int, int]]
    start: tuple[int, int] | None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.lines = {}
        self.start = None

    def __reduce__(self) -> Any:  # pickles (and deep-copies) as a plain mapping
        return (dict, (dict(self),))


class KeyProblem(ValueError):
    """Raised by a section's validator: ``message`` about the key ``key`` of the section
    (None: the key the validator belongs to)."""

    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


def base_of(info: ValidationInfo) -> Path | None:
    """The folder relative paths resolve against (``read_section``'s ``base``), or None."""
    context = info.context
    base = context.get("base") if isinstance(context, dict) else None
    return base if isinstance(base, Path) else None


S = TypeVar("S")


def read_section(
    cls: type[S],
    data: Any,
    prefix: str,
    base: Path | None = None,
    *,
    line: tuple[int, int] | None = None,
) -> S:
    """``data`` (a mapping, None meaning empty) validated into the section ``cls``; a
    ConfigError naming ``prefix.key`` (and the YAML line, ``ConfigError.line``: the key's,
    else ``line``, the section's) if not."""
    if data is None:
        data = {}
    adapter: TypeAdapter[S] = TypeAdapter(cls)
    cleaned = _without_nulls(cls, data)
    try:
        return adapter.validate_python(cleaned, context={"base": base})
    except ValidationError as exc:
        error = _config_error(cls, data, prefix, exc)
        if error.line is None and line is not None:
            error = ConfigError(str(error), line=line)
        raise error from None


def subset(data: dict[Any, Any], keys: Sequence[Any]) -> YamlMapping:
    """The keys ``keys`` of ``data`` (those it has), with their lines."""
    out = YamlMapping({k: data[k] for k in keys if k in data})
    if isinstance(data, YamlMapping):
        out.lines = {k: v for k, v in data.lines.items() if k in out}
        out.start = data.start
    return out


def line_of(data: Any, key: Any) -> tuple[int, int] | None:
    """The (line, column) of ``key`` in a mapping read by ``read_yaml``, else None."""
    return data.lines.get(key) if isinstance(data, YamlMapping) else None


def _without_nulls(cls: Any, data: Any) -> Any:
    """``data`` without its null keys (a null key is an absent one), in this section and the
    sections nested in it (``YamlMapping`` kept, for the lines)."""
    if not isinstance(data, dict) or not is_dataclass(cls):
        return data
    nested = {f.name: _section_type(f.type, cls) for f in fields(cls)}
    out = YamlMapping()
    if isinstance(data, YamlMapping):
        out.lines, out.start = data.lines, data.start
    for key, value in data.items():
        if value is None:
            continue
        sub = nested.get(key) if isinstance(key, str) else None
        out[key] = _without_nulls(sub, value) if sub is not None else value
    return out


def _section_type(annotation: Any, owner: Any) -> Any:
    """The section class a field holds (``X`` or ``X | None``), else None."""
    hint = _resolved(annotation, owner)
    for arg in (hint, *get_args(hint)):
        if isinstance(arg, type) and is_dataclass(arg):
            return arg
    return None


def _resolved(annotation: Any, owner: Any) -> Any:
    if isinstance(annotation, str):  # postponed annotations (``from __future__``)
        module = inspect.getmodule(owner)
        return eval(annotation, vars(module) if module else {}, {})  # the module's own names
    return annotation


# --- error messages ---------------------------------------------------------------------------


def _config_error(cls: Any, data: Any, prefix: str, exc: ValidationError) -> ConfigError:
    error = exc.errors(include_url=False)[0]
    loc = [p for p in error["loc"] if not _is_branch(p)]
    of_key = bool(error["loc"]) and error["loc"][-1] == "[key]"  # a mapping's key is at fault
    owner, names, rest = _walk(cls, loc)
    key = ".".join([prefix, *names] if prefix else names)
    key += "".join(f"[{p!r}]" if isinstance(p, str) else f"[{p}]" for p in rest)
    kind = error["type"]
    given = error.get("input")
    if kind in ("missing", "missing_argument"):
        message = "required key is missing"
    elif kind in ("extra_forbidden", "unexpected_keyword_argument", "invalid_key"):
        known = sorted(f.name for f in fields(owner)) if owner is not None else []
        name = loc[-1] if loc else given
        key = ".".join([prefix, *names[:-1]] if prefix else names[:-1])
        key = f"{key}.{_key_text(name)}" if key else _key_text(name)
        message = f"unknown key (expected one of {known})"
    elif kind == "value_error" and isinstance(error.get("ctx", {}).get("error"), KeyProblem):
        problem = error["ctx"]["error"]
        if problem.key is not None:
            key = f"{key}.{problem.key}" if key else problem.key
        message = str(problem)
    elif kind == "value_error":
        message = str(error["ctx"]["error"])
    elif kind == "finite_number":
        message = f"expected a finite number, got {shown(given)}"
    elif kind in ("dataclass_type", "dataclass_exact_type", "model_type") and not rest:
        message = f"expected a mapping, got {shown(given)}"
    else:
        field = _field(owner, names[-1]) if owner is not None and names else None
        if field is not None and rest:
            field = _inside(field[0], field[1], rest, of_key)
        what = expected(field[0], field[1]) if field else _pydantic_words(error["msg"])
        message = f"expected {what}, got {shown(given)}"
    where = _line(data, loc)
    return ConfigError(f"{key}: {message}" if key else message, line=where)


def _is_branch(part: Any) -> bool:
    """A loc part pydantic adds for a union branch or a validator (not a key)."""
    return isinstance(part, str) and (
        part == "[key]" or "[" in part or part in ("function-after", "function-before")
    )


def _walk(cls: Any, loc: Sequence[Any]) -> tuple[Any, list[str], list[Any]]:
    """(the section holding the last key, the key names, the positions inside its value)."""
    owner, names = cls, list[str]()
    for i, part in enumerate(loc):
        if owner is None or not isinstance(part, str):
            return owner, names, list(loc[i:])
        known = {f.name: f for f in fields(owner)}
        names.append(part)
        if part not in known:
            return owner, names, list(loc[i + 1 :])
        inner = _section_type(known[part].type, owner)
        if inner is None:
            return owner, names, list(loc[i + 1 :])
        if i < len(loc) - 1:
            owner = inner
    return owner, names, []


def _inside(
    annotation: Any, metadata: Sequence[Any], rest: Sequence[Any], of_key: bool
) -> tuple[Any, Any] | None:
    """The type (and metadata) of the value at ``rest`` inside a value of ``annotation``
    (of the key itself at the end, with ``of_key``); None where the types do not say."""
    hint, meta = _unwrap(annotation, list(metadata))
    for i, part in enumerate(rest):
        origin, args = get_origin(hint), get_args(hint)
        last = i == len(rest) - 1
        if origin is dict:
            hint, meta = _unwrap(args[0] if last and of_key else args[1], [])
        elif origin in (tuple, list) and args and (len(args) == 2 and args[1] is Ellipsis):
            hint, meta = _unwrap(args[0], [])
        elif origin is tuple and isinstance(part, int) and 0 <= part < len(args):
            hint, meta = _unwrap(args[part], [])
        elif origin is list and args:
            hint, meta = _unwrap(args[0], [])
        else:
            return None
    return hint, meta


def _key_text(name: Any) -> str:
    return name if isinstance(name, str) and len(name) <= 120 else shown(name)


def _line(data: Any, loc: Sequence[Any]) -> tuple[int, int] | None:
    """Where in the YAML the key at ``loc`` is: its own line, else the nearest mapping's."""
    where = data.start if isinstance(data, YamlMapping) else None
    node = data
    for part in loc:
        if isinstance(node, YamlMapping) and part in node:
            where = node.lines.get(part, where)
            node = node[part]
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        else:
            break
    return where


def _pydantic_words(msg: str) -> str:
    """pydantic's "Input should be a valid string" as "a valid string"."""
    return msg.removeprefix("Input should be ").removeprefix("Value error, ")


# --- what a key takes -------------------------------------------------------------------------


def _field(owner: Any, name: str) -> tuple[Any, Any] | None:
    pyd = getattr(owner, "__pydantic_fields__", {})
    if name not in pyd:
        return None
    info = pyd[name]
    return info.annotation, info.metadata


def expected(annotation: Any, metadata: Sequence[Any] = ()) -> str:
    """What a key of type ``annotation`` (with pydantic's ``metadata``: bounds, lengths,
    ``Expected``) takes, in words: ``a number in (0, 2e+05]``, ``one of ['a', 'b']``."""
    hint, meta = _unwrap(annotation, list(metadata))
    for m in meta:
        if isinstance(m, Expected):
            return m.text
    origin = get_origin(hint)
    if origin in (Union, types.UnionType):
        options = [a for a in get_args(hint) if a is not type(None)]
        text = " or ".join(expected(a, meta) for a in options)
        return f"{text} or null" if type(None) in get_args(hint) else text
    if origin is Literal:
        return f"one of {list(get_args(hint))}"
    if hint is bool:
        return "true or false"
    if hint is int:
        lo, hi = _bounds(meta)
        if lo is None and hi is None:
            return "an integer"
        lo_text = "-inf" if lo is None else f"{lo[1]}"
        hi_text = "inf" if hi is None else f"{hi[1]}"
        if lo is not None and lo[0] == "gt":
            lo_text = f"{lo[1] + 1}"
        if hi is not None and hi[0] == "lt":
            hi_text = f"{hi[1] - 1}"
        return f"an integer in [{lo_text}, {hi_text}]"
    if hint is float:
        return "a number" + _range_words(*_bounds(meta))
    if hint is str:
        longest = next((m.max_length for m in meta if hasattr(m, "max_length")), None)
        return "text" + (f" of at most {longest} characters" if longest else "")
    if origin in (tuple, list):
        args = [a for a in get_args(hint) if a is not Ellipsis]
        return f"a list, each {expected(args[0]) if args else 'a value'}"
    if origin is dict:
        key_type, value_type = get_args(hint)
        return f"a mapping of {expected(key_type)} to {expected(value_type)}"
    if isinstance(hint, type) and is_dataclass(hint):
        return "a mapping (its keys below)"
    return getattr(hint, "__name__", str(hint))


def _unwrap(annotation: Any, meta: list[Any]) -> tuple[Any, list[Any]]:
    """``Annotated[T, m1, m2]`` as (T, [m1, m2, *meta]), flattened."""
    while get_origin(annotation) is Annotated:
        inner, *extra = get_args(annotation)
        meta = [*_flat(extra), *meta]
        annotation = inner
    return annotation, meta


def _flat(items: Sequence[Any]) -> Iterator[Any]:
    for item in items:
        if isinstance(item, FieldInfo):
            yield from item.metadata
        elif isinstance(item, annotated_types.GroupedMetadata):
            yield from item
        else:
            yield item


def _bounds(meta: Sequence[Any]) -> tuple[tuple[str, Any] | None, tuple[str, Any] | None]:
    lo: tuple[str, Any] | None = None
    hi: tuple[str, Any] | None = None
    for m in meta:
        if isinstance(m, annotated_types.Gt):
            lo = ("gt", m.gt)
        elif isinstance(m, annotated_types.Ge):
            lo = ("ge", m.ge)
        elif isinstance(m, annotated_types.Lt):
            hi = ("lt", m.lt)
        elif isinstance(m, annotated_types.Le):
            hi = ("le", m.le)
    return lo, hi


def _num(value: Any) -> str:
    """A bound as written in a config: ``200000``, ``0.5``, ``1e-09``."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e16:
        return str(int(value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def _range_words(lo: tuple[str, Any] | None, hi: tuple[str, Any] | None) -> str:
    if lo is None and hi is None:
        return ""
    if lo is None:
        assert hi is not None
        return f" {'<' if hi[0] == 'lt' else '<='} {_num(hi[1])}"
    if hi is None:
        if lo == ("gt", 0):
            return " > 0"
        return f" {'>' if lo[0] == 'gt' else '>='} {_num(lo[1])}"
    left = "(" if lo[0] == "gt" else "["
    right = ")" if hi[0] == "lt" else "]"
    return f" in {left}{_num(lo[1])}, {_num(hi[1])}{right}"


# --- values shown in messages -----------------------------------------------------------------

_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxother = 120
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = _SHOWN.maxset = 8
_SHOWN.maxlevel = 3


def shown(value: Any) -> str:
    """``repr(value)`` cut to a bounded length (``reprlib``: long strings, lists and mappings
    elided with ``...``), for error messages about config values of any size; a non-finite
    number as YAML writes it (``.nan``, ``.inf``)."""
    if isinstance(value, YamlMapping):
        value = dict(value)
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return _SHOWN.repr(value)


# --- the reference page -----------------------------------------------------------------------


def attribute_docs(cls: type) -> dict[str, str]:
    """The string literal under each field of ``cls`` (its documentation), by field name."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    docs: dict[str, str] = {}
    for node, after in itertools.pairwise(body):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def _default_text(f: Any) -> str:
    if f.default is not MISSING:
        value = f.default
    elif f.default_factory is not MISSING:
        value = f.default_factory()
    else:
        return "required"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list, dict)):
        import yaml

        flow = yaml.safe_dump(_plain(value), default_flow_style=True, sort_keys=False, width=10**6)
        return f"`{flow.strip()}`"
    if isinstance(value, float):
        return f"`{_num(value)}`"
    return f"`{value}`"


def _plain(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def reference_markdown(
    sections: Sequence[tuple[str, type]],
    *,
    title: str = "Configuration reference",
    intro: str = "",
    extra: Callable[[str], str] | None = None,
) -> str:
    """The reference page (Markdown) of ``sections``, (``section.key`` prefix, section class)
    in page order: per section its class docstring and a table of every key with what it
    takes (type, choices, bounds), its default and its documentation."""
    lines = [f"# {title}", ""]
    if intro:
        lines += [intro.strip(), ""]
    for prefix, cls in sections:
        lines += [f"## `{prefix}`", ""]
        doc = inspect.cleandoc(cls.__doc__ or "")
        if doc:
            lines += [doc, ""]
        if extra is not None and extra(prefix):
            lines += [extra(prefix).strip(), ""]
        docs = attribute_docs(cls)
        lines += ["| key | takes | default | meaning |", "|---|---|---|---|"]
        pyd = getattr(cls, "__pydantic_fields__", {})
        for f in fields(cls):
            info = pyd.get(f.name)
            what = expected(info.annotation, info.metadata) if info else str(f.type)
            lines.append(
                f"| `{prefix}.{f.name}` | {_cell(what)} | {_cell(_default_text(f))} "
                f"| {_cell(docs.get(f.name, ''))} |"
            )
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
