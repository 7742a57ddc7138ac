"""Shared helpers of the label readers: strict value coercion, times, files beside a label.

Every coercion failure raises ``LabelError(path, field, reason)``; nothing else escapes.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from datetime import date, datetime, timezone
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from mars_pairs.errors import LabelError
from mars_pairs.geometry.camera import CameraModel

PathLike = str | os.PathLike[str]

# Values PDS labels use for "no value" (PDS3 "NULL"/"N/A"/"UNK", empty XML elements).
NULL_TOKENS = frozenset({"", "NULL", "N/A", "UNK", "NONE"})
BROWSE_SUFFIXES = (".jpg", ".JPG", ".jpeg", ".JPEG", ".png", ".PNG")

_INT_RE = re.compile(r"[+-]?[0-9]+", re.ASCII)
_FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_DOY_RE = re.compile(r"(\d{4})-(\d{3})T(\d{2}):(\d{2}):(\d{2}(?:\.\d+)?)Z?", re.ASCII)


def read_bytes(path: Path) -> bytes:
    """The file's bytes; a missing or unreadable file is a LabelError."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise LabelError(path, None, f"cannot read label: {exc.strerror or exc}") from exc


def is_null(value: Any) -> bool:
    """True for the label's "no value" markers (None, "NULL", "N/A", "UNK", empty text)."""
    if value is None:
        return True
    return isinstance(value, str) and value.strip().upper() in NULL_TOKENS


class Fields:
    """Strict coercion of raw label values, raising LabelError naming ``path`` and the field."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, field: str | None, reason: str) -> NoReturn:
        """Raise the LabelError for ``field``."""
        raise LabelError(self.path, field, reason)

    def text(self, value: Any, field: str) -> str:
        """A non-empty string."""
        if not isinstance(value, str) or not value.strip():
            self.fail(field, f"expected non-empty text, got {_show(value)}")
        return value.strip()

    def integer(self, value: Any, field: str, minimum: int | None = 0) -> int:
        """An integer (an int, or text of decimal digits), at least ``minimum``."""
        if isinstance(value, str) and _INT_RE.fullmatch(value.strip()):
            value = int(value.strip())
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(field, f"expected an integer, got {_show(value)}")
        if minimum is not None and value < minimum:
            self.fail(field, f"expected an integer >= {minimum}, got {value}")
        return value

    def number(self, value: Any, field: str) -> float:
        """A finite real number (int, float, pvl Quantity or numeric text)."""
        if hasattr(value, "value") and hasattr(value, "units"):  # pvl Quantity
            value = value.value
        if isinstance(value, str) and _FLOAT_RE.fullmatch(value.strip()):
            value = float(value.strip())
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(field, f"expected a number, got {_show(value)}")
        result = float(value)
        if not math.isfinite(result):
            self.fail(field, f"expected a finite number, got {result}")
        return result

    def vector(self, value: Any, n: int, field: str) -> np.ndarray:
        """A sequence of exactly ``n`` finite numbers, as a float64 array."""
        if isinstance(value, str | bytes) or not isinstance(value, Sequence):
            self.fail(field, f"expected a list of {n} numbers, got {_show(value)}")
        if len(value) != n:
            self.fail(field, f"expected {n} numbers, got {len(value)}")
        return np.array([self.number(v, field) for v in value], dtype=np.float64)

    def quaternion(self, values: Sequence[float], field: str) -> np.ndarray:
        """A (s, v1, v2, v3) quaternion of norm close to 1, normalised."""
        q = np.asarray(values, dtype=np.float64)
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            self.fail(field, f"expected a unit quaternion, norm is {norm:.6g}")
        return q / norm

    def angle(self, value: Any, field: str, lo: float, hi: float) -> float:
        """A finite number within [lo, hi] (degrees)."""
        result = self.number(value, field)
        if not lo <= result <= hi:
            self.fail(field, f"expected a value in [{lo:g}, {hi:g}], got {result:g}")
        return result

    def time(self, value: Any, field: str) -> datetime:
        """A UTC datetime from a datetime/date value or ISO (or day-of-year) text."""
        if isinstance(value, str):
            parsed = parse_time(value)
            if parsed is None:
                self.fail(field, f"expected an ISO time, got {_show(value)}")
            return parsed
        if isinstance(value, datetime):
            return value if value.tzinfo else value.replace(tzinfo=timezone.utc)
        if isinstance(value, date):
            return datetime(value.year, value.month, value.day, tzinfo=timezone.utc)
        self.fail(field, f"expected a time, got {_show(value)}")

    def camera(
        self, field: str, kind: str, vectors: dict[str, np.ndarray], frame: str
    ) -> CameraModel:
        """Build the CameraModel; its ValueError, or a zero axis, becomes a LabelError."""
        for name in ("a", "o"):
            vec = vectors.get(name)
            if vec is not None and not np.linalg.norm(vec) > 0.0:
                self.fail(field, f"{name.upper()} vector of the {kind} model is zero")
        try:
            return CameraModel(model_type=kind, frame=frame, **vectors)
        except ValueError as exc:
            self.fail(field, f"invalid {kind} camera model: {exc}")


def parse_time(text: str) -> datetime | None:
    """Parse an ISO 8601 UTC time ("...Z" or naive) or PDS day-of-year form; None if invalid."""
    text = text.strip()
    match = _DOY_RE.fullmatch(text)
    if match:
        year, doy, hh, mm, ss = match.groups()
        try:
            base = datetime.strptime(f"{year}-{doy}", "%Y-%j")
            sec = float(ss)
            return base.replace(
                hour=int(hh), minute=int(mm), second=int(sec),
                microsecond=round((sec % 1) * 1e6) % 1_000_000, tzinfo=timezone.utc,
            )  # fmt: skip
        except ValueError:
            return None
    if text.endswith(("Z", "z")):
        text = text[:-1] + "+00:00"
    try:
        parsed = datetime.fromisoformat(text)
    except ValueError:
        return None
    if parsed.tzinfo is None:
        return parsed.replace(tzinfo=timezone.utc)
    return parsed.astimezone(timezone.utc)


def file_beside(label_path: Path, name: str) -> Path | None:
    """The file ``name`` in the label's folder (exact name, else a case-insensitive match)."""
    name = name.strip()
    if not name or Path(name).name != name:
        return None
    exact = label_path.parent / name
    try:
        if exact.is_file():
            return exact
        for entry in label_path.parent.iterdir():
            if entry.name.lower() == name.lower() and entry.is_file():
                return entry
    except OSError:
        return None
    return None


def browse_beside(label_path: Path) -> Path | None:
    """A .jpg/.png with the label's stem beside it, or None."""
    for suffix in BROWSE_SUFFIXES:
        candidate = label_path.with_suffix(suffix)
        try:
            if candidate.is_file():
                return candidate
        except OSError:
            return None
    return None


def image_beside(label_path: Path, pointed: str | None) -> Path | None:
    """The image the label points to if present beside it, else its browse image, else None."""
    if pointed:
        found = file_beside(label_path, pointed)
        if found is not None:
            return found
    return browse_beside(label_path)


def _show(value: Any) -> str:
    """A short repr of a bad value for error messages."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
