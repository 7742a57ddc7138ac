"""What identifies a build's inputs: the label list's streaming digest (``LabelDigest``) and
each input file's fingerprint (``file_fingerprint``: content hash, size and mtime, a VRT's
source tiles, an S3 object's ETag), and what changed between two fingerprints, in words.
"""

from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store import fs


class LabelDigest:
    """The sha256 of the label names joined by newlines, and their count, fed one name at a
    time: the digest of ``"\n".join(names).encode()`` without holding the names."""

    def __init__(self) -> None:
        self._sha = hashlib.sha256()
        self.count = 0

    def add(self, name: str) -> None:
        if self.count:
            self._sha.update(b"\n")
        self._sha.update(name.encode())
        self.count += 1

    def tally(self, names: Iterable[str]) -> Iterator[str]:
        """``names`` unchanged, each added to the digest as it passes."""
        for name in names:
            self.add(name)
            yield name

    def hexdigest(self) -> str:
        return self._sha.hexdigest()


#: Files up to this size are fingerprinted by content (sha256), larger ones by size and mtime.
HASHED_BYTES = 4 << 20


#: The inputs besides the labels whose files a resumed build must find unchanged.
INPUT_KEYS = ("places", "dem", "ortho")


#: The most bytes of a VRT read for its source list.
VRT_BYTES = 64 << 20


def file_fingerprint(path: Path | str, *, depth: int = 0) -> dict[str, Any]:
    """What identifies the input file ``path``: its path, and its size and sha256 (a file
    of up to ``HASHED_BYTES``) or its size and ``st_mtime_ns`` (a larger one); a VRT also
    lists its source files' (``SourceFilename``, relative to the VRT when it says so; a VRT
    of VRTs to 4 levels). An object on S3 (``/vsis3/``): its path, size and ETag. Another URL
    or GDAL ``/vsi`` path: the string only; an absent or unreadable file: ``missing`` (the
    error's words)."""
    text = str(path)
    if text.startswith("/vsis3/"):
        return _object_fingerprint(text)
    if text.startswith("/vsi") or "://" in text:
        return {"path": text}
    is_vrt = text.lower().endswith(".vrt")
    try:
        st = os.stat(text)
        doc: dict[str, Any] = {"path": text, "size": st.st_size}
        data = b""
        if st.st_size <= HASHED_BYTES or is_vrt:
            with open(text, "rb") as fh:
                data = fh.read(max(HASHED_BYTES, VRT_BYTES if is_vrt else 0) + 1)
        if st.st_size <= HASHED_BYTES:
            doc["sha256"] = hashlib.sha256(data).hexdigest()
        else:
            doc["mtime_ns"] = st.st_mtime_ns
    except OSError as exc:
        return {"path": text, "missing": exc.strerror or type(exc).__name__}
    if is_vrt and data and depth < 4:
        sources = vrt_sources(Path(text), data)
        doc["sources"] = [file_fingerprint(src, depth=depth + 1) for src in sources]
    return doc


def _object_fingerprint(text: str) -> dict[str, Any]:
    """``file_fingerprint`` of the S3 object behind the GDAL path ``/vsis3/BUCKET/KEY``: its
    size and ETag (one HEAD request, with the environment's credentials: ``store.fs``)."""
    url = "s3://" + text.removeprefix("/vsis3/")
    try:
        filesystem, key = fs.filesystem(url)
        info = filesystem.info(key)
    except (OSError, ConfigError) as exc:
        return {"path": text, "missing": str(exc) or type(exc).__name__}
    return {"path": text, "size": info.get("size"), "etag": info.get("ETag")}


def vrt_sources(vrt: Path, data: bytes) -> list[str]:
    """The distinct ``SourceFilename`` paths of the VRT ``vrt`` (its bytes ``data``), in
    order: relative ones (``relativeToVRT="1"``) joined to the VRT's folder; [] when the
    bytes are not VRT XML (what opens the raster says why)."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError:
        return []
    seen: dict[str, None] = {}
    for el in root.iter("SourceFilename"):
        name = (el.text or "").strip()
        if not name:
            continue
        relative = el.get("relativeToVRT", "0") == "1"
        if relative and not (name.startswith("/vsi") or "://" in name):
            name = str(vrt.parent / name)
        seen.setdefault(name, None)
    return list(seen)


def inputs_fingerprint(config: BuildConfig) -> dict[str, Any]:
    """``file_fingerprint`` of each input besides the labels (``INPUT_KEYS``)."""
    return {key: file_fingerprint(getattr(config.inputs, key)) for key in INPUT_KEYS}


def without_paths(doc: Any) -> Any:
    """A file fingerprint (``file_fingerprint``) without its ``path`` keys, at every level: what
    identifies the file's content wherever it lies (dataset.json holds no input path)."""
    if isinstance(doc, dict):
        return {k: without_paths(v) for k, v in doc.items() if k != "path"}
    if isinstance(doc, list):
        return [without_paths(v) for v in doc]
    return doc


def input_files(config: BuildConfig) -> dict[str, Any]:
    """``inputs_fingerprint`` without paths (``without_paths``): dataset.json's
    ``input_files``, which ``--append`` checks the DEM and ortho against."""
    files: dict[str, Any] = without_paths(inputs_fingerprint(config))
    return files


def input_change(before: Any, after: Any) -> str:
    """What differs between two file fingerprints, in words (size, content, mtime, VRT
    sources; "not recorded" when one is not a fingerprint)."""
    return _change(before, after)


def _change(before: Any, after: Any) -> str:
    """What differs between two file fingerprints, in words."""
    if not (isinstance(before, dict) and isinstance(after, dict)):
        return "not recorded"
    if before.get("path") != after.get("path"):
        return f"path {before.get('path')} -> {after.get('path')}"
    if "missing" in after:
        return f"now missing ({after['missing']})"
    if "missing" in before:
        return "absent then, present now"
    parts = []
    if before.get("size") != after.get("size"):
        parts.append(f"size {before.get('size')} -> {after.get('size')} bytes")
    if before.get("sha256") != after.get("sha256"):
        old, new = (str(d.get("sha256", "none"))[:12] for d in (before, after))
        parts.append(f"content (sha256 {old}... -> {new}...)")
    if before.get("etag") != after.get("etag"):
        parts.append(f"ETag {before.get('etag')} -> {after.get('etag')}")
    if before.get("mtime_ns") != after.get("mtime_ns"):
        parts.append(f"mtime_ns {before.get('mtime_ns')} -> {after.get('mtime_ns')}")
    old_src, new_src = before.get("sources", []), after.get("sources", [])
    if [s.get("path") for s in old_src] != [s.get("path") for s in new_src]:
        parts.append(f"its source files ({len(old_src)} then, {len(new_src)} now)")
    else:
        for a, b in zip(old_src, new_src, strict=True):
            if a != b:
                parts.append(f"source {b.get('path')}: {_change(a, b)}")
                break
    return "; ".join(parts) or "changed"
