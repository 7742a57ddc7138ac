"""``croissant.json``: Croissant 1.0 metadata (MLCommons, JSON-LD) of a built dataset folder.

The manifest is a FileObject and the record set ``samples`` its typed columns (one record per
sample); the shards are a FileSet (``shards/*.tar``) and the members a FileSet of each kind
contained in them. Paths are relative to the folder (``contentUrl``), so the folder moves
whole. Written from the build's facts alone (no date): the same build writes the same bytes.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from mars_pairs.store.card import COLUMN_DOCS, MEMBER_DOCS, sources

#: The JSON-LD context of Croissant 1.0 (as mlcroissant writes it).
CONTEXT: dict[str, Any] = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "equivalentProperty": "cr:equivalentProperty",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "samplingRate": "cr:samplingRate",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}

#: Where the project lives (the dataset's ``url`` when it has no home of its own).
PROJECT_URL = "https://github.com/mars-pairs/mars-pairs"

_MEDIA = {".png": "image/png", ".jpg": "image/jpeg", ".tif": "image/tiff",
          ".npy": "application/x-npy", ".json": "application/json"}  # fmt: skip


def croissant_type(t: pa.DataType) -> str | None:
    """The Croissant data type of an Arrow column type; None for columns left out of the
    record set (WKB geometries, structs: described in the card)."""
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return "sc:Text"
    if pa.types.is_boolean(t):
        return "sc:Boolean"
    if pa.types.is_integer(t):
        return "sc:Integer"
    if pa.types.is_floating(t):
        return "sc:Float"
    if pa.types.is_timestamp(t):
        return "sc:DateTime"
    return None


def sha256_of(path: Path | str) -> str:
    """The hex SHA-256 of a file's bytes (a local path or an fsspec URL: ``store.fs``)."""
    from mars_pairs.store import fs

    h = hashlib.sha256()
    with fs.open_input(path if isinstance(path, str) and fs.is_url(path) else Path(path)) as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def croissant_metadata(
    *,
    name: str,
    description: str,
    version: str,
    license: str,
    synthetic: bool,
    schema: pa.Schema,
    manifest_sha256: str,
    members: Sequence[str] = tuple(MEMBER_DOCS),
    missions: Sequence[str] = (),
    url: str = PROJECT_URL,
) -> dict[str, Any]:
    """The Croissant JSON-LD document of a dataset folder whose manifest has ``schema`` and
    whose ``manifest.parquet`` hashes to ``manifest_sha256``; ``missions``: those of its
    samples (the PDS data sets cited)."""
    fields = []
    for f in schema:
        kind = croissant_type(f.type)
        if kind is None:
            continue
        field: dict[str, Any] = {
            "@type": "cr:Field",
            "@id": f"samples/{f.name}",
            "name": f.name,
            "dataType": kind,
            "source": {"fileObject": {"@id": "manifest"}, "extract": {"column": f.name}},
        }
        units, frame = COLUMN_DOCS.get(f.name, ("-", "-"))
        if (units, frame) != ("-", "-"):
            field["description"] = f"{units}; {frame}"
        fields.append(field)
    distribution: list[dict[str, Any]] = [
        {
            "@type": "cr:FileObject",
            "@id": "manifest",
            "name": "manifest",
            "description": "One row per sample (GeoParquet 1.1).",
            "contentUrl": "manifest.parquet",
            "encodingFormat": "application/x-parquet",
            "sha256": manifest_sha256,
        },
        {
            "@type": "cr:FileSet",
            "@id": "shards",
            "name": "shards",
            "description": "WebDataset tar shards: members <key>.<member>.",
            "encodingFormat": "application/x-tar",
            "includes": "shards/*.tar",
        },
    ]
    for member in members:
        file_name, fmt, units = MEMBER_DOCS[member]
        first = file_name.split(" / ")[0]
        suffix = Path(first).suffix
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": f"member-{member}",
                "name": f"member-{member}",
                "description": f"{fmt}; {units}",
                "containedIn": {"@id": "shards"},
                "encodingFormat": _MEDIA.get(suffix, "application/octet-stream"),
                "includes": f"*.{member}.*",
            }
        )
    cited = sources(synthetic, missions)
    return {
        "@context": CONTEXT,
        "@type": "sc:Dataset",
        "name": name,
        "description": description,
        "conformsTo": "http://mlcommons.org/croissant/1.0",
        "license": license,
        "url": url,
        "version": version,
        "citeAs": " ".join(s.lstrip("- ") for s in cited),
        "keywords": ["Mars", "rover", "cross-view", "geospatial", "webdataset"],
        "distribution": distribution,
        "recordSet": [
            {
                "@type": "cr:RecordSet",
                "@id": "samples",
                "name": "samples",
                "description": "The manifest: one record per sample.",
                "key": {"@id": "samples/key"},
                "field": fields,
            }
        ],
    }


def dataset_description(counts: Mapping[str, Any], synthetic: bool) -> str:
    """The one-paragraph description of the dataset (Croissant ``description``)."""
    kind = "synthetic" if synthetic else "NASA PDS"
    return (
        f"Paired Mars rover ground images and orbital chips (orthoimage, DEM, viewshed) with "
        f"per-pixel correspondence, from {kind} data: {counts.get('samples', 0)} samples."
    )
