"""The dense members' files (``output.members``, format version 3 on): each a lossless
one-strip zstd TIFF (``store.strip_tiff``), ``<field>.tif``, read back bit for bit.

Each field's pixel type and predictor (:data:`CODECS`): the float grids (``range``,
``depth``, ``dem_view`` float32, ``hits`` float64 (H', W', 3)) after the floating-point
predictor (TIFF predictor 3), NaN kept as it is (GDAL_NODATA ``nan``); ``ortho_view`` (uint8)
after horizontal differencing (predictor 2); the masks (``view_valid``,
``ground_on_map_cover``, uint8 0/255), the colours laid on the map (``ground_on_map``, uint8,
RGB when the ground image is) and ``ground_px`` (float32 (S, S, 2), ``store.float_tiff``'s
file) without a predictor: on the chip grid most of each is empty, which zstd takes alone.
All at zstd level 1. GDAL (so rasterio and QGIS) reads each as written.

Against the members of format version 2 (``.npy`` arrays and PNG images: :data:`V2_MEMBERS`),
on the 512 px chips of ``benchmarks/bench_build.py --dense`` (thread CPU, best of 5, 48
samples, load 8): the colours laid on the map 0.07 ms instead of 0.88 ms for libpng (3.3
against 4.8 KiB), their cover 0.03 ms instead of 0.28 ms; the float grids 0.05-0.25 ms each
where ``np.save`` took 0.01 ms, for 12.5 KiB instead of 30.3 (``range``) and 75.8 KiB
instead of 181.2 (``hits``).

Older datasets keep their members: :func:`version_suffixes` names them, and the readers
(``torch.decode``) tell the formats apart by the member's first bytes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from mars_pairs.store import dem_codec
from mars_pairs.store.strip_tiff import (
    DESCRIPTION,
    FLOAT_PREDICTOR,
    GDAL_NODATA,
    HORIZONTAL_PREDICTOR,
    NO_PREDICTOR,
    read_strip_tiff,
    write_strip_tiff,
)

#: the first dataset format version whose dense members are ``<field>.tif``
#: (``store.dataset_info.FORMAT_VERSION``)
DENSE_TIFF_FORMAT_VERSION = 3


@dataclass(frozen=True)
class DenseCodec:
    """How one dense field is stored: its pixel type (numpy name), the TIFF predictor and the
    zstd level."""

    dtype: str
    predictor: int
    level: int = 1


#: every dense field's file (``store.members.DENSE_FIELDS``)
CODECS: dict[str, DenseCodec] = {
    "range": DenseCodec("float32", FLOAT_PREDICTOR),
    "depth": DenseCodec("float32", FLOAT_PREDICTOR),
    "hits": DenseCodec("float64", FLOAT_PREDICTOR),
    "ortho_view": DenseCodec("uint8", HORIZONTAL_PREDICTOR),
    "view_valid": DenseCodec("uint8", NO_PREDICTOR),
    "dem_view": DenseCodec("float32", FLOAT_PREDICTOR),
    "ground_on_map": DenseCodec("uint8", NO_PREDICTOR),
    "ground_on_map_cover": DenseCodec("uint8", NO_PREDICTOR),
    "ground_px": DenseCodec("float32", NO_PREDICTOR),
}

#: the dense members of format version 2 written otherwise (``ground_px`` was already
#: ``ground_px.tif``; version 1's ``ground_px.npy``: ``store.dem_codec.version_suffixes``)
V2_MEMBERS = {
    "range": "range.npy",
    "depth": "depth.npy",
    "hits": "hits.npy",
    "ortho_view": "ortho_view.png",
    "view_valid": "view_valid.png",
    "dem_view": "dem_view.npy",
    "ground_on_map": "ground_on_map.png",
    "ground_on_map_cover": "ground_on_map_cover.png",
}


def dense_member(field: str) -> str:
    """The tar member suffix of a dense field (format version 3 on): ``<field>.tif``."""
    if field not in CODECS:
        raise ValueError(f"not a dense field: {field!r}; expected one of {list(CODECS)}")
    return f"{field}.tif"


def version_suffixes(format_version: int) -> dict[str, str]:
    """The member suffixes (field -> suffix) a dataset of ``format_version`` names otherwise
    than this version: version 2's dense ``.npy`` and ``.png`` members (:data:`V2_MEMBERS`),
    version 1's besides (``store.dem_codec.version_suffixes``); {} from version 3."""
    if format_version >= DENSE_TIFF_FORMAT_VERSION:
        return {}
    return {**V2_MEMBERS, **dem_codec.version_suffixes(format_version)}


def encode_dense(field: str, values: np.ndarray) -> bytes:
    """The ``<field>.tif`` bytes of a dense field's array (cast to its codec's pixel type:
    :data:`CODECS`), bit for bit."""
    codec = CODECS[field]
    pixels = np.asarray(values, dtype=codec.dtype)
    texts = _TEXTS.get(codec.dtype, {})
    return write_strip_tiff(pixels, predictor=codec.predictor, level=codec.level, texts=texts)


#: the ASCII tags of the float fields' files: the description float_tiff writes (one file
#: for ground_px) and GDAL's nodata
_TEXTS = {
    name: {
        DESCRIPTION: json.dumps({"codec": f"{name}-tiff-zstd", "nodata": "nan"}),
        GDAL_NODATA: "nan",
    }
    for name in ("float32", "float64")
}


def decode_dense(data: bytes | bytearray, max_pixels: int | None = None) -> np.ndarray:
    """The (writable) array of a dense member's TIFF, as :func:`encode_dense` wrote it;
    ValueError for other bytes and, unread, for more than ``max_pixels`` pixels."""
    pixels, _ = read_strip_tiff(data, max_pixels)
    return pixels
