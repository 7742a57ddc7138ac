"""``dataset.json``: what a reader of a built dataset needs beyond the manifest (the ray
stride of the correspondence grids, the CRS, the chip size). Every reader requires it: there
is no default stride to fall back on.

Every reader of a dataset folder's ``dataset.json`` goes through this module:
:func:`read_dataset_info` (the torch datasets, ``verify``), :func:`read_dataset_doc` (the whole
document: the report, the query, the summary) and :func:`dataset_crs` (the QGIS export)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mars_pairs.errors import DatasetError

#: the file's name in a dataset folder
DATASET_JSON = "dataset.json"

#: where dataset.json keeps the ray stride (ground-image pixels between keypoint rays)
RAY_STRIDE = ("config", "geometry", "ray_stride")


@dataclass(frozen=True)
class DatasetInfo:
    """The reader's part of dataset.json: ``crs`` (WKT or PROJJSON text; None when absent),
    ``chip_px`` (chip side in pixels; None when absent), ``ray_stride`` (ground-image pixels
    between rays, >= 1) and the whole document."""

    path: Path
    crs: str | None
    chip_px: int | None
    ray_stride: int
    doc: dict[str, Any]


def _positive_int(value: Any) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        return None
    return value


def dataset_json_path(root: str | Path) -> Path:
    """The dataset.json of the dataset folder ``root``."""
    return Path(root) / DATASET_JSON


def read_dataset_doc(root: str | Path, *, missing_ok: bool = False) -> dict[str, Any]:
    """The whole dataset.json of the dataset folder ``root``; ``{}`` when it is absent and
    ``missing_ok``. DatasetError naming the file when it is missing (unless ``missing_ok``),
    unreadable or not a JSON object."""
    path = dataset_json_path(root)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        if missing_ok:
            return {}
        reason = "missing (it holds the ray stride, CRS and chip size: rebuild or restore it)"
        raise DatasetError(path, None, reason) from None
    except (OSError, ValueError) as exc:
        raise DatasetError(path, None, f"unreadable: {exc}") from None
    if not isinstance(doc, dict):
        raise DatasetError(path, None, f"expected a JSON object, got {type(doc).__name__}")
    return doc


def dataset_crs(root: str | Path) -> str:
    """The dataset CRS text (WKT or PROJJSON) of dataset.json's ``crs``; DatasetError naming
    the file and the field when the file or the field is missing or damaged."""
    crs = read_dataset_doc(root).get("crs")
    if not isinstance(crs, str) or not crs:
        got = repr(crs) if crs is None or crs == "" else type(crs).__name__
        raise DatasetError(dataset_json_path(root), "crs", f"expected CRS text, got {got}")
    return crs


def read_dataset_info(root: str | Path) -> DatasetInfo:
    """The dataset.json of the dataset folder ``root``; DatasetError naming the file (and the
    field) when it is missing, unreadable, not a JSON object or lacks a valid ray stride."""
    path = dataset_json_path(root)
    doc = read_dataset_doc(root)
    value: Any = doc
    for part in RAY_STRIDE:
        value = value.get(part) if isinstance(value, dict) else None
    stride = _positive_int(value)
    if stride is None:
        reason = f"expected a positive integer, got {value!r}"
        raise DatasetError(path, ".".join(RAY_STRIDE), reason)
    chip = doc.get("chip")
    size_px = chip.get("size_px") if isinstance(chip, dict) else None
    if size_px is not None and _positive_int(size_px) is None:
        raise DatasetError(path, "chip.size_px", f"expected a positive integer, got {size_px!r}")
    crs = doc.get("crs")
    if crs is not None and not isinstance(crs, str):
        raise DatasetError(path, "crs", f"expected a string, got {type(crs).__name__}")
    return DatasetInfo(path, crs or None, size_px, stride, doc)
