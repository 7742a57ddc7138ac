"""Typed, named reading of one config mapping: every error names ``section.key``."""

from __future__ import annotations

import math
import os
import re
import reprlib
import stat
from pathlib import Path
from types import EllipsisType
from typing import Any, overload

from mars_pairs.errors import ConfigError

_NUMBER_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][+-]?[0-9]+", re.ASCII)

_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxother = 120
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = _SHOWN.maxset = 8
_SHOWN.maxlevel = 3


def shown(value: Any) -> str:
    """``repr(value)`` cut to a bounded length (``reprlib``: long strings, lists and mappings
    elided with ``...``), for error messages about config values of any size."""
    return _SHOWN.repr(value)


_KINDS = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISDIR, "a folder"),
)


def file_kind(mode: int) -> str | None:
    """What a file of ``st_mode`` ``mode`` is, when it is not a regular file (None)."""
    for test, kind in _KINDS:
        if test(mode):
            return kind
    return None if stat.S_ISREG(mode) else "not a regular file"


def check_regular(path: Path | str, key: str, *, folder: bool = False) -> None:
    """ConfigError naming ``key`` and ``path`` when ``path`` exists and is not a regular file
    (with ``folder``: not a folder): a FIFO, a socket or a device would block or never end
    when read. An absent path, a URL and a GDAL ``/vsi`` path pass (what opens them says
    why they do not). Checked by ``stat``, without opening the path."""
    text = str(path)
    if text.startswith("/vsi") or "://" in text:
        return
    try:
        mode = os.stat(text).st_mode
    except (OSError, ValueError):
        return
    if folder and stat.S_ISDIR(mode):
        return
    kind = file_kind(mode)
    if kind is not None:
        expected = "a folder" if folder else "a regular file"
        raise ConfigError(f"{key}: {path} is {kind}, expected {expected}")


class Section:
    """Reads typed keys from one mapping, naming ``prefix.key`` in every error."""

    def __init__(self, data: Any, prefix: str, known: set[str]) -> None:
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(f"{prefix}: expected a mapping, got {type(data).__name__}")
        unknown = sorted((k for k in data if k not in known), key=str)
        if unknown:
            name = unknown[0]
            if not isinstance(name, str) or len(name) > 120:
                name = shown(name)
            where = f"{prefix}.{name}" if prefix else name
            raise ConfigError(f"{where}: unknown key (expected one of {sorted(known)})")
        self.data, self.prefix = data, prefix

    def _name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def raw(self, key: str, default: Any = ...) -> Any:
        if key not in self.data or self.data[key] is None:
            if default is ...:
                raise ConfigError(f"{self._name(key)}: required key is missing")
            return default
        return self.data[key]

    def number(
        self, key: str, default: Any = ..., *, positive: bool = True, maximum: float = math.inf
    ) -> Any:
        """A finite number (YAML 1.1 reads ``1e12``, without a dot, as text: accepted too),
        positive if ``positive``, at most ``maximum``."""
        value = self.raw(key, default)
        if value is None:
            return None
        if isinstance(value, str) and _NUMBER_TEXT.fullmatch(value.strip()):
            value = float(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{self._name(key)}: expected a number, got {shown(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{self._name(key)}: expected a finite number, got {shown(value)}")
        if positive and value <= 0:
            raise ConfigError(f"{self._name(key)}: expected a positive number, got {shown(value)}")
        if value > maximum:
            raise ConfigError(
                f"{self._name(key)}: expected a number <= {maximum:g}, got {shown(value)}"
            )
        return float(value)

    def integer(
        self, key: str, default: Any = ..., *, minimum: int = 1, maximum: int = 2**31 - 1
    ) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
            raise ConfigError(
                f"{self._name(key)}: expected an integer in [{minimum}, {maximum}], "
                f"got {shown(value)}"
            )
        return value

    def choice(self, key: str, options: tuple[str, ...], default: Any = ...) -> str:
        value = self.raw(key, default)
        if value not in options:
            raise ConfigError(
                f"{self._name(key)}: expected one of {list(options)}, got {shown(value)}"
            )
        return str(value)

    def raster(self, key: str, base: Path) -> Path | str:
        """A raster: a local path, or an http(s) URL read window by window (``/vsicurl/``)."""
        from mars_pairs.raster.vsi import gdal_path, is_remote, use_remote_defaults

        value = self.raw(key)
        if isinstance(value, str) and is_remote(value):
            use_remote_defaults()
            return gdal_path(value)
        return self.path(key, base, folder=False)

    @overload
    def path(self, key: str, base: Path, *, folder: bool = True) -> Path: ...
    @overload
    def path(self, key: str, base: Path, default: None, *, folder: bool = True) -> Path | None: ...
    def path(
        self, key: str, base: Path, default: EllipsisType | None = ..., *, folder: bool = True
    ) -> Path | None:
        """A path, relative to ``base``; ConfigError if it names a FIFO, a socket or a device
        (``check_regular``: a regular file, a folder when ``folder``, or absent). Required
        unless ``default`` is None (then None when absent)."""
        value = self.raw(key, default)
        if value is None:
            return None
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{self._name(key)}: expected a path, got {shown(value)}")
        resolved = (base / Path(value).expanduser()).resolve()
        check_regular(resolved, self._name(key), folder=folder)
        return resolved
