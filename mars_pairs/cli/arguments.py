"""argparse types and checks shared by the commands: finite, bounded numbers, counts, bands,
a local dataset folder, and the one output convention (``--out``)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import NoReturn

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


def local_dataset(value: str) -> str:
    """An argument naming a dataset folder on this machine: a URL is refused, naming the
    commands that read object storage."""
    from mars_pairs.store.fs import is_url

    if is_url(value):
        raise argparse.ArgumentTypeError(
            f"{value}: this command reads a dataset folder on this machine; `inspect`, "
            "`verify` and the Python datasets (MarsPairsDataset, Manifest) read object "
            "storage: copy the dataset here first (e.g. `aws s3 sync`)"
        )
    return value


def add_out(
    p: argparse.ArgumentParser, help: str, *, required: bool = False, positional: bool = False
) -> None:
    """Every command's output argument: ``--out PATH`` (``args.out``). ``positional``: the
    command's earlier spelling, a positional ``OUT`` (still accepted; :func:`out_path` reads
    either). ``required``: one of the two must be given."""
    if positional:
        p.add_argument("out_positional", nargs="?", metavar="OUT", help=f"{help} (or --out)")
        p.add_argument("--out", help=help)
        p.set_defaults(out_required=required)
    else:
        p.add_argument("--out", required=required, help=help)


def out_path(args: argparse.Namespace) -> str | None:
    """The output a command was given (``--out``, or the positional ``OUT`` of
    :func:`add_out`); UsageError if both are given, or none where one is required."""
    given = [v for v in (args.out, getattr(args, "out_positional", None)) if v is not None]
    if len(given) > 1:
        raise UsageError("give the output once: OUT or --out")
    if not given and getattr(args, "out_required", False):
        raise UsageError("the output is required: --out PATH")
    return str(given[0]) if given else None


def required_out_path(args: argparse.Namespace) -> str:
    """The output of a command whose output is required (:func:`out_path`)."""
    out = out_path(args)
    if out is None:
        raise UsageError("the output is required: --out PATH")
    return out


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


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (``PROG: error: MESSAGE (see
    PROG --help)``), exit status 2, as the commands' own errors are; ``--help`` unchanged."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
