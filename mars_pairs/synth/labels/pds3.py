"""Synthetic Curiosity Mastcam PDS3 labels (``MSL:`` keywords, request window, IMAGE object)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from mars_pairs.pds.observation import Observation
from mars_pairs.synth.labels.format import iso_time, pointer_name, real_text

_SYMBOL_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def _pds3_text(value: str) -> str:
    """A PDS3 value: a bare symbol if it is one, else a quoted string."""
    if _SYMBOL_RE.fullmatch(value):
        return value
    if '"' in value or "\n" in value:
        raise ValueError(f"cannot write {value!r} as a PDS3 string")
    return f'"{value}"'


def _pds3_vector(values: Iterable[float]) -> str:
    """A parenthesised PDS3 list, wrapped like the real Mastcam labels."""
    items = [real_text(v) for v in values]
    return "( " + ",\n".join(", ".join(items[i : i + 2]) for i in range(0, len(items), 2)) + " )"


def write_pds3_label(obs: Observation, path: str | os.PathLike[str]) -> Path:
    """Write ``obs`` as a Curiosity Mastcam-style PDS3 label at ``path``; returns the path."""
    path = Path(path)
    lines = [
        "PDS_VERSION_ID                    = PDS3",
        "",
        "/* FILE DATA ELEMENTS */",
        "",
        "RECORD_TYPE                         = FIXED_LENGTH",
        f"RECORD_BYTES                        = {obs.width}",
        "",
        "/* Pointers to Data Objects */",
        "",
        f'^IMAGE = ("{pointer_name(obs, path, ".IMG")}")',
        "",
        *_pds3_identification(obs),
        *_pds3_camera(obs),
        *_pds3_rover(obs),
        *_pds3_request(obs),
        *_pds3_state_and_derived(obs),
        *_pds3_image(obs),
        "END",
        "",
    ]
    path.write_text("\n".join(lines), encoding="ascii", newline="\r\n")
    return path


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


def _pds3_camera(obs: Observation) -> list[str]:
    """The GEOMETRIC_CAMERA_MODEL_PARMS group."""
    cam = obs.camera
    vectors = [cam.c, cam.a, cam.h, cam.v]
    if cam.model_type == "CAHVOR":
        vectors += [cam.o, cam.r]
    letters = "CAHVOR"[: len(vectors)]
    out = [
        "/* Camera Model Data Elements */",
        "",
        "GROUP                              = GEOMETRIC_CAMERA_MODEL_PARMS",
        f'  MODEL_TYPE                          = "{cam.model_type}"',
        "  MODEL_COMPONENT_ID                  = (" + ", ".join(f'"{c}"' for c in letters) + ")",
    ]
    for i, vec in enumerate(vectors, start=1):
        out.append(f"  MODEL_COMPONENT_{i}                   = {_pds3_vector(vec)}")
    out += [
        f"  REFERENCE_COORD_SYSTEM_NAME         = {_pds3_text(cam.frame)}",
        "END_GROUP                          = GEOMETRIC_CAMERA_MODEL_PARMS",
        "",
    ]
    return out


def _pds3_rover(obs: Observation) -> list[str]:
    """ROVER_COORDINATE_SYSTEM_PARMS (only when the Observation has a rover pose)."""
    if obs.rover_offset_m is None or obs.rover_quaternion is None:
        return []
    return [
        "/* Coordinate System State: Rover */",
        "",
        "GROUP                              = ROVER_COORDINATE_SYSTEM_PARMS",
        "  MSL:SOLUTION_ID                     = telemetry",
        "  COORDINATE_SYSTEM_NAME              = ROVER_NAV_FRAME",
        f"  ORIGIN_OFFSET_VECTOR                = {_pds3_vector(obs.rover_offset_m)}",
        f"  ORIGIN_ROTATION_QUATERNION          = {_pds3_vector(obs.rover_quaternion)}",
        "  POSITIVE_AZIMUTH_DIRECTION          = CLOCKWISE",
        "  REFERENCE_COORD_SYSTEM_NAME         = SITE_FRAME",
        "END_GROUP                          = ROVER_COORDINATE_SYSTEM_PARMS",
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


def _pds3_state_and_derived(obs: Observation) -> list[str]:
    """INSTRUMENT_STATE_PARMS (FOV) and DERIVED_IMAGE_PARMS (site-frame pointing)."""
    state = [("HORIZONTAL_FOV", obs.hfov_deg), ("VERTICAL_FOV", obs.vfov_deg)]
    derived = [
        ("MSL:COVER_STATE_FLAG", '"N/A"'),
        ("FIXED_INSTRUMENT_AZIMUTH", obs.azimuth_deg),
        ("FIXED_INSTRUMENT_ELEVATION", obs.elevation_deg),
    ]
    out: list[str] = []
    for group, items in (("INSTRUMENT_STATE_PARMS", state), ("DERIVED_IMAGE_PARMS", derived)):
        out.append(f"GROUP                              = {group}")
        for key, value in items:
            if value is not None:
                text = value if isinstance(value, str) else real_text(value)
                out.append(f"  {key:<34}= {text}")
        out += [f"END_GROUP                          = {group}", ""]
    return out


def _pds3_image(obs: Observation) -> list[str]:
    """The IMAGE object: the product's own pixel grid."""
    return [
        "/* PRIMARY DATA OBJECT */",
        "",
        "OBJECT                            = IMAGE",
        "  INTERCHANGE_FORMAT              = BINARY",
        f"  LINES                           = {obs.height}",
        f"  LINE_SAMPLES                    = {obs.width}",
        "  SAMPLE_TYPE                     = UNSIGNED_INTEGER",
        "  SAMPLE_BITS                     = 8",
        "  BANDS                           = 3",
        "END_OBJECT                        = IMAGE",
        "",
    ]
