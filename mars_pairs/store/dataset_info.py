"""``dataset.json``: what a reader of a built dataset needs beyond the manifest (the ray
stride of the correspondence grids, the CRS, the chip size). Every reader requires it: there
is no default stride to fall back on.

Every reader of a dataset folder's ``dataset.json`` goes through this module and its typed
:class:`DatasetInfo`: :func:`read_dataset_info` (strict: the torch datasets, ``verify``;
``required=False``: the report, the overview, the query, the summary) and :func:`dataset_crs`
(the QGIS export); the build writes it with :func:`dataset_document`, which puts the
:data:`FORMAT_VERSION` first. A dataset root may be a local folder or an fsspec URL
(``store.fs``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs

#: the file's name in a dataset folder
DATASET_JSON = "dataset.json"

#: where dataset.json keeps the ray stride (ground-image pixels between keypoint rays)
RAY_STRIDE = ("config", "geometry", "ray_stride")

#: the version of the dataset folder's format this mars-pairs writes and reads (every older
#: one too); a dataset.json without ``format_version`` (written before it was recorded) is
#: version 1. Version 2: the DEM chip is ``dem.tif``, uint16 quantized (``store.dem_codec``;
#: dataset.json's ``dem_encoding``), where version 1 holds a float32 ``dem.npy``. Version 3:
#: every dense member is a one-strip zstd TIFF ``<field>.tif`` (``store.dense_codec``), where
#: version 2 holds ``.npy`` arrays and PNG images
FORMAT_VERSION = 3


def _mapping(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


@dataclass(frozen=True)
class DatasetInfo:
    """dataset.json, typed: what readers of a built dataset may rely on.

    ``path``: the file; ``exists``: False for a folder without one (the lenient reader);
    ``format_version`` (1 when the file predates it); ``crs`` (WKT or PROJJSON text; None
    when absent) and ``crs_name``; ``chip_px`` (chip side in pixels; None when absent) and
    ``chip`` (``size_m``, ``size_px``, ``orientation``); ``ray_stride`` (ground-image pixels
    between rays, >= 1; 0 only from the lenient reader when unrecorded) and ``dense_stride``
    (the dense members' stride, ``config.output.dense_stride``, default the ray stride);
    ``config`` (the build configuration, paths relative to the folder), ``counts``
    (``samples``, ``failures``, ``by_split``, ``by_mission``), ``splits`` (the split report:
    guard, buffer, warnings, ...), ``failures_by_reason``, ``versions``, ``license``,
    ``build_seconds``; ``doc``: the whole document (with the keys the build adds beside:
    ``appends``, ``build_stamp``, ``input_files``, ...)."""

    path: Path | str
    crs: str | None
    chip_px: int | None
    ray_stride: int
    doc: dict[str, Any]
    format_version: int = FORMAT_VERSION
    exists: bool = True
    dense_stride: int = 0
    crs_name: str | None = None
    chip: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    splits: dict[str, Any] = field(default_factory=dict)
    failures_by_reason: dict[str, Any] = field(default_factory=dict)
    versions: dict[str, Any] = field(default_factory=dict)
    license: str | None = None
    build_seconds: float | None = None

    @property
    def split_config(self) -> dict[str, Any]:
        """The build's ``splits`` configuration (``config.splits``; {} when unrecorded)."""
        return _mapping(self.config.get("splits"))

    @property
    def split_warnings(self) -> list[str]:
        """The split warnings the build recorded (``splits.warnings``: a configured split left
        empty); [] for a dataset built before they were recorded."""
        found = self.splits.get("warnings")
        return [str(w) for w in found] if isinstance(found, list) else []

    def configured_splits(self) -> set[str] | None:
        """The split names the build configures: ``train`` and ``buffer`` always, the
        ``splits.ratios`` names of a same-area rule, the ``splits.areas`` names of a
        cross-area one, and those ``counts.by_split`` holds; None (unknown) when the file
        records neither its split config nor its counts."""
        from mars_pairs.store.splits import BUFFER, TRAIN

        names = {TRAIN, BUFFER}
        recorded = isinstance(self.config.get("splits"), dict)
        for part in ("ratios", "areas"):
            names.update(str(n) for n in _mapping(self.split_config.get(part)))
        by_split = self.counts.get("by_split")
        if isinstance(by_split, dict):
            recorded = True
            names.update(str(n) for n in by_split)
        return names if recorded else None

    def build_input(self, root: str | Path, name: str) -> Path | None:
        """The path of the build's input ``name`` (``config.inputs.<name>``, e.g. ``ortho``),
        relative to the dataset folder ``root`` (an absolute path stays as it is); None
        when the file does not record it."""
        value = _mapping(self.config.get("inputs")).get(name)
        return Path(root) / value if value else None

    @classmethod
    def from_doc(
        cls, doc: dict[str, Any], path: Path | str, *, required: bool = True
    ) -> DatasetInfo:
        """The typed view of a dataset.json document ``doc`` (the file ``path``, named in
        errors). DatasetError naming the field when ``format_version`` is not a positive
        integer or newer than :data:`FORMAT_VERSION`, the CRS is not text, ``chip.size_px``
        not a positive integer, or (``required``) the ray stride is missing or invalid."""
        version = doc.get("format_version", 1)
        if _positive_int(version) is None:
            reason = f"expected a positive integer, got {version!r}"
            raise DatasetError(path, "format_version", reason)
        if version > FORMAT_VERSION:
            raise DatasetError(
                path,
                "format_version",
                f"{version} is newer than this mars-pairs reads ({FORMAT_VERSION}): upgrade "
                "mars-pairs",
            )
        value: Any = doc
        for part in RAY_STRIDE:
            value = value.get(part) if isinstance(value, dict) else None
        stride = _positive_int(value)
        if stride is None and required:
            reason = f"expected a positive integer, got {value!r}"
            raise DatasetError(path, ".".join(RAY_STRIDE), reason)
        chip = _mapping(doc.get("chip"))
        size_px = chip.get("size_px")
        if size_px is not None and _positive_int(size_px) is None:
            reason = f"expected a positive integer, got {size_px!r}"
            raise DatasetError(path, "chip.size_px", reason)
        crs = doc.get("crs")
        if crs is not None and not isinstance(crs, str):
            raise DatasetError(path, "crs", f"expected a string, got {type(crs).__name__}")
        config = _mapping(doc.get("config"))
        dense = _positive_int(_mapping(config.get("output")).get("dense_stride"))
        seconds = doc.get("build_seconds")
        name, license_ = doc.get("crs_name"), doc.get("license")
        return cls(
            path=path,
            crs=crs or None,
            chip_px=size_px,
            ray_stride=stride or 0,
            doc=doc,
            format_version=version,
            dense_stride=dense or stride or 0,
            crs_name=name if isinstance(name, str) else None,
            chip=chip,
            config=config,
            counts=_mapping(doc.get("counts")),
            splits=_mapping(doc.get("splits")),
            failures_by_reason=_mapping(doc.get("failures_by_reason")),
            versions=_mapping(doc.get("versions")),
            license=license_ if isinstance(license_, str) else None,
            build_seconds=float(seconds) if isinstance(seconds, (int, float)) else None,
        )


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


def read_dataset_info(root: str | Path, *, required: bool = True) -> DatasetInfo:
    """The dataset.json of the dataset folder ``root``, typed (:class:`DatasetInfo`).

    ``required`` (the torch datasets, ``verify``): DatasetError naming the file (and the
    field) when it is missing, unreadable, not a JSON object or lacks a valid ray stride.
    ``required=False`` (the pictures, the report, the query, the summary): a folder
    without one gives an empty DatasetInfo (``exists`` False) and an unrecorded stride 0;
    a damaged file is still a DatasetError naming it."""
    if required:
        path, doc = _load_required(root)
        return DatasetInfo.from_doc(doc, path)
    path = _location(root)
    if not fs.exists(path):
        return DatasetInfo(path, None, None, 0, {}, exists=False)
    return DatasetInfo.from_doc(_load(path), path, required=False)


def read_dataset_doc(root: str | Path) -> dict[str, Any]:
    """The whole dataset.json document of ``root`` ({} when absent); readers use the typed
    ``read_dataset_info(root, required=False)``."""
    return read_dataset_info(root, required=False).doc


def build_input(root: str | Path, doc: dict[str, Any], name: str) -> Path | None:
    """``DatasetInfo.build_input`` of a dataset.json document ``doc``."""
    info = DatasetInfo.from_doc(doc, dataset_json_path(root), required=False)
    return info.build_input(root, name)


def dataset_document(doc: dict[str, Any], path: Path | str) -> dict[str, Any]:
    """The dataset.json document a build writes: ``format_version`` (:data:`FORMAT_VERSION`)
    first, then ``doc``'s keys; checked by reading it back (:meth:`DatasetInfo.from_doc`),
    so a build never writes what its readers refuse."""
    rest = {k: v for k, v in doc.items() if k != "format_version"}
    out = {"format_version": FORMAT_VERSION, **rest}
    DatasetInfo.from_doc(out, path)
    return out
