"""Shared helpers of the label readers: strict value coercion, times, files beside a label.

Every coercion failure raises ``LabelError(path, field, reason)``; nothing else escapes.
"""

from __future__ import annotations

import math
import os
import re
import signal
import stat
import threading
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
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

#: Largest integer a label field may hold (sol, site, drive, pose): the int32 maximum.
MAX_INTEGER = 2**31 - 1
#: Largest image side (lines or samples) accepted; real products are at most 5120.
MAX_IMAGE_SIDE = 100_000
#: Largest camera model component accepted (C in metres, H and V in pixels are far below).
MAX_MODEL_COMPONENT = 1e12
#: the smallest focal length (|A x H|, |A x V|, pixels) of a plausible camera model: the
#: widest real mast or hazard camera has ~ 250 px; 10 px would see nearly 180 deg across 1000
MIN_MODEL_SCALE = 10.0
#: the largest |cos| of the angle between the model's image axes (H' = H - hc A, V' = V - vc A);
#: real models have ~ 0 (perpendicular axes); 0.5 is 60 deg
MAX_AXIS_COS = 0.5
#: how far a model's field of view may be from the label's: the larger of 5 deg and 25 %
FOV_TOLERANCE_DEG, FOV_TOLERANCE_REL = 5.0, 0.25
#: Largest rover offset from its SITE origin accepted, per axis (metres): past Mars's diameter
#: (6.8e6 m) no offset places anything; real ones are hundreds of metres.
MAX_OFFSET_M = 1e7
#: Longest product id / instrument / frame name accepted (real ones are under 60).
MAX_ID_CHARS = 80
_ID_RE = re.compile(r"[A-Za-z0-9_.\-]+", re.ASCII)
_INT_RE = re.compile(r"[+-]?[0-9]+", re.ASCII)
_FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_DOY_RE = re.compile(r"(\d{4})-(\d{3})T(\d{2}):(\d{2}):(\d{2}(?:\.\d+)?)Z?", re.ASCII)


#: Labels (and the label head of a product with an attached label) are read up to this size.
MAX_LABEL_BYTES = 4 * 1024 * 1024
#: Wall-clock budget of parsing one label on a process's main thread (seconds); past it the
#: label is a LabelError. On every thread the structural bounds of the readers
#: (``pds3.check_structure``, ``xml.MAX_XML_MARKUP``) keep a parse far below it.
PARSE_SECONDS = 5.0


def read_bytes(path: Path, limit: int = MAX_LABEL_BYTES) -> tuple[bytes, bool]:
    """The first ``limit`` bytes of a regular file and whether the file is longer.

    A missing or unreadable file, one that is not a regular file (a directory, FIFO or
    device such as /dev/zero), or a path no file can have (a NUL byte) is a LabelError;
    nothing is read from non-regular files.
    """
    if "\x00" in str(path):
        raise LabelError(path, None, f"not a file path: {str(path)!r} holds a NUL byte")
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise LabelError(path, None, "not a regular file")
        with path.open("rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise LabelError(path, None, f"cannot read label: {exc.strerror or exc}") from exc
    return data[:limit], len(data) > limit


class _Overtime(Exception):
    """Raised inside a parse that ran past its time limit."""


@contextmanager
def time_limit(path: Path, seconds: float = PARSE_SECONDS) -> Iterator[None]:
    """Stop the enclosed parse with a LabelError once it has run ``seconds`` of wall time.

    Uses a real-time interval timer (SIGALRM), so it applies on the main thread of a process
    (the CLI, local build workers); on other threads (Dask workers) the readers' structural
    bounds alone bound the parse. A timer set by the caller is restored afterwards.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "setitimer"
    ):
        yield
        return

    armed = [True]

    def expire(signum: int, frame: object) -> None:
        if armed[0]:
            raise _Overtime

    previous = signal.signal(signal.SIGALRM, expire)
    outer_delay, outer_interval = signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    except _Overtime:
        raise LabelError(path, None, f"parsing took longer than {seconds:g} s") from None
    finally:
        armed[0] = False
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if outer_delay > 0:
            signal.setitimer(signal.ITIMER_REAL, outer_delay, outer_interval)


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

    def identifier(self, value: Any, field: str, limit: int = MAX_ID_CHARS) -> str:
        """Non-empty text of letters, digits and ``_ . -`` (product ids, instruments, frames):
        no spaces, slashes or colons, at most ``limit`` characters."""
        text = self.text(value, field)
        if not _ID_RE.fullmatch(text):
            self.fail(field, f"expected an identifier (letters, digits, _ . -), got {_show(text)}")
        if len(text) > limit:
            self.fail(field, f"longer than {limit} characters ({len(text)})")
        return text

    def integer(
        self, value: Any, field: str, minimum: int | None = 0, maximum: int = 2**31 - 1
    ) -> int:
        """An integer (an int, or text of decimal digits) in [``minimum``, ``maximum``]
        (the manifest's int32 columns by default)."""
        if isinstance(value, str) and _INT_RE.fullmatch(value.strip()):
            if len(value.strip()) > 40:  # int() of thousands of digits is slow, then refused
                self.fail(field, f"expected an integer <= {maximum}, got {_show(value)}")
            value = int(value.strip())
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(field, f"expected an integer, got {_show(value)}")
        if minimum is not None and value < minimum:
            self.fail(field, f"expected an integer >= {minimum}, got {_show(value)}")
        if value > maximum:
            self.fail(field, f"expected an integer <= {maximum}, got {_show(value)}")
        return value

    def image_side(self, value: Any, field: str) -> int:
        """An image's line or sample count: 1 to MAX_IMAGE_SIDE."""
        return self.integer(value, field, 1, MAX_IMAGE_SIDE)

    def number(self, value: Any, field: str) -> float:
        """A finite real number (int, float, numeric text, or a quantity with units)."""
        value = quantity_value(value)
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

    def offset_m(self, values: np.ndarray, field: str) -> np.ndarray:
        """An offset in metres (any frame) within ``MAX_OFFSET_M`` on every axis."""
        if not np.all(np.abs(values) <= MAX_OFFSET_M):
            self.fail(field, f"offset beyond {MAX_OFFSET_M:g} m: {values.tolist()}")
        return values

    def quaternion(self, values: Sequence[float] | np.ndarray, field: str) -> np.ndarray:
        """A (s, v1, v2, v3) quaternion of norm close to 1, normalised."""
        q = np.asarray(values, dtype=np.float64)
        with np.errstate(over="ignore", under="ignore"):  # an inf norm is refused below
            norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            self.fail(field, f"expected a unit quaternion, norm is {norm:.6g}")
        return q / norm

    def angle(self, value: Any, field: str, lo: float, hi: float) -> float:
        """A finite number within [lo, hi] (degrees; a quantity must say degrees)."""
        units = quantity_units(value)
        if units is not None and units.strip().lower() not in ("deg", "degree", "degrees"):
            self.fail(field, f"expected degrees, got units {units!r}")
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

    def local_time(self, value: Any, field: str, sol: int | None = None) -> str:
        """A local solar time of day as "HH:MM:SS[.fff]" (Mars hours of 1/24 sol), from
        "HH:MM:SS[.fff]" or "Sol-NNNNNM" before it (Curiosity's and Perseverance's form,
        whose sol must be ``sol`` when given)."""
        text = self.text(value, field).strip()
        match = _LOCAL_TIME_RE.fullmatch(text)
        if match is None:
            self.fail(
                field, f"expected a local time HH:MM:SS or Sol-NNNNNMHH:MM:SS, got {_show(value)}"
            )
        day, hh, mm, ss = match.group(1), int(match[2]), int(match[3]), float(match[4])
        if hh > 24 or mm > 59 or ss >= 61:
            self.fail(field, f"not a time of day: {_show(value)}")
        if day is not None and sol is not None and int(day) != sol:
            self.fail(field, f"sol {int(day)} is not the label's sol {sol}")
        return text[match.start(2) :]

    def model_type_code(self, value: Any, field: str) -> int:
        """CAHVORE's model type: 1, 2 or 3 (labels write it as an integer or a real, "3.0")."""
        number = self.number(value, field)
        if number not in (1.0, 2.0, 3.0):
            self.fail(field, f"expected CAHVORE model type 1, 2 or 3, got {number:g}")
        return int(number)

    def camera(self, field: str, kind: str, vectors: dict[str, Any], frame: str) -> CameraModel:
        """Build the CameraModel; its ValueError, a component beyond 1e12 (no projection
        survives it), or an A / O that is not a unit vector (within 1 %), is a LabelError."""
        for name in ("c", "a", "h", "v", "o", "r", "e"):
            vec = vectors.get(name)
            if vec is not None and not np.all(np.abs(vec) <= MAX_MODEL_COMPONENT):
                self.fail(field, f"{name.upper()} of the {kind} model exceeds 1e12: {vec.tolist()}")
        for name in ("a", "o"):
            vec = vectors.get(name)
            if vec is not None and not abs(float(np.linalg.norm(vec)) - 1.0) <= 0.01:
                norm = float(np.linalg.norm(vec))
                self.fail(field, f"{name.upper()} of the {kind} model is not a unit vector "
                                 f"(norm {norm:.6g})")  # fmt: skip
        try:
            model = CameraModel(model_type=kind, frame=frame, **vectors)
        except ValueError as exc:
            self.fail(field, f"invalid {kind} camera model: {exc}")
        problem = degenerate(model)
        if problem is not None:
            self.fail(field, f"degenerate {kind} camera model: {problem}")
        return model


def degenerate(model: CameraModel) -> str | None:
    """What makes ``model`` no camera (H or V without a component across A, a focal length
    under MIN_MODEL_SCALE pixels, image axes less than 60 deg apart), or None."""
    if model.hs < MIN_MODEL_SCALE or model.vs < MIN_MODEL_SCALE:
        return (
            f"focal lengths |A x H| = {model.hs:.6g}, |A x V| = {model.vs:.6g} px "
            f"(at least {MIN_MODEL_SCALE:g} px)"
        )
    h = model.h - model.hc * model.a
    v = model.v - model.vc * model.a
    cos = float(abs(h @ v) / (np.linalg.norm(h) * np.linalg.norm(v)))
    if cos > MAX_AXIS_COS:
        return f"image axes H and V are {np.degrees(np.arccos(min(cos, 1.0))):.3g} deg apart"
    return None


def fov_problem(model_deg: float, label_deg: float | None) -> str | None:
    """Whether a model's field of view ``model_deg`` disagrees with the label's
    ``label_deg`` beyond the tolerance (FOV_TOLERANCE_DEG or FOV_TOLERANCE_REL, the larger)."""
    if label_deg is None:
        return None
    if not np.isfinite(model_deg):
        return f"the model's field of view is {model_deg} (label {label_deg:.4g} deg)"
    tolerance = max(FOV_TOLERANCE_DEG, FOV_TOLERANCE_REL * label_deg)
    if abs(model_deg - label_deg) > tolerance:
        return (
            f"the camera model sees {model_deg:.4g} deg, the label says {label_deg:.4g} deg "
            f"(tolerance {tolerance:.3g} deg)"
        )
    return None


def quantity_value(value: Any) -> Any:
    """The number of a ``value <units>`` quantity (pdr: a {'value', 'units'} mapping)."""
    if isinstance(value, Mapping) and set(value) == {"value", "units"}:
        return value["value"]
    return value


def quantity_units(value: Any) -> str | None:
    """The units of a quantity, or None for a plain value."""
    if isinstance(value, Mapping) and set(value) == {"value", "units"}:
        return str(value["units"])
    return None


_LOCAL_TIME_RE = re.compile(
    r"(?:Sol-?([0-9]{1,6})M)?([0-9]{1,2}):([0-9]{2}):([0-9]{2}(?:\.[0-9]+)?)"
)


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
