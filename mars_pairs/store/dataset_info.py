"""``dataset.json``: what a reader of a built dataset needs beyond the manifest (the ray
stride of the correspondence grids, the CRS, the chip size). Every reader requires it: there
is no default stride to fall back on.

Every reader of a dataset folder's ``dataset.json`` goes through this module:
:func:`read_dataset_info` (the torch datasets, ``verify``), :func:`read_dataset_doc` (the whole
document: the report, the overview, the query, the summary) and :func:`dataset_crs` (the QGIS
export). A dataset root may be a local folder or an fsspec URL (``store.fs``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs

#: the file's name in a dataset folder
DATASET_JSON = "dataset.json"

#: where dataset.json keeps the ray stride (ground-image pixels between keypoint rays)
RAY_STRIDE = ("config", "geometry", "ray_stride")


@dataclass(frozen=True)
class DatasetInfo:
    """The reader's part of dataset.json: ``crs`` (WKT or PROJJSON text; None when absent),
    ``chip_px`` (chip side in pixels; None when absent), ``ray_stride`` (ground-image pixels
    between rays, >= 1) and the whole document."""

    path: Path | str
    crs: str | None
    chip_px: int | None
    ray_stride: int
    doc: dict[str, Any]


def _positive_int(value: Any) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        return None
    return value


def _load(path: fs.Location) -> dict[str, Any]:
    """The JSON object in ``path``; DatasetError naming it when unreadable or not an object."""
    try:
        doc = json.loads(fs.read_bytes(path))
    except (OSError, ValueError) as exc:
        raise DatasetError(path, None, f"unreadable: {exc}") from None
    if not isinstance(doc, dict):
        raise DatasetError(path, None, f"expected a JSON object, got {type(doc).__name__}")
    return doc


def dataset_json_path(root: str | Path) -> Path:
    """The dataset.json of the dataset folder ``root``."""
    return Path(root) / DATASET_JSON


def _location(root: str | Path) -> fs.Location:
    """The dataset.json of the dataset root ``root``: a local folder or a URL (``store.fs``)."""
    return fs.join(fs.dataset_root(root), DATASET_JSON)


def _load_required(root: str | Path) -> tuple[fs.Location, dict[str, Any]]:
    """(path, document) of the dataset.json of ``root``; DatasetError naming it when it is
    missing, unreadable or not a JSON object."""
    path = _location(root)
    if not fs.exists(path):
        reason = "missing (it holds the ray stride, CRS and chip size: rebuild or restore it)"
        raise DatasetError(path, None, reason)
    return path, _load(path)


def dataset_crs(root: str | Path) -> str:
    """The dataset CRS text (WKT or PROJJSON) of dataset.json's ``crs``; DatasetError naming
    the file and the field when the file or the field is missing or damaged."""
    path, doc = _load_required(root)
    crs = doc.get("crs")
    if not isinstance(crs, str) or not crs:
        got = repr(crs) if crs is None or crs == "" else type(crs).__name__
        raise DatasetError(path, "crs", f"expected CRS text, got {got}")
    return crs


def read_dataset_info(root: str | Path) -> DatasetInfo:
    """The dataset.json of the dataset folder ``root``; DatasetError naming the file (and the
    field) when it is missing, unreadable, not a JSON object or lacks a valid ray stride."""
    path, doc = _load_required(root)
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


def read_dataset_doc(root: str | Path) -> dict[str, Any]:
    """The whole dataset.json document of the dataset folder ``root``, for readers that work
    without it (the pictures, the report): {} when the file is absent; DatasetError naming the
    file when it is unreadable or not a JSON object."""
    path = _location(root)
    return _load(path) if fs.exists(path) else {}


def build_input(root: str | Path, doc: dict[str, Any], name: str) -> Path | None:
    """The path of the build's input ``name`` (``config.inputs.<name>`` of the dataset.json
    document ``doc``, e.g. ``ortho``), relative to the dataset folder ``root`` (an absolute
    path stays as it is); None when the document does not record it."""
    config = doc.get("config")
    inputs = config.get("inputs") if isinstance(config, dict) else None
    value = inputs.get(name) if isinstance(inputs, dict) else None
    return Path(root) / value if value else None
