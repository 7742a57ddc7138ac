"""argparse types and checks shared by the commands: finite, bounded numbers, counts, bands."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from mars_pairs.errors import UsageError


def finite(text: str) -> float:
    """argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def bounded(low: float, high: float, *, open_low: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number in [low, high] (or (low, high] with ``open_low``)."""

    def parse(text: str) -> float:
        value = finite(text)
        if value < low or value > high or (open_low and value == low):
            bracket = "(" if open_low else "["
            raise argparse.ArgumentTypeError(
                f"expected a number in {bracket}{low:g}, {high:g}], got {text!r}"
            )
        return value

    return parse


def count(minimum: int) -> Callable[[str], int]:
    """argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value

    return parse


def band(low: float | None, high: float | None, names: str) -> tuple[float, float] | None:
    """A (low, high) band from two options given together, or None when both are absent."""
    if low is None and high is None:
        return None
    if low is None or high is None:
        raise UsageError(f"{names}: give both bounds of the band, in degrees")
    return (low, high)


#: The libraries ``mars-pairs --version`` names (distribution names), in the order shown.
VERSIONED = ("numpy", "pyarrow", "rasterio", "shapely", "pyproj", "numba", "torch", "matplotlib")


def version_text() -> str:
    """Two lines: the package and Python versions; the key libraries' versions (``-`` for
    one not installed) and GDAL's, as rasterio links it. Read from the installed metadata,
    so nothing heavy is imported but rasterio (for GDAL)."""
    import platform
    from importlib import metadata

    from mars_pairs.version import __version__

    parts = []
    for name in VERSIONED:
        try:
            parts.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            parts.append(f"{name} -")
    try:
        import rasterio

        parts.insert(VERSIONED.index("rasterio") + 1, f"GDAL {rasterio.__gdal_version__}")
    except ImportError:  # pragma: no cover - rasterio is a core dependency
        pass
    return f"mars-pairs {__version__} (Python {platform.python_version()})\n" + ", ".join(parts)


class VersionAction(argparse.Action):
    """``--version``: print :func:`version_text` and exit 0 (computed only when asked)."""

    def __init__(
        self, option_strings: list[str], dest: str = argparse.SUPPRESS, help: str | None = None
    ) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        print(version_text())
        parser.exit(0)
