"""Curiosity PDS3 labels (``.LBL``, or attached at the start of an ``.IMG``) -> Observation.

Parsed with pdr's PDS3 label parser (``pdr.parselabel.pds3.parse_pvl``): ~3 ms per Mastcam
label against ~130 ms for ``pvl.loads``; ``tests/pds/test_pds3_pdr.py`` shows every field read
here equals what pvl reads, on every real label in ``../shared/pds-samples``. The parse runs
under a size limit (``common.MAX_LABEL_BYTES``), after a linear pre-scan that bounds the
structure pdr is handed (``check_structure``), so that parsing is bounded in time and memory on
any thread; on a process's main thread a wall-clock limit (``common.time_limit``) applies too.

Products: Mastcam RDRs (``GEOMETRIC_CAMERA_MODEL_PARMS``, ``DERIVED_IMAGE_PARMS``) and the
MIPL-processed Navcam, Hazcam and MAHLI EDRs/RDRs (``GEOMETRIC_CAMERA_MODEL``,
``SITE_DERIVED_GEOMETRY_PARMS``, label attached to the image). Camera models: CAHV, CAHVOR and
CAHVORE (MODEL_COMPONENT_7..9 = E, T, P).

Required keywords (a LabelError names the one at fault): PRODUCT_ID, INSTRUMENT_ID,
PLANET_DAY_NUMBER, ROVER_MOTION_COUNTER(_NAME) with SITE and DRIVE, the camera model group
and the IMAGE object's LINES / LINE_SAMPLES. Optional ones (rover pose, derived pointing, FOV,
time) are None when absent or "NULL"/"N/A"/"UNK", and a LabelError when present but malformed.
"""

from __future__ import annotations

import re
import warnings
from collections import Counter
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from mars_pairs.errors import LabelError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.pds.common import (
    PARSE_SECONDS,
    Fields,
    PathLike,
    image_beside,
    is_null,
    read_bytes,
    time_limit,
)

MISSION = "msl"
CAMERA_GROUPS = ("GEOMETRIC_CAMERA_MODEL_PARMS", "GEOMETRIC_CAMERA_MODEL")
ROVER_GROUPS = ("ROVER_COORDINATE_SYSTEM_PARMS", "ROVER_COORDINATE_SYSTEM")
DERIVED_GROUP = "DERIVED_IMAGE_PARMS"
SITE_DERIVED_GROUP = "SITE_DERIVED_GEOMETRY_PARMS"
STATE_GROUP = "INSTRUMENT_STATE_PARMS"
_COMPONENTS = {"CAHV": "cahv", "CAHVOR": "cahvor", "CAHVORE": "cahvore"}
_END_RE = re.compile(rb"^[ \t]*END[ \t]*\r?$", re.MULTILINE)
# pdr turns values into Python objects with ast.literal_eval, which also reads Python-only
# syntax that PDS3 does not have: a '#' starts a comment ("12002#101#" -> 12002), digits may
# hold '_' ("1_000"), 0x/0o/0b prefixes and complex numbers. Such text is refused first.
_QUOTED = re.compile(r'"[^"]*"')
_RADIX = re.compile(r"(?<![\w#])[+-]?\d{1,2}#[+-]?[0-9A-Za-z]+#(?![\w#])")
_NOT_PDS3_NUMBER = re.compile(
    r"#|\b\d+(?:_\d+)+\b|\b0[xXoObB][0-9A-Fa-f_]+\b|\b\d+(?:\.\d*)?(?:[eE][+-]?\d+)?[jJ]\b"
)
# pdr's comment stripping (``parse_pvl``): a comment runs from "/*" to the end of its line or
# to the next "/*", whatever follows; one pass, at most one line per match.
_PDR_COMMENT = re.compile(r"/\*.*?(\r|\n|/\*)")

# Bounds of the structure handed to pdr (``check_structure``). The real Curiosity labels in
# ../shared/pds-samples/msl have 22,320-22,563 characters, 491-495 lines, 25 comments,
# 283-285 statements, values of at most 268 characters, 219-227 commas, GROUP/OBJECT depth 1,
# no keyword twice in one GROUP/OBJECT and 2 pointers (^IMAGE, ^MODEL_DESC), none repeated.
# The size bounds are 35 to 250 times those figures, depth and repeats 16 and 64 against 1,
# repeated pointers 8 against none; what pdr 1.4.4 costs at the bounds is measured by
# benchmarks/bench_labels.py (~1.5 s at most on a loaded machine, against 59 s to hours).
#: Characters of the label text (up to its END line), ~0.5 us apiece for pdr at worst.
MAX_TEXT_CHARS = 1024 * 1024
#: Lines (newlines plus comment starts, each of which may end a line for pdr).
MAX_LINES = 50_000
#: Statements (``KEY = value``, GROUP/OBJECT and their ends) as pdr chunks them.
MAX_STATEMENTS = 10_000
#: Characters of one statement's value (its continuation lines joined).
MAX_VALUE_CHARS = 65_536
#: Commas in all values: each is a sequence item that ``ast.literal_eval`` (and, for
#: ``1 <m>`` quantities, a regular expression) turns into an object, ~2 to 13 us apiece.
MAX_SEPARATORS = 10_000
#: GROUP/OBJECT nesting depth.
MAX_DEPTH = 16
#: Times one keyword may occur in one GROUP/OBJECT (OBJECT = COLUMN style repeats included).
MAX_KEY_REPEATS = 64
#: Pointer statements (``^NAME``) that share their name with another, anywhere in the label.
#: pdr's ``index_duplicate_pointers`` copies the whole label (``multidict_dig_and_edit``)
#: twice per such statement: quadratic, 59 s for 10,000 ``^A = 1`` lines.
MAX_REPEATED_POINTERS = 8


def read_pds3(path: PathLike) -> Observation:
    """Read a PDS3 label (detached or attached) into an Observation (LabelError on any fault)."""
    label_path = Path(path)
    data, longer = read_bytes(label_path)
    return parse_pds3(data, label_path, longer)


def parse_pds3(data: bytes, path: Path, longer: bool = False) -> Observation:
    """Parse the PDS3 label at the start of ``data`` (the first bytes of the file at ``path``;
    ``longer``: the file goes on past them). An attached label is cut at its END line."""
    return observation_from_label(load_label(data, path, longer), path)


def load_label(data: bytes, path: Path, longer: bool = False) -> Mapping[str, Any]:
    """Decode and parse the label text; any decoding or parser failure is a LabelError."""
    end = _END_RE.search(data)
    if end is not None:
        data = data[: end.end()]
    elif longer:
        raise LabelError(path, None, f"no END line in the first {len(data)} bytes")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LabelError(path, None, f"not a text label (bad byte at {exc.start})") from exc
    if "\x00" in text:
        raise LabelError(path, None, "not a text label (NUL bytes)")
    check_structure(text, path)
    _refuse_python_only_numbers(text, path)
    from pdr.parselabel.pds3 import parse_pvl

    try:
        with time_limit(path, PARSE_SECONDS), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pdr warns about unclosed groups: checked below
            label, _ = parse_pvl(text)
    except LabelError:
        raise
    except Exception as exc:  # pdr's literal parsing raises RecursionError, MemoryError, ...
        raise LabelError(path, None, f"not a readable PDS3 label: {_brief(exc)}") from exc
    if not isinstance(label, Mapping) or len(label) == 0:
        raise LabelError(path, None, "not a PDS3 label (no keywords)")
    return label


def check_structure(text: str, path: Path) -> None:
    """LabelError if the label text exceeds a structural bound (``MAX_*`` above).

    The statements are those pdr parses (its own comment stripping and
    ``pdr.parselabel.pds3.chunk_statements``); the scan is one pass over them after the line
    count, itself a C-speed count, has bounded their number. With every bound met, pdr's
    ``parse_pvl`` is bounded too: its quadratic step, ``index_duplicate_pointers`` (a full
    copy of the label per repeated pointer), by ``MAX_REPEATED_POINTERS``; ``literal_eval`` of
    the values by ``MAX_VALUE_CHARS`` and ``MAX_SEPARATORS``; its recursion by ``MAX_DEPTH``.
    """
    from pdr.parselabel.pds3 import PVL_BLOCK_INITIALS, chunk_statements

    if len(text) > MAX_TEXT_CHARS:
        reason = f"label text of {len(text):,} characters (at most {MAX_TEXT_CHARS:,})"
        raise LabelError(path, None, reason)
    lines = text.count("\n") + text.count("/*")
    if lines > MAX_LINES:
        raise LabelError(path, None, f"{lines:,} lines and comments (at most {MAX_LINES:,})")
    uncommented = _PDR_COMMENT.sub("\n", text)
    statements = chunk_statements(filter(None, map(str.strip, uncommented.split("\n"))))
    scopes: list[Counter[str]] = [Counter()]
    firsts: list[dict[str, str]] = [{}]  # each scope's keys' first values
    pointers: Counter[str] = Counter()
    separators = 0
    for key, value in statements:
        if len(value) > MAX_VALUE_CHARS:
            reason = f"a value of {len(value):,} characters (at most {MAX_VALUE_CHARS:,})"
            raise LabelError(path, key, reason)
        separators += value.count(",")
        if key in PVL_BLOCK_INITIALS:
            scopes.append(Counter())
            firsts.append({})
            if len(scopes) - 1 > MAX_DEPTH:
                reason = f"GROUP/OBJECT nested deeper than {MAX_DEPTH} ({value[:60]!r})"
                raise LabelError(path, key, reason)
        elif key.startswith("END"):  # pdr closes a block on any END* statement
            if len(scopes) > 1:
                scopes.pop()
                firsts.pop()
        else:
            scopes[-1][key] += 1
            if scopes[-1][key] > MAX_KEY_REPEATS:
                reason = f"repeated more than {MAX_KEY_REPEATS} times in one GROUP/OBJECT"
                raise LabelError(path, key, reason)
            if key.startswith("^"):
                pointers[key] += 1
            else:  # a keyword given twice in one group with two values: which is meant?
                given = " ".join(value.split())
                first = firsts[-1].setdefault(key, given)
                if first != given:
                    reason = (
                        f"given twice in one GROUP/OBJECT with different values ({first[:40]!r}, "
                        f"then {given[:40]!r})"
                    )
                    raise LabelError(path, key, reason)
    if len(statements) > MAX_STATEMENTS:
        reason = f"{len(statements):,} statements (at most {MAX_STATEMENTS:,})"
        raise LabelError(path, None, reason)
    if separators > MAX_SEPARATORS:
        raise LabelError(path, None, f"{separators:,} commas (at most {MAX_SEPARATORS:,})")
    repeated = {key: n for key, n in pointers.items() if n > 1}
    if sum(repeated.values()) > MAX_REPEATED_POINTERS:
        key = max(repeated, key=repeated.__getitem__)
        reason = (f"{sum(repeated.values())} pointer statements share a name "
                  f"(at most {MAX_REPEATED_POINTERS}; {key} {repeated[key]} times)")  # fmt: skip
        raise LabelError(path, key, reason)


def _refuse_python_only_numbers(text: str, path: Path) -> None:
    """LabelError at the first value pdr's literal parsing would misread (see above).

    Comments are blanked as pdr strips them (to the end of the line), then quoted text; both
    passes are linear in the text, unclosed comments included.
    """
    bare = _PDR_COMMENT.sub(_blank_comment, text)
    bare = _QUOTED.sub(lambda m: " " * len(m.group()), bare)
    bare = _RADIX.sub(lambda m: " " * len(m.group()), bare)
    bad = _NOT_PDS3_NUMBER.search(bare)
    if bad is not None:
        start = text.rfind("\n", 0, bad.start()) + 1
        end = text.find("\n", bad.start())
        shown = text[start : None if end < 0 else end].strip()
        key = re.match(r"\s*([A-Za-z^][\w:^]*)\s*=", text[start:])
        line = text.count("\n", 0, bad.start()) + 1
        field = key.group(1) if key else None
        raise LabelError(path, field, f"line {line}: not a PDS3 value ({shown[:60]!r})")


def _blank_comment(match: re.Match[str]) -> str:
    """A comment matched by ``_PDR_COMMENT`` as spaces, its line end kept (positions kept)."""
    end = match.group(1)
    return " " * (len(match.group()) - len(end)) + (end if end in ("\r", "\n") else "  ")


def observation_from_label(label: Mapping[str, Any], path: Path) -> Observation:
    """The Observation of a parsed PDS3 label (any mapping: pdr's MultiDict or pvl's module)."""
    f = Fields(path)
    image = _image(f, label)
    return Observation(
        label_path=path,
        mission=MISSION,
        product_id=f.identifier(_require(f, label, "PRODUCT_ID"), "PRODUCT_ID"),
        instrument=f.identifier(_require(f, label, "INSTRUMENT_ID"), "INSTRUMENT_ID").upper(),
        sol=f.integer(_require(f, label, "PLANET_DAY_NUMBER"), "PLANET_DAY_NUMBER"),
        rmc=_motion_counter(f, label),
        width=f.image_side(_require(f, image, "LINE_SAMPLES"), "LINE_SAMPLES"),
        height=f.image_side(_require(f, image, "LINES"), "LINES"),
        camera=_camera(f, label),
        **_rover_pose(f, label),
        **_pointing(f, label),
        start_time=_start_time(f, label),
        image_path=_image_path(path, label),
        lmst=_lmst(f, label),
    )


def _brief(exc: BaseException) -> str:
    """The first line of an exception message, shortened (its type if it has none)."""
    lines = str(exc).splitlines() or [type(exc).__name__]
    return f"{type(exc).__name__}: {lines[0][:200]}"


def _require(f: Fields, container: Mapping[str, Any], key: str, where: str = "") -> Any:
    """The value of ``key``; missing or "NULL" is a LabelError."""
    value = container.get(key)
    if is_null(value):
        state = "missing" if value is None else f"has no value ({value!r})"
        f.fail(key, f"required keyword {state}{f' in {where}' if where else ''}")
    return value


def _group(f: Fields, label: Mapping[str, Any], name: str, required: bool) -> Mapping[str, Any]:
    """The GROUP/OBJECT ``name`` as a mapping ({} if optional and absent)."""
    value = label.get(name)
    if value is None:
        if required:
            f.fail(name, "required group missing")
        return {}
    if not isinstance(value, Mapping):
        f.fail(name, f"expected a GROUP or OBJECT, got {type(value).__name__}")
    return value


def _image(f: Fields, label: Mapping[str, Any]) -> Mapping[str, Any]:
    """The top-level IMAGE object (not IMAGE_REQUEST_PARMS, whose LINES differ)."""
    return _group(f, label, "IMAGE", required=True)


def _as_list(value: Any) -> list[Any]:
    """A pvl sequence as a list; a scalar as a one-element list; a set stays unordered (error)."""
    if isinstance(value, list | tuple):
        return list(value)
    return [value]


def _motion_counter(f: Fields, label: Mapping[str, Any]) -> MotionCounter:
    """SITE, DRIVE (and POSE) of ROVER_MOTION_COUNTER, located by ROVER_MOTION_COUNTER_NAME."""
    names = _as_list(_require(f, label, "ROVER_MOTION_COUNTER_NAME"))
    values = _as_list(_require(f, label, "ROVER_MOTION_COUNTER"))
    keys = [f.text(n, "ROVER_MOTION_COUNTER_NAME").upper() for n in names]
    if len(keys) != len(values):
        f.fail(
            "ROVER_MOTION_COUNTER",
            f"has {len(values)} values but ROVER_MOTION_COUNTER_NAME has {len(keys)} names",
        )
    index = dict(zip(keys, values, strict=True))
    for needed in ("SITE", "DRIVE"):
        if needed not in index:
            f.fail("ROVER_MOTION_COUNTER_NAME", f"no {needed} entry")
    pose = index.get("POSE")
    return MotionCounter(
        site=f.integer(index["SITE"], "ROVER_MOTION_COUNTER"),
        drive=f.integer(index["DRIVE"], "ROVER_MOTION_COUNTER"),
        pose=None if pose is None else f.integer(pose, "ROVER_MOTION_COUNTER"),
    )


def _camera(f: Fields, label: Mapping[str, Any]) -> CameraModel:
    """The CAHV/CAHVOR/CAHVORE model: MODEL_COMPONENT_1..9 = C, A, H, V, O, R, E, T, P.

    Mastcam RDRs name the group GEOMETRIC_CAMERA_MODEL_PARMS, MIPL products
    GEOMETRIC_CAMERA_MODEL; either is read (the first present, in that order).
    """
    name = next((g for g in CAMERA_GROUPS if label.get(g) is not None), CAMERA_GROUPS[0])
    group = _group(f, label, name, required=True)
    kind = f.text(_require(f, group, "MODEL_TYPE", name), "MODEL_TYPE").upper()
    if kind not in _COMPONENTS:
        f.fail("MODEL_TYPE", f"unsupported camera model {kind!r} (CAHV, CAHVOR or CAHVORE)")
    vectors: dict[str, Any] = {}
    for i, letter in enumerate(_COMPONENTS[kind], start=1):
        key = f"MODEL_COMPONENT_{i}"
        vectors[letter] = f.vector(_require(f, group, key, name), 3, key)
    if kind == "CAHVORE":
        vectors["mtype"] = f.model_type_code(_require(f, group, "MODEL_COMPONENT_8", name),
                                             "MODEL_COMPONENT_8")  # fmt: skip
        vectors["mparm"] = f.number(_require(f, group, "MODEL_COMPONENT_9", name),
                                    "MODEL_COMPONENT_9")  # fmt: skip
    key = "REFERENCE_COORD_SYSTEM_NAME"
    frame = f.identifier(_require(f, group, key, name), key).upper()
    return f.camera(name, kind, vectors, frame)


class _RoverPose(TypedDict):
    """The ``Observation`` fields of a label's rover pose (``_rover_pose``)."""

    rover_offset_m: np.ndarray | None
    rover_quaternion: np.ndarray | None


class _Pointing(TypedDict):
    """The ``Observation`` fields of a label's pointing (``_pointing``)."""

    azimuth_deg: float | None
    elevation_deg: float | None
    hfov_deg: float | None
    vfov_deg: float | None


def _rover_pose(f: Fields, label: Mapping[str, Any]) -> _RoverPose:
    """ROVER_NAV_FRAME origin (metres, SITE_FRAME) and quaternion (ROVER_NAV_FRAME ->
    SITE_FRAME); None if absent or given in another frame."""
    none: _RoverPose = {"rover_offset_m": None, "rover_quaternion": None}
    name = next((g for g in ROVER_GROUPS if label.get(g) is not None), ROVER_GROUPS[0])
    group = _group(f, label, name, required=False)
    frame = group.get("COORDINATE_SYSTEM_NAME", "ROVER_NAV_FRAME")
    reference = group.get("REFERENCE_COORD_SYSTEM_NAME", "SITE_FRAME")
    if frame != "ROVER_NAV_FRAME" or reference != "SITE_FRAME":
        return none
    offset = group.get("ORIGIN_OFFSET_VECTOR")
    quaternion = group.get("ORIGIN_ROTATION_QUATERNION")
    if is_null(offset) or is_null(quaternion):
        return none
    q = f.vector(quaternion, 4, "ORIGIN_ROTATION_QUATERNION")
    xyz = f.vector(offset, 3, "ORIGIN_OFFSET_VECTOR")
    return {
        "rover_offset_m": f.offset_m(xyz, "ORIGIN_OFFSET_VECTOR"),
        "rover_quaternion": f.quaternion(q, "ORIGIN_ROTATION_QUATERNION"),
    }


def _pointing(f: Fields, label: Mapping[str, Any]) -> _Pointing:
    """Derived SITE_FRAME azimuth/elevation and the field of view (each optional).

    Mastcam RDRs: DERIVED_IMAGE_PARMS FIXED_INSTRUMENT_AZIMUTH/ELEVATION. MIPL products:
    SITE_DERIVED_GEOMETRY_PARMS INSTRUMENT_AZIMUTH/ELEVATION (``<deg>`` quantities), taken only
    when the group's REFERENCE_COORD_SYSTEM_NAME is SITE_FRAME (or absent).
    """
    derived = _group(f, label, DERIVED_GROUP, required=False)
    site = _group(f, label, SITE_DERIVED_GROUP, required=False)
    state = _group(f, label, STATE_GROUP, required=False)
    if not is_null(site.get("REFERENCE_COORD_SYSTEM_NAME")) and (
        str(site.get("REFERENCE_COORD_SYSTEM_NAME")).upper() != "SITE_FRAME"
    ):
        site = {}

    def get(group: Mapping[str, Any], key: str, lo: float, hi: float) -> float | None:
        value = group.get(key)
        return None if is_null(value) else f.angle(value, key, lo, hi)

    def either(key: str, lo: float, hi: float) -> float | None:
        fixed = get(derived, f"FIXED_{key}", lo, hi)
        return fixed if fixed is not None else get(site, key, lo, hi)

    return {
        "azimuth_deg": either("INSTRUMENT_AZIMUTH", -360.0, 720.0),
        "elevation_deg": either("INSTRUMENT_ELEVATION", -90.0, 90.0),
        "hfov_deg": get(state, "HORIZONTAL_FOV", 1e-9, 180.0),
        "vfov_deg": get(state, "VERTICAL_FOV", 1e-9, 180.0),
    }


def _start_time(f: Fields, label: Mapping[str, Any]) -> datetime | None:
    """START_TIME, else IMAGE_TIME, as a UTC datetime (None if absent)."""
    for key in ("START_TIME", "IMAGE_TIME"):
        value = label.get(key)
        if not is_null(value):
            return f.time(value, key)
    return None


def _lmst(f: Fields, label: Mapping[str, Any]) -> str | None:
    """LOCAL_MEAN_SOLAR_TIME (Curiosity writes MSL:LOCAL_MEAN_SOLAR_TIME, "Sol-NNNNNM" before
    the time) as "HH:MM:SS[.fff]", its sol checked against PLANET_DAY_NUMBER (None if
    absent)."""
    for key in ("LOCAL_MEAN_SOLAR_TIME", "MSL:LOCAL_MEAN_SOLAR_TIME"):
        value = label.get(key)
        if not is_null(value):
            sol = f.integer(_require(f, label, "PLANET_DAY_NUMBER"), "PLANET_DAY_NUMBER")
            return f.local_time(value, key, sol)
    return None


def _image_path(path: Path, label: Mapping[str, Any]) -> Path | None:
    """The image: the label file itself when ^IMAGE points inside it (a record number or a
    byte offset: an attached label), else the named file beside the label, else a browse
    image with the label's stem."""
    value = label.get("^IMAGE")
    if isinstance(value, list | tuple) and len(value) == 1:
        value = value[0]
    if isinstance(value, bool):
        return image_beside(path, None)
    if isinstance(value, int) or (isinstance(value, Mapping) and set(value) == {"value", "units"}):
        return path
    if isinstance(value, list | tuple) and value:
        value = value[0]
    return image_beside(path, value if isinstance(value, str) else None)
