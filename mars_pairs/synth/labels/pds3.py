"""Synthetic Curiosity PDS3 labels: Mastcam RDR style (detached ``.LBL``) and MIPL style
(Navcam / Hazcam / MAHLI EDRs and RDRs: ``GEOMETRIC_CAMERA_MODEL``, ``ROVER_COORDINATE_SYSTEM``,
``SITE_DERIVED_GEOMETRY_PARMS``), detached or attached at the start of an ``.IMG``."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from mars_pairs.errors import ArgumentError
from mars_pairs.observation import Observation
from mars_pairs.synth.labels.format import iso_time, pointer_name, real_text

_SYMBOL_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
STYLES = ("mastcam", "mipl")
#: Group names of each style: camera model, rover pose, site-frame derived pointing.
_GROUPS = {
    "mastcam": ("GEOMETRIC_CAMERA_MODEL_PARMS", "ROVER_COORDINATE_SYSTEM_PARMS"),
    "mipl": ("GEOMETRIC_CAMERA_MODEL", "ROVER_COORDINATE_SYSTEM"),
}


def _pds3_text(value: str) -> str:
    """A PDS3 value: a bare symbol if it is one, else a quoted string."""
    if _SYMBOL_RE.fullmatch(value):
        return value
    if '"' in value or "\n" in value:
        raise ArgumentError(f"cannot write {value!r} as a PDS3 string")
    return f'"{value}"'


def _pds3_vector(values: Iterable[float]) -> str:
    """A parenthesised PDS3 list, wrapped like the real Mastcam labels."""
    items = [real_text(v) for v in values]
    return "( " + ",\n".join(", ".join(items[i : i + 2]) for i in range(0, len(items), 2)) + " )"


def write_pds3_label(
    obs: Observation, path: str | os.PathLike[str], style: str = "mastcam"
) -> Path:
    """Write ``obs`` as a detached PDS3 label at ``path`` ("mastcam" or "mipl" style)."""
    path = Path(path)
    pointer = f'("{pointer_name(obs, path, ".IMG")}")'
    text = _label_text(obs, style, f"RECORD_BYTES                        = {obs.width}", pointer,
                       _image_object(obs, 8, 3))  # fmt: skip
    path.write_text(text, encoding="ascii", newline="\r\n")
    return path


def write_pds3_img(
    obs: Observation, path: str | os.PathLike[str], pixels: np.ndarray, style: str = "mipl"
) -> Path:
    """Write an ``.IMG`` with its PDS3 label attached: the label, padded to whole records, then
    ``pixels`` (uint8 or uint16, (H, W) or (H, W, 3); band sequential, MSB first)."""
    path = Path(path)
    pixels = np.asarray(pixels)
    if pixels.dtype not in (np.uint8, np.uint16) or pixels.ndim not in (2, 3):
        raise ArgumentError(
            f"pixels must be uint8/uint16 (H, W[, 3]), got {pixels.dtype} {pixels.shape}"
        )
    bands = 1 if pixels.ndim == 2 else pixels.shape[2]
    if pixels.shape[:2] != (obs.height, obs.width):
        raise ArgumentError(
            f"pixels are {pixels.shape[:2]}, the label says {(obs.height, obs.width)}"
        )
    bits = 8 * pixels.itemsize
    record = obs.width * pixels.itemsize
    data = np.moveaxis(pixels.reshape(obs.height, obs.width, bands), -1, 0)
    body = data.astype(">u2" if bits == 16 else "u1").tobytes()
    records = 1
    while True:
        head = "\r\n".join([
            f"RECORD_BYTES                        = {record}",
            f"FILE_RECORDS                        = {records + obs.height * bands}",
            f"LABEL_RECORDS                       = {records}",
        ])  # fmt: skip
        text = _label_text(obs, style, head, str(records + 1), _image_object(obs, bits, bands))
        encoded = text.replace("\n", "\r\n").encode("ascii")
        if len(encoded) <= records * record:
            break
        records = -(-len(encoded) // record)
    path.write_bytes(encoded.ljust(records * record, b" ") + body)
    return path


def _label_text(obs: Observation, style: str, records: str, pointer: str, image: list[str]) -> str:
    """The whole label text (LF line ends)."""
    if style not in STYLES:
        raise ArgumentError(f"unknown PDS3 label style {style!r} (one of {STYLES})")
    lines = [
        "PDS_VERSION_ID                    = PDS3",
        "",
        "/* FILE DATA ELEMENTS */",
        "",
        "RECORD_TYPE                         = FIXED_LENGTH",
        *records.split("\r\n"),
        "",
        "/* Pointers to Data Objects */",
        "",
        f"^IMAGE = {pointer}",
        "",
        *_pds3_identification(obs),
        *_pds3_camera(obs, _GROUPS[style][0]),
        *_pds3_rover(obs, _GROUPS[style][1]),
        *_pds3_request(obs),
        *_pds3_state_and_derived(obs, style),
        *image,
        "END",
        "",
    ]
    return "\n".join(lines)


def _pds3_identification(obs: Observation) -> list[str]:
    """Identification keywords, motion counter and times."""
    names = ["SITE", "DRIVE"] + ([] if obs.rmc.pose is None else ["POSE"])
    counter = [obs.rmc.site, obs.rmc.drive] + ([] if obs.rmc.pose is None else [obs.rmc.pose])
    out = [
        "/* Identification Data Elements */",
        "",
        'MSL:ACTIVE_FLIGHT_STRING_ID         = "B"',
        'DATA_SET_ID                         = "MSL-M-MASTCAM-4-RDR-IMG-V1.0"',
        "INSTRUMENT_HOST_ID                  = MSL",
        f"INSTRUMENT_ID                       = {_pds3_text(obs.instrument)}",
        f"PLANET_DAY_NUMBER                   = {obs.sol}",
        f'PRODUCT_ID                          = "{obs.product_id}"',
        "ROVER_MOTION_COUNTER_NAME           = (" + ", ".join(f'"{n}"' for n in names) + ")",
        "ROVER_MOTION_COUNTER                = (" + ", ".join(str(v) for v in counter) + ")",
    ]
    if obs.start_time is not None:
        out += [
            f"IMAGE_TIME                          = {iso_time(obs.start_time)}",
            f"START_TIME                          = {iso_time(obs.start_time)}",
        ]
    return [*out, ""]


def _pds3_camera(obs: Observation, group: str) -> list[str]:
    """The camera model group (CAHV, CAHVOR or CAHVORE: components 7..9 = E, type, P)."""
    cam = obs.camera
    vectors = [cam.c, cam.a, cam.h, cam.v]
    if cam.model_type in ("CAHVOR", "CAHVORE"):
        assert cam.o is not None and cam.r is not None
        vectors += [cam.o, cam.r]
    if cam.model_type == "CAHVORE":
        assert cam.e is not None
        vectors.append(cam.e)
    letters = "CAHVORE"[: len(vectors)]
    out = [
        "/* Camera Model Data Elements */",
        "",
        f"GROUP                              = {group}",
        f'  MODEL_TYPE                          = "{cam.model_type}"',
        "  MODEL_COMPONENT_ID                  = (" + ", ".join(f'"{c}"' for c in letters) + ")",
    ]
    for i, vec in enumerate(vectors, start=1):
        out.append(f"  MODEL_COMPONENT_{i}                   = {_pds3_vector(vec)}")
    if cam.model_type == "CAHVORE":
        assert cam.mtype is not None and cam.mparm is not None
        out += [
            f"  MODEL_COMPONENT_8                   = {real_text(cam.mtype)}",
            f"  MODEL_COMPONENT_9                   = {real_text(cam.mparm)}",
        ]
    out += [
        f"  REFERENCE_COORD_SYSTEM_NAME         = {_pds3_text(cam.frame)}",
        f"END_GROUP                          = {group}",
        "",
    ]
    return out


def _pds3_rover(obs: Observation, group: str) -> list[str]:
    """ROVER_COORDINATE_SYSTEM_PARMS (only when the Observation has a rover pose)."""
    if obs.rover_offset_m is None or obs.rover_quaternion is None:
        return []
    return [
        "/* Coordinate System State: Rover */",
        "",
        f"GROUP                              = {group}",
        "  MSL:SOLUTION_ID                     = telemetry",
        "  COORDINATE_SYSTEM_NAME              = ROVER_NAV_FRAME",
        f"  ORIGIN_OFFSET_VECTOR                = {_pds3_vector(obs.rover_offset_m)}",
        f"  ORIGIN_ROTATION_QUATERNION          = {_pds3_vector(obs.rover_quaternion)}",
        "  POSITIVE_AZIMUTH_DIRECTION          = CLOCKWISE",
        "  REFERENCE_COORD_SYSTEM_NAME         = SITE_FRAME",
        f"END_GROUP                          = {group}",
        "",
    ]


def _pds3_request(obs: Observation) -> list[str]:
    """IMAGE_REQUEST_PARMS: a synthetic request window larger than the product (as in MSL)."""
    return [
        "/* Image Request (synthetic request window) */",
        "",
        "GROUP                              = IMAGE_REQUEST_PARMS",
        "  FIRST_LINE                          = 1",
        f"  LINES                               = {obs.height + 4}",
        f"  LINE_SAMPLES                        = {obs.width + 5}",
        "END_GROUP                          = IMAGE_REQUEST_PARMS",
        "",
    ]


_Item = tuple[str, str | float | None] | tuple[str, str | float | None, str]


def _pds3_state_and_derived(obs: Observation, style: str) -> list[str]:
    """INSTRUMENT_STATE_PARMS (FOV) and the site-frame pointing: Mastcam's DERIVED_IMAGE_PARMS
    FIXED_INSTRUMENT_*, or MIPL's SITE_DERIVED_GEOMETRY_PARMS INSTRUMENT_* in <deg>."""
    # (keyword, value, optional units); a None value leaves the keyword out
    state: list[_Item] = [("HORIZONTAL_FOV", obs.hfov_deg), ("VERTICAL_FOV", obs.vfov_deg)]
    if style == "mastcam":
        derived_group = "DERIVED_IMAGE_PARMS"
        derived: list[_Item] = [
            ("MSL:COVER_STATE_FLAG", '"N/A"'),
            ("FIXED_INSTRUMENT_AZIMUTH", obs.azimuth_deg),
            ("FIXED_INSTRUMENT_ELEVATION", obs.elevation_deg),
        ]
    else:
        derived_group = "SITE_DERIVED_GEOMETRY_PARMS"
        derived = [
            ("INSTRUMENT_AZIMUTH", obs.azimuth_deg, "<deg>"),
            ("INSTRUMENT_ELEVATION", obs.elevation_deg, "<deg>"),
            ("POSITIVE_AZIMUTH_DIRECTION", "CLOCKWISE"),
            ("REFERENCE_COORD_SYSTEM_NAME", "SITE_FRAME"),
        ]
    out: list[str] = []
    for group, items in (("INSTRUMENT_STATE_PARMS", state), (derived_group, derived)):
        out.append(f"GROUP                              = {group}")
        for key, value, *units in items:
            if value is not None:
                text = value if isinstance(value, str) else real_text(value)
                out.append(f"  {key:<34}= {text}{' ' + units[0] if units else ''}")
        out += [f"END_GROUP                          = {group}", ""]
    return out


def _image_object(obs: Observation, bits: int, bands: int) -> list[str]:
    """The IMAGE object: the product's own pixel grid and sample format."""
    kind = "UNSIGNED_INTEGER" if bits == 8 else "MSB_UNSIGNED_INTEGER"
    return [
        "/* PRIMARY DATA OBJECT */",
        "",
        "OBJECT                            = IMAGE",
        "  INTERCHANGE_FORMAT              = BINARY",
        f"  LINES                           = {obs.height}",
        f"  LINE_SAMPLES                    = {obs.width}",
        f"  SAMPLE_TYPE                     = {kind}",
        f"  SAMPLE_BITS                     = {bits}",
        f"  BANDS                           = {bands}",
        "  BAND_STORAGE_TYPE               = BAND_SEQUENTIAL",
        "END_OBJECT                        = IMAGE",
        "",
    ]
