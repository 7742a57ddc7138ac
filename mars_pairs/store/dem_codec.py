"""The DEM chip member (``dem.tif``): float32 metres quantized to uint16, in a one-strip TIFF
compressed with zstd after horizontal differencing (TIFF predictor 2).

A chip of elevations z (metres above the areoid, NaN: no data) is stored as
``v = round((z - offset_m) / scale_m)`` (uint16 0..65534; 65535: no data), so
``z = offset_m + scale_m * v``. ``offset_m`` is the chip's lowest elevation floored to whole
metres, ``scale_m`` is 2^-7 m (7.8 mm), doubled until the chip's span fits in 65534 steps
(a chip spanning more than 512 m). Both are powers-of-two steps on an integer offset, so the
decoded float32 value is the quantization grid point exactly (for |z| < 131 km): every
finite cell decodes within ``scale_m / 2`` (3.9 mm) of the float32 chip, every NaN cell to
NaN. Non-finite cells (NaN, +-inf) are no data.

The file is a standard TIFF (uint16, BlackIsZero, zstd = compression 50000, predictor 2):
GDAL, rasterio, QGIS and tifffile open it, and GDAL applies the scale, offset and no-data
value it carries (the GDAL_METADATA and GDAL_NODATA tags). The ImageDescription tag holds
the same as JSON (``DemEncoding.as_dict``), which :func:`decode_dem` reads; the sample's
``meta.json`` repeats it under ``dem_encoding``.

Written and read by ``store.strip_tiff``: 30 KiB a 256 px demo chip, 0.4 ms to encode and
0.13 ms to decode (best of 300, load 6). Against the other codecs measured on 256 px chips
(load 6-10): a 16-bit PNG of the same values is 33 KiB and decodes in 0.56 ms (inflate alone
0.33 ms); LERC at 3.9 mm is 40 KiB and loses NaN; blosc2 (lz4, byte shuffle) 47 KiB and 0.05
ms but no TIFF reader opens it; float32 zstd with byte shuffling (lossless) 72 KiB; the
float32 ``.npy`` 256 KiB.

Older datasets (format version 1) hold ``dem.npy`` (float32); :func:`is_npy` tells the two
apart by the member's first bytes.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mars_pairs.kernels.quantize import quantize_steps
from mars_pairs.store.strip_tiff import (
    DESCRIPTION,
    GDAL_METADATA,
    GDAL_NODATA,
    HORIZONTAL_PREDICTOR,
    read_strip_tiff,
    write_strip_tiff,
)

#: the member's file name (format version 2 on); version 1 datasets hold ``DEM_NPY_MEMBER``
DEM_MEMBER = "dem.tif"
DEM_NPY_MEMBER = "dem.npy"

#: the first dataset format version holding ``DEM_MEMBER`` (``store.dataset_info.FORMAT_VERSION``)
DEM_TIFF_FORMAT_VERSION = 2


def dem_member(format_version: int) -> str:
    """The DEM chip's member suffix in a dataset of ``format_version``."""
    return DEM_MEMBER if format_version >= DEM_TIFF_FORMAT_VERSION else DEM_NPY_MEMBER


def version_suffixes(format_version: int) -> dict[str, str]:
    """The member suffixes (field -> suffix) a dataset of ``format_version`` names otherwise
    than this version: version 1's ``dem.npy`` and ``ground_px.npy``; {} from version 2."""
    if format_version >= DEM_TIFF_FORMAT_VERSION:
        return {}
    return {"dem": DEM_NPY_MEMBER, "ground_px": "ground_px.npy"}


#: the finest quantum (metres): 2^-7 m; a chip spanning more than 65534 of it takes a coarser one
FINEST_SCALE_M = 2.0**-7
NODATA = 65535
_MAX_STEP = NODATA - 1
_ZSTD_LEVEL = 3  # 0.29 ms and 24.8 KiB a 256 px chip; level 9: 2.2 ms for 22.7 KiB
CODEC = "uint16-tiff-zstd"

_NPY_MAGIC = b"\x93NUMPY"


def dataset_dem_encoding() -> dict[str, Any]:
    """dataset.json's ``dem_encoding``: how every sample's ``dem.tif`` decodes (the values
    of each sample are in its ``meta.json``'s ``dem_encoding``)."""
    return {
        "member": DEM_MEMBER,
        "codec": CODEC,
        "layout": "one-strip little-endian TIFF, uint16, zstd (compression 50000), "
        "horizontal differencing (predictor 2)",
        "metres": "offset_m + scale_m * v",
        "nodata": NODATA,
        "finest_scale_m": FINEST_SCALE_M,
        "max_error_m": "scale_m / 2 (a power of two from finest_scale_m up, per sample)",
        "per_sample": "meta.json dem_encoding: codec, scale_m, offset_m, nodata, max_error_m",
    }


@dataclass(frozen=True)
class DemEncoding:
    """How one chip's uint16 values map to metres: ``z = offset_m + scale_m * v``; ``v ==
    nodata``: no data. ``max_error_m`` (half the quantum) bounds |decoded - float32 chip|."""

    scale_m: float
    offset_m: float
    nodata: int = NODATA

    @property
    def max_error_m(self) -> float:
        return self.scale_m / 2

    def as_dict(self) -> dict[str, Any]:
        """The JSON form (the TIFF's description, ``meta.json``'s ``dem_encoding``)."""
        return {
            "codec": CODEC,
            "scale_m": self.scale_m,
            "offset_m": self.offset_m,
            "nodata": self.nodata,
            "max_error_m": self.max_error_m,
        }


def dem_encoding(dem: np.ndarray) -> DemEncoding:
    """The quantization of a float32 chip (metres; non-finite: no data): the lowest finite
    elevation floored to whole metres, the finest power-of-two quantum from 2^-7 m up that
    spans the chip in 65534 steps."""
    finite = dem[np.isfinite(dem)]
    if finite.size == 0:
        return DemEncoding(FINEST_SCALE_M, 0.0)
    offset = math.floor(float(finite.min()))
    span = float(finite.max()) - offset
    scale = FINEST_SCALE_M
    while span / scale > _MAX_STEP - 0.5:
        scale *= 2
    return DemEncoding(scale, float(offset))


def quantize(dem: np.ndarray, enc: DemEncoding) -> np.ndarray:
    """uint16 (H, W) values of a float32 chip under ``enc`` (no data: ``enc.nodata``):
    ``rint((z - offset_m) / scale_m)`` in float64, clipped to [0, 65534] (one compiled pass,
    ``kernels.quantize``)."""
    values = np.ascontiguousarray(dem, dtype=np.float32)
    return quantize_steps(values, enc.offset_m, enc.scale_m, _MAX_STEP, enc.nodata)


def dequantize(values: np.ndarray, enc: DemEncoding) -> np.ndarray:
    """float32 metres of uint16 values under ``enc`` (NaN where ``enc.nodata``)."""
    out: np.ndarray = np.multiply(values, np.float32(enc.scale_m), dtype=np.float32)
    out += np.float32(enc.offset_m)
    out[values == enc.nodata] = np.nan
    return out


def encode_dem(dem: np.ndarray) -> tuple[bytes, DemEncoding]:
    """The ``dem.tif`` bytes of a float32 (H, W) chip (metres, non-finite: no data) and the
    quantization it used."""
    if dem.ndim != 2:
        raise ValueError(f"DEM chip: expected a 2-D array, got shape {dem.shape}")
    enc = dem_encoding(dem)
    gdal = (
        '<GDALMetadata><Item name="SCALE" sample="0" role="scale">'
        f'{enc.scale_m!r}</Item><Item name="OFFSET" sample="0" role="offset">'
        f"{enc.offset_m!r}</Item></GDALMetadata>"
    )
    texts = {
        DESCRIPTION: json.dumps(enc.as_dict(), sort_keys=True),
        GDAL_METADATA: gdal,
        GDAL_NODATA: str(enc.nodata),
    }
    data = write_strip_tiff(
        quantize(dem, enc), predictor=HORIZONTAL_PREDICTOR, level=_ZSTD_LEVEL, texts=texts
    )
    return data, enc


def is_npy(data: bytes | bytearray) -> bool:
    """Whether member bytes are a ``.npy`` array (a version-1 ``dem.npy``), not a ``dem.tif``."""
    return bytes(data[:6]) == _NPY_MAGIC


def dem_chip(data: bytes | bytearray) -> np.ndarray:
    """A DEM chip member of either format (``dem.tif``, or a version-1 ``dem.npy``) as float32
    (H, W) metres, NaN no data; ValueError for other bytes."""
    if is_npy(data):
        chip = np.load(io.BytesIO(bytes(data)), allow_pickle=False)
        if chip.ndim != 2:
            raise ValueError(f"DEM chip .npy: shape {chip.shape}, expected 2-D")
        return np.asarray(chip, dtype=np.float32)
    return decode_dem(data)


def decode_dem(data: bytes | bytearray) -> np.ndarray:
    """A ``dem.tif``'s float32 (H, W) metres (NaN: no data), as :func:`encode_dem` wrote it;
    ValueError for other bytes (the datasets name the member)."""
    values, enc = decode_dem_values(data)
    return dequantize(values, enc)


def decode_dem_values(data: bytes | bytearray) -> tuple[np.ndarray, DemEncoding]:
    """The uint16 (H, W) values of a ``dem.tif`` and their quantization (its description);
    ValueError when the bytes are not such a file."""
    values, texts = read_strip_tiff(data)
    if values.dtype != np.uint16 or values.ndim != 2:
        raise ValueError(f"DEM chip TIFF: {values.dtype} pixels of shape {values.shape}")
    try:
        desc = json.loads(texts[DESCRIPTION])
        enc = DemEncoding(float(desc["scale_m"]), float(desc["offset_m"]), int(desc["nodata"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"DEM chip TIFF: bad description: {exc!r}") from None
    return values, enc
