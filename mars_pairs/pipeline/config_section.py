"""Typed, named reading of one config mapping: every error names ``section.key``."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError

_NUMBER_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][+-]?[0-9]+", re.ASCII)


class Section:
    """Reads typed keys from one mapping, naming ``prefix.key`` in every error."""

    def __init__(self, data: Any, prefix: str, known: set[str]) -> None:
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(f"{prefix}: expected a mapping, got {type(data).__name__}")
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(
                f"{prefix}.{unknown[0]}: unknown key (expected one of {sorted(known)})"
            )
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
            raise ConfigError(f"{self._name(key)}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{self._name(key)}: expected a finite number, got {value!r}")
        if positive and value <= 0:
            raise ConfigError(f"{self._name(key)}: expected a positive number, got {value!r}")
        if value > maximum:
            raise ConfigError(f"{self._name(key)}: expected a number <= {maximum:g}, got {value!r}")
        return float(value)

    def integer(
        self, key: str, default: Any = ..., *, minimum: int = 1, maximum: int = 2**31 - 1
    ) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
            raise ConfigError(
                f"{self._name(key)}: expected an integer in [{minimum}, {maximum}], got {value!r}"
            )
        return value

    def choice(self, key: str, options: tuple[str, ...], default: Any = ...) -> str:
        value = self.raw(key, default)
        if value not in options:
            raise ConfigError(f"{self._name(key)}: expected one of {list(options)}, got {value!r}")
        return str(value)

    def raster(self, key: str, base: Path) -> Path | str:
        """A raster: a local path, or an http(s) URL read window by window (``/vsicurl/``)."""
        from mars_pairs.fetch.vsi import gdal_path, is_remote, use_remote_defaults

        value = self.raw(key)
        if isinstance(value, str) and is_remote(value):
            use_remote_defaults()
            return gdal_path(value)
        return self.path(key, base)  # type: ignore[return-value]

    def path(self, key: str, base: Path, default: Any = ...) -> Path | None:
        value = self.raw(key, default)
        if value is None:
            return None
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{self._name(key)}: expected a path, got {value!r}")
        return (base / Path(value).expanduser()).resolve()
