"""What a build keeps in its output folder: chunk part paths, the build stamp, clearing.

The stamp (``parts/build.json``) holds the fingerprint of the build that wrote the parts (its
config, its label list, and its other inputs: the PLACES table, the DEM and the ortho, with a
VRT's source tiles); a resumed build must match it. It also lists what that build writes: its
label count and ``output.shard_size`` give its chunks, and ``written_by`` names their files.
A build clears only those (and its own temporary files), and a resumed build keeps only
those: a folder holding anything else is refused, untouched (``foreign_file``). A shard or
failure part of an unfinished chunk must read as one a build writes (a tar of
``<key>.<field>`` members, a parquet file of the failure columns). Clearing is ordered so
that a kill at any point resumes.

A finished build removes ``parts/`` (``remove_parts``, unless ``output.keep_parts``): its stamp
lives on as ``build_stamp`` in dataset.json (``finished_stamp``: the label count, shard size and
the SHA-256 of the fingerprint, no paths), written before the parts go.

The output folder may be object storage (an fsspec URL: ``store.fs``): the same files under
the same names, listed with one listing; a rename there is a server-side copy and a delete
(``fs.replace``), and there are no folders (nor links) to find.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import re
import tarfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.store import fs
from mars_pairs.store.atomic import temporary_target
from mars_pairs.store.manifest import FAILURE_SCHEMA
from mars_pairs.store.wids_index import WIDS_INDEX

DROPPED_KEY = b"mars_pairs:dropped_in_buffer"
#: The stamp of a build whose files are being cleared (the old stamp, renamed).
CLEARING = "parts/clearing.json"
#: The files of a build besides its chunks', relative to the output folder.
BUILD_FILES = (
    "parts/build.json",
    CLEARING,
    "manifest.parquet",
    "failures.parquet",
    "dataset.json",
    WIDS_INDEX,
    "README.md",
    "croissant.json",
    # an append's snapshot of the dataset it appends to (``pipeline.build.append``)
    "parts/base-manifest.parquet",
    "parts/base-failures.parquet",
    "parts/base-dataset.json",
)
#: dataset.json's key holding the stamp of the finished build (``stamp_digest``).
FINISHED_KEY = "build_stamp"
_CHUNK_FILE = re.compile(
    r"(shards/shard-([0-9]{6,})\.tar|parts/(?:manifest|failures)-([0-9]{6,})\.parquet)"
)


def part_paths(out: fs.Location, k: int) -> tuple[str, Any, Any]:
    """Chunk k's shard (relative to ``out``), manifest part and failure part (in ``out``: a
    Path for a local folder, a URL for object storage)."""
    return (
        f"shards/shard-{k:06d}.tar",
        fs.join(out, f"parts/manifest-{k:06d}.parquet"),
        fs.join(out, f"parts/failures-{k:06d}.parquet"),
    )


def stamp_path(out: fs.Location) -> Any:
    """The build stamp: the fingerprint of the build that wrote the parts."""
    return fs.join(out, "parts/build.json")


def dropped_count(out: fs.Location, n_chunks: int) -> int:
    """Samples dropped in the split buffer, summed over the chunk parts."""
    total = 0
    for k in range(n_chunks):
        meta = fs.parquet_schema(part_paths(out, k)[1]).metadata or {}
        total += int(meta.get(DROPPED_KEY, b"0"))
    return total


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


def stamp_difference(previous: dict[str, Any], stamp: dict[str, Any]) -> str | None:
    """Why a build of fingerprint ``stamp`` cannot resume one of ``previous`` (one phrase:
    the config or label list, or the input and what changed); None when they match."""
    for key in ("config", "labels", "count"):
        if previous.get(key) != stamp.get(key):
            return "the config or the label list changed since the interrupted build"
    old, new = previous.get("inputs"), stamp.get("inputs", {})
    if not isinstance(old, dict):
        return "the interrupted build's stamp records no fingerprint of its inputs"
    for key in INPUT_KEYS:
        if old.get(key) != new.get(key):
            return (
                f"inputs.{key} changed since the interrupted build: {new[key].get('path')}: "
                f"{_change(old.get(key), new[key])}"
            )
    return None if previous == stamp else "the build stamp differs"


def fingerprint(config: BuildConfig, labels: Iterable[str | Path]) -> dict[str, Any]:
    """What a resumed build must share with the interrupted one: the config (without its
    source and output folder), the label list's digest and count (in one streaming pass),
    and the fingerprint of the other inputs (``inputs_fingerprint``)."""
    digest = LabelDigest()
    for label in labels:
        digest.add(str(label))
    return stamp_of(config, digest)


def stamp_of(config: BuildConfig, digest: LabelDigest) -> dict[str, Any]:
    """The fingerprint of ``config`` with the label list that ``digest`` summed."""
    doc = config.to_dict()
    doc.pop("source", None)
    doc["output"].pop("dir", None)
    return {
        "config": doc,
        "labels": digest.hexdigest(),
        "count": digest.count,
        "inputs": inputs_fingerprint(config),
    }


def read_stamp(stamp: fs.Location) -> dict[str, Any] | None:
    """The fingerprint of the build that wrote the parts; None when absent or damaged."""
    try:
        doc = json.loads(fs.read_bytes(stamp))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def stamp_digest(stamp: dict[str, Any]) -> dict[str, Any]:
    """What dataset.json keeps of a build's fingerprint: its label count, shard size and the
    SHA-256 of the fingerprint (canonical JSON), so that no input path is written there."""
    text = json.dumps(stamp, sort_keys=True, separators=(",", ":")).encode()
    return {
        "count": stamp["count"],
        "shard_size": stamp["config"]["output"]["shard_size"],
        "sha256": hashlib.sha256(text).hexdigest(),
    }


def finished_stamp(out: fs.Location) -> dict[str, Any] | None:
    """The ``stamp_digest`` of the finished build in ``out`` (dataset.json's ``build_stamp``);
    None when there is none."""
    doc = read_stamp(fs.join(out, "dataset.json"))
    digest = doc.get(FINISHED_KEY) if doc is not None else None
    return digest if isinstance(digest, dict) else None


def stamp_chunks(stamp: Any) -> int | None:
    """The chunk count of the build a stamp describes (its label count over its
    ``output.shard_size``, or its ``chunks`` when larger: an append's stamp and an appended
    dataset's ``build_stamp`` count the chunks before it too); None when ``stamp`` is not a
    build's fingerprint. A finished build's dataset.json (its ``build_stamp``) describes that
    build."""
    try:
        if isinstance(stamp, dict) and isinstance(stamp.get(FINISHED_KEY), dict):
            count, size = stamp[FINISHED_KEY]["count"], stamp[FINISHED_KEY]["shard_size"]
            chunks = stamp[FINISHED_KEY].get("chunks")
        else:
            count, size = stamp["count"], stamp["config"]["output"]["shard_size"]
            chunks = stamp.get("chunks")
    except (KeyError, TypeError, AttributeError):
        return None
    ints = all(isinstance(v, int) and not isinstance(v, bool) for v in (count, size))
    if not ints or count < 0 or size < 1:
        return None
    n: int = -(-count // size)
    if isinstance(chunks, int) and not isinstance(chunks, bool) and chunks > n:
        return chunks  # an appended dataset's (or an append's): chunks beyond its count's
    return n


def written_by(chunks: int | None, rel: str) -> bool:
    """Whether a build of ``chunks`` chunks (None: no build) writes the file ``rel`` (a path
    relative to the output folder, with ``/``)."""
    if chunks is None:
        return False
    if rel in BUILD_FILES:
        return True
    k = _chunk_of(rel)
    return k is not None and k < chunks


def _chunk_of(rel: str) -> int | None:
    """The chunk whose file ``rel`` is (a shard or a part, its number written as a build
    writes it: six digits or more, no extra leading zero), else None."""
    m = _CHUNK_FILE.fullmatch(rel)
    if m is None:
        return None
    digits = m[2] or m[3]
    return int(digits) if f"{int(digits):06d}" == digits else None


def is_temporary(rel: str) -> bool:
    """Whether ``rel`` is the temporary name (``store.atomic``: ``.NAME.tmp-PID`` beside NAME,
    left by a killed build) of a file some build writes, whatever its chunk count."""
    folder, _, name = rel.rpartition("/")
    target = temporary_target(name)
    if target is None:
        return False
    rel = f"{folder}/{target}" if folder else target
    return rel in BUILD_FILES or _chunk_of(rel) is not None


def stamped_chunks(out: fs.Location) -> int | None:
    """The chunks of the build(s) whose stamp the folder holds (the build's, and a clearing's
    left by a killed clearing); None when it holds no valid stamp."""
    stamps = ("parts/build.json", CLEARING, "dataset.json")
    counts = [stamp_chunks(read_stamp(fs.join(out, rel))) for rel in stamps]
    valid = [n for n in counts if n is not None]
    return max(valid) if valid else None


def appended_to(stamp: Any) -> int:
    """The chunks of the finished dataset an append's stamp appends to (its first chunk: a
    finished build vouched for them); 0 for any other stamp."""
    append = stamp.get("append") if isinstance(stamp, dict) else None
    first = append.get("first_chunk") if isinstance(append, dict) else None
    return first if isinstance(first, int) and not isinstance(first, bool) else 0


def foreign_file(out: fs.Location) -> str | None:
    """The first entry of ``out`` (sorted, relative, with ``/``) that the build that stamped
    it did not write: a file it does not list, a shard or failure part of an unfinished
    chunk that does not read as one (``_as_built``; a finished build's chunks are all
    finished, vouched for by its dataset.json, and so are those of the dataset an
    interrupted append appends to: ``appended_to``), a symbolic link, a folder other than
    ``shards`` and ``parts``; None when a build may clear or resume the folder. On object
    storage, every object under the prefix (one listing)."""
    if not isinstance(out, Path):
        return _foreign_object(out)
    if not out.is_dir():
        return None
    chunks = stamped_chunks(out)
    finished = finished_stamp(out) is not None and not stamp_path(out).exists()
    vouched = 2**62 if finished else appended_to(read_stamp(stamp_path(out)))
    for folder, dirs, files in os.walk(out):
        dirs.sort()
        rel_dir = os.path.relpath(folder, out).replace(os.sep, "/")
        prefix = "" if rel_dir == "." else rel_dir + "/"
        for name in sorted(files):
            rel = prefix + name
            path = os.path.join(folder, name)
            if os.path.islink(path) or not os.path.isfile(path):
                return rel
            if not (written_by(chunks, rel) or is_temporary(rel)):
                return rel
            if not _as_built(out, rel, vouched):
                return rel
        for name in dirs:
            if (
                prefix
                or name not in ("shards", "parts")
                or os.path.islink(os.path.join(folder, name))
            ):
                return prefix + name + "/"
    return None


def _foreign_object(out: str) -> str | None:
    """``foreign_file`` of the object storage prefix ``out``."""
    files = fs.list_files(out)
    if not files:
        return None
    chunks = stamped_chunks(out)
    finished = finished_stamp(out) is not None and "parts/build.json" not in files
    vouched = 2**62 if finished else appended_to(read_stamp(stamp_path(out)))
    for rel in files:
        if not (written_by(chunks, rel) or is_temporary(rel)):
            return rel
        if not _as_built(out, rel, vouched):
            return rel
    return None


_MEMBER = re.compile(r"[^./]+\.[^/]+")  # <key>.<field> (``ShardWriter``)


def _as_built(out: fs.Location, rel: str, vouched: int = 0) -> bool:
    """Whether the chunk file ``rel`` reads as one a build writes, when its chunk is not
    finished (no manifest part, and not one of the first ``vouched`` chunks, which a finished
    build vouches for: the dataset an append appends to): a shard is a tar of regular
    ``<key>.<field>`` members, a failure part a parquet file of the failure columns. Other
    files: True. Reads tar headers and the parquet footer only."""
    m = _CHUNK_FILE.fullmatch(rel)
    if m is None or rel.startswith("parts/manifest-"):
        return True
    k = int(m[2] or m[3])
    if k < vouched or fs.exists(part_paths(out, k)[1]):
        return True
    path = fs.join(out, rel)
    if m[2] is not None:
        try:
            with fs.open_input(path) as fh, tarfile.open(fileobj=fh, mode="r:") as tar:
                return all(t.isreg() and _MEMBER.fullmatch(t.name) for t in tar)
        except (OSError, tarfile.TarError):
            return False
    try:
        return bool(fs.parquet_schema(path).names == FAILURE_SCHEMA.names)
    except (OSError, ValueError):
        return False


def remove_temporaries(out: fs.Location) -> None:
    """Remove the temporary files a killed build left (``is_temporary`` names only, in the
    output folder, ``shards/`` and ``parts/``)."""
    if not isinstance(out, Path):
        for rel in fs.list_files(out):
            if is_temporary(rel):
                fs.remove(fs.join(out, rel))
        return
    for sub in ("", "shards/", "parts/"):
        folder = out / sub
        if not folder.is_dir():
            continue
        for name in sorted(os.listdir(folder)):
            path = folder / name
            if is_temporary(sub + name) and path.is_file() and not path.is_symlink():
                path.unlink()


def remove_parts(out: fs.Location, chunks: int) -> None:
    """Remove ``parts/`` of a finished build (its dataset.json holds the stamp): the chunk
    commit markers first, then the failure parts, the stamp, the folder. A kill at any point
    resumes: a chunk without its manifest part is rebuilt, byte for byte."""
    for k in range(chunks):
        fs.remove(part_paths(out, k)[1])
    for k in range(chunks):
        fs.remove(part_paths(out, k)[2])
    fs.remove(stamp_path(out))
    remove_empty_parts(out)


def remove_empty_parts(out: fs.Location) -> None:
    """Remove ``parts/`` when it is an empty folder (object storage has no folders)."""
    if not isinstance(out, Path):
        return
    parts = out / "parts"
    if parts.is_dir() and not parts.is_symlink() and not any(parts.iterdir()):
        parts.rmdir()


def built_keys(out: fs.Location, done: Iterable[int]) -> dict[str, str]:
    """Sample key -> label path of the chunks a resumed build keeps (for duplicate ids)."""
    seen: dict[str, str] = {}
    for k in done:
        part = fs.read_parquet(part_paths(out, k)[1], columns=["key", "label_path"])
        seen.update(zip(part["key"].to_pylist(), part["label_path"].to_pylist(), strict=True))
    return seen


#: What ``clear_outputs`` removes, in order (patterns relative to the output folder).
_CLEARED = (
    "manifest.parquet",
    "dataset.json",
    "README.md",
    "croissant.json",
    WIDS_INDEX,
    "failures.parquet",
    "parts/manifest-*.parquet",
    "parts/*.parquet",
    "parts/base-dataset.json",
    "shards/*.tar",
)


def clear_outputs(out: fs.Location) -> None:
    """Remove what the earlier build(s) stamped in ``out`` wrote (``written_by``; the caller
    has checked that the folder holds nothing else: ``foreign_file``), crash-safely. The
    stamp is renamed first (``parts/clearing.json``): a build killed at any point of the
    clearing leaves no build stamp, so its rerun (resumed or not) clears again, and the
    renamed stamp still lists what is left (a finished build's stamp is its dataset.json,
    renamed the same way). Then the dataset's own commit marker (manifest.parquet) goes, so
    no reader sees a manifest whose shards are going; then the chunk commit markers (manifest
    parts) before the failure parts and shards they vouch for; the renamed stamp goes last.
    On object storage the same, in the same order (a rename is a copy and a delete)."""
    if not isinstance(out, Path):
        _clear_objects(out)
        return
    chunks = stamped_chunks(out)
    stamp = stamp_path(out)
    finished = out / "dataset.json"
    if stamp.is_file():
        os.replace(stamp, out / CLEARING)
    elif finished_stamp(out) is not None and not (out / CLEARING).is_file():
        (out / "parts").mkdir(exist_ok=True)
        os.replace(finished, out / CLEARING)
    for pattern in _CLEARED:
        for stale in sorted(out.glob(pattern)):
            rel = stale.relative_to(out).as_posix()
            if written_by(chunks, rel) and stale.is_file() and not stale.is_symlink():
                stale.unlink()
    clearing = out / CLEARING
    if clearing.is_file():
        clearing.unlink()


def _clear_objects(out: str) -> None:
    """``clear_outputs`` of the object storage prefix ``out``."""
    chunks = stamped_chunks(out)
    stamp, clearing = stamp_path(out), fs.join(out, CLEARING)
    if fs.is_file(stamp):
        fs.replace(stamp, clearing)
    elif finished_stamp(out) is not None and not fs.is_file(clearing):
        fs.replace(fs.join(out, "dataset.json"), clearing)
    files = fs.list_files(out)
    done: set[str] = set()
    for pattern in _CLEARED:
        for rel in files:
            if rel not in done and fnmatch.fnmatchcase(rel, pattern) and written_by(chunks, rel):
                if "/" in pattern and rel.count("/") != pattern.count("/"):
                    continue
                fs.remove(fs.join(out, rel))
                done.add(rel)
    fs.remove(clearing)
