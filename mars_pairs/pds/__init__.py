"""PDS label readers: Curiosity PDS3 (detached or attached) and Perseverance PDS4 -> Observation.

``read_observation`` chooses the format by content (XML vs PDS3 ``keyword = value``), not by
file extension. Every failure, of any kind, is a ``LabelError`` naming the file and field.
"""

from __future__ import annotations

import re
from pathlib import Path

from mars_pairs.errors import LabelError
from mars_pairs.observation import Observation
from mars_pairs.pds.common import PathLike, read_bytes
from mars_pairs.pds.pds3 import parse_pds3, read_pds3
from mars_pairs.pds.pds4 import parse_pds4, read_pds4

__all__ = ["LabelError", "read_observation", "read_pds3", "read_pds4", "sniff_format"]

_BOM = b"\xef\xbb\xbf"
_PDS3_START = re.compile(rb"[A-Za-z^][A-Za-z0-9_:^]*[ \t]*=")


def sniff_format(data: bytes) -> str | None:
    """'pds4' for XML, 'pds3' for PDS_VERSION_ID / ``KEYWORD = value`` text, else None."""
    head = data[:4096].removeprefix(_BOM).lstrip()
    while head.startswith(b"/*"):  # PDS3 labels may open with comments
        end = head.find(b"*/")
        if end < 0:
            return None
        head = head[end + 2 :].lstrip()
    if head.startswith(b"<"):
        return "pds4"
    if head.startswith(b"PDS_VERSION_ID") or _PDS3_START.match(head):
        return "pds3"
    return None


def read_observation(path: PathLike) -> Observation:
    """Read a PDS3 or PDS4 mast-camera label into an Observation.

    Raises LabelError, and only LabelError, for a missing, unreadable or malformed file.
    """
    try:
        label_path = Path(path)
    except TypeError as exc:
        raise LabelError(path, None, "not a file path") from exc
    data, longer = read_bytes(label_path)
    if not data.strip():
        raise LabelError(label_path, None, "empty file")
    kind = sniff_format(data)
    if kind is None:
        raise LabelError(label_path, None, "not a PDS label (neither XML nor PDS3 keyword = value)")
    if kind == "pds4" and longer:
        raise LabelError(label_path, None, f"larger than {len(data)} bytes: not a label")
    try:
        obs = (
            parse_pds4(data, label_path) if kind == "pds4" else parse_pds3(data, label_path, longer)
        )
        _check_fov(obs)
        return obs
    except LabelError:
        raise
    except Exception as exc:  # safety net of the contract; the readers should not get here
        reason = f"unexpected {type(exc).__name__} while reading the label: {exc}"
        raise LabelError(label_path, None, reason) from exc


def _check_fov(obs: Observation) -> None:
    """LabelError when the camera model's field of view disagrees with the label's
    (``common.fov_problem``); labels without a field of view are not checked."""
    import warnings

    from mars_pairs.pds.common import fov_problem

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a NaN edge ray: reported below
        hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
    for field, model, label in (
        ("HORIZONTAL_FOV", hfov, obs.hfov_deg),
        ("VERTICAL_FOV", vfov, obs.vfov_deg),
    ):
        problem = fov_problem(model, label)
        if problem is not None:
            raise LabelError(obs.label_path, field, problem)
