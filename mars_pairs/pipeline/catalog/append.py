"""Appending a new archive release to a finished footprint catalogue
(``mars-pairs catalog --append``), as ``build --append`` appends to a dataset
(``pipeline.builder.append``, whose rules it shares).

The labels the release's globs match that the catalogue does not hold yet (a row's
``label_path`` or a failure row's ``path``: *known*, skipped and counted) are catalogued as new
chunks after the catalogue's own (chunk k >= catalog.json's ``chunks``); their rows join the
existing ones, which are read back unchanged, and every file of the folder is rewritten whole,
atomically: catalog.parquet (Hilbert order, as a single run), failures.parquet (the base's
rows, then the new chunks'), pairs.parquet (recomputed over the union, so new-old pairs are
in it), catalog.json (counts, the inputs' fingerprints, ``chunks``, the appends made), the
card and the STAC files. A new label whose key the catalogue holds becomes a
DuplicateKeyError failure row naming the label holding it (the existing row is kept, as the
build's append keeps the existing sample).

What may change: ``inputs.labels`` (their labels root must stay the one ``label_path`` is
relative to) and ``inputs.places``; every other config key, and the DEM and ortho files, must
be the catalogue's (refused naming the key).

Crash safety: the append first links (or copies) catalog.parquet, failures.parquet and
catalog.json to ``parts/base-*``, then writes its stamp (``parts/stamp.json``, ``kind:
catalog-append``: the fingerprint of its config and new labels, its first chunk). While that
stamp is there the base is read from ``parts/base-*``, so a killed append rerun with
``--append`` plans the same chunks, keeps those committed and ends with the same folder. The
stamp goes before the base copies as the append finishes.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.append import (
    MAY_CHANGE,
    check_fixed_inputs,
    config_difference,
    known_labels,
    new_labels,
)
from mars_pairs.pipeline.builder.fingerprints import LabelDigest
from mars_pairs.pipeline.builder.finish import relative_config
from mars_pairs.pipeline.builder.stamp import read_stamp, stamp_difference, stamp_of
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.record import labels_root
from mars_pairs.store.atomic import atomic_path

#: the stamp's ``kind`` of an append in progress
APPEND_KIND = "catalog-append"
#: catalog.json's list of the appends made to the catalogue
APPENDS_KEY = "appends"
#: the catalogue's files an append reads as its base, and where it keeps their snapshot
BASE_FILES = {
    "catalog.parquet": "parts/base-catalog.parquet",
    "failures.parquet": "parts/base-failures.parquet",
    "catalog.json": "parts/base-catalog.json",
}


@dataclass(frozen=True)
class CatalogAppend:
    """What ``catalog --append`` does over the catalogue in ``out``: the release's labels
    matched, those the catalogue holds (skipped), the new ones (in build order) and their
    chunks ``[base_chunks, base_chunks + chunks)``; ``resumed``: an interrupted append of the
    same release was found (its committed chunks are kept)."""

    out: Path
    base_chunks: int
    labels_seen: int
    labels_known: int
    labels: tuple[str, ...]
    chunks: int
    resumed: bool
    stamp: dict[str, Any] = field(repr=False)  # the stamp it writes (parts/stamp.json)
    base: dict[str, Any] = field(repr=False)  # the base's catalog.json
    keys: dict[str, str] = field(repr=False)  # key -> label_path the catalogue holds

    def base_path(self, name: str) -> Path:
        """Where the append reads the base's ``name`` (``BASE_FILES``' snapshot)."""
        return self.out / BASE_FILES[name]

    def record(self, config: BuildConfig, images: int, failures: int) -> dict[str, Any]:
        """The entry of catalog.json's ``appends``: the release's globs and PLACES table
        (relative to the folder), the globs before it, the labels matched, skipped and
        added, the rows and failure rows it added, its chunks ``[first, end)``."""
        inputs = relative_config(config)["inputs"]
        before = self.base.get("config", {}).get("inputs", {})
        return {
            "labels": inputs["labels"],
            "previous_labels": before.get("labels"),
            "places": inputs["places"],
            "labels_seen": self.labels_seen,
            "labels_known": self.labels_known,
            "labels_added": len(self.labels),
            "images": images,
            "failures": failures,
            "chunks": [self.base_chunks, self.base_chunks + self.chunks],
        }


def _plain(doc: Any) -> Any:
    return json.loads(json.dumps(doc))


def _lookup(doc: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        doc = doc.get(part) if isinstance(doc, dict) else None
    return doc


def check_catalog_append(config: BuildConfig, out: Path, base: dict[str, Any]) -> None:
    """ConfigError naming the key when ``config`` may not append to the catalogue in ``out``
    whose catalog.json is ``base``: a config key other than ``MAY_CHANGE`` changed, the
    labels root moved, or the DEM or ortho file changed (catalog.json's ``input_files``)."""
    why = f"{out}: cannot --append"
    old = base.get("config")
    if not isinstance(old, dict):
        raise ConfigError(f"{why}: its catalog.json holds no config")
    key = config_difference(old, _plain(relative_config(config)))
    if key is not None:
        raise ConfigError(
            f"{key}: changed since the catalogue was made ({_lookup(old, key)!r} -> "
            f"{_lookup(relative_config(config), key)!r}); {why}: an append may change "
            f"{' and '.join(MAY_CHANGE[:2])} only (catalogue the new config into a new folder)"
        )
    globs = old.get("inputs", {}).get("labels") or []
    before = labels_root([os.path.normpath(out / g) for g in globs])
    now = labels_root(config.inputs.labels)
    if os.path.normpath(before) != os.path.normpath(now):
        raise ConfigError(
            f"inputs.labels: the labels root would move from {before} to {now}; {why}: "
            "label_path is relative to it, so the release's globs must start from the same "
            "folder"
        )
    recorded = base.get("input_files")
    if not isinstance(recorded, dict):
        raise ConfigError(f"{why}: its catalog.json records no input_files; rebuild it")
    check_fixed_inputs(
        config, recorded, "the catalogue was made", f"{why}: its footprints would not match "
        "the new ones",
    )  # fmt: skip


def plan_catalog_append(config: BuildConfig, out: Path, stamp_rel: str) -> CatalogAppend:
    """Check that ``config`` may append to the finished catalogue in ``out`` and find the new
    labels (one streaming pass) and the chunks an interrupted append of the same release
    (its stamp at ``out / stamp_rel``) committed; writes nothing. ConfigError naming the file
    or key otherwise (no finished catalogue, an interrupted catalogue that is not an append,
    an interrupted append of another release, ``check_catalog_append``)."""
    previous = read_stamp(out / stamp_rel)
    interrupted = previous is not None and previous.get("kind") == APPEND_KIND
    if previous is not None and not interrupted:
        raise ConfigError(
            f"{out}: cannot --append: it holds an interrupted catalogue ({stamp_rel}); "
            "finish it with --resume first"
        )
    paths = {n: out / (rel if interrupted else n) for n, rel in BASE_FILES.items()}
    base = read_stamp(paths["catalog.json"])
    absent = [str(p) for p in paths.values() if not p.is_file()]
    if absent or base is None or not isinstance(base.get("chunks"), int):
        what = absent[0] if absent else str(paths["catalog.json"])
        raise ConfigError(
            f"{out}: cannot --append: {what} is missing or not a finished catalogue's; "
            "--append adds to a finished catalogue (make it first)"
        )
    check_catalog_append(config, out, base)
    known, keys = known_labels(
        paths["catalog.parquet"], paths["failures.parquet"], labels_root(config.inputs.labels)
    )
    every, fresh = LabelDigest(), LabelDigest()
    labels = tuple(fresh.tally(new_labels(config, known.__contains__, every)))
    base_chunks = int(base["chunks"])
    chunks = -(-len(labels) // config.output.shard_size)
    stamp = {"kind": APPEND_KIND, **stamp_of(config, fresh), "first_chunk": base_chunks}
    if interrupted:
        assert previous is not None
        why = stamp_difference(previous, stamp)
        if why is None and previous.get("first_chunk") != base_chunks:
            why = "the interrupted append's first chunk differs"
        if why is not None:
            raise ConfigError(
                f"{out}: cannot --append: the folder holds an interrupted --append of another "
                f"release ({why}); rerun that append (its config) with --append to finish it"
            )
    return CatalogAppend(
        out, base_chunks, every.count, every.count - fresh.count, labels, chunks,
        interrupted, stamp, base, keys,
    )  # fmt: skip


def snapshot_base(out: Path) -> None:
    """Keep the catalogue's catalog.parquet, failures.parquet and catalog.json as the
    append's base (``BASE_FILES``): hard links where the file system has them (the merge
    replaces the files, never writes into them), copies otherwise; atomically each."""
    (out / "parts").mkdir(exist_ok=True)
    for name, rel in BASE_FILES.items():
        with atomic_path(out / rel) as tmp:
            tmp.unlink(missing_ok=True)
            try:
                os.link(out / name, tmp)
            except OSError:
                shutil.copyfile(out / name, tmp)
