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

Written and read here, not through libtiff: :func:`decode_dem` inflates the one strip with
zstd and undoes the differencing in 0.11 ms a 256 px chip against 0.19 ms for
``imagecodecs.tiff_decode`` of the same file, and libtiff's writer (``imagecodecs.tiff_encode``)
cannot write the GDAL tags. Against the other codecs measured on 256 px demo chips
(``benchmarks/bench_dem_codec.py``): a 16-bit PNG of the same values is 33 KiB and decodes in
0.56 ms (inflate alone 0.33 ms); LERC at 3.9 mm is 40 KiB and loses NaN; float32 zstd with byte
shuffling (lossless) is 72 KiB; the float32 ``.npy`` is 256 KiB.

Older datasets (format version 1) hold ``dem.npy`` (float32); :func:`is_npy` tells the two
apart by the member's first bytes.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from typing import Any

import imagecodecs
import numpy as np

#: the member's file name (format version 2 on); version 1 datasets hold ``DEM_NPY_MEMBER``
DEM_MEMBER = "dem.tif"
DEM_NPY_MEMBER = "dem.npy"

#: the first dataset format version holding ``DEM_MEMBER`` (``store.dataset_info.FORMAT_VERSION``)
DEM_TIFF_FORMAT_VERSION = 2


def dem_member(format_version: int) -> str:
    """The DEM chip's member suffix in a dataset of ``format_version``."""
    return DEM_MEMBER if format_version >= DEM_TIFF_FORMAT_VERSION else DEM_NPY_MEMBER


#: the finest quantum (metres): 2^-7 m; a chip spanning more than 65534 of it takes a coarser one
FINEST_SCALE_M = 2.0**-7
NODATA = 65535
_MAX_STEP = NODATA - 1
_ZSTD_LEVEL = 3  # 0.29 ms and 24.8 KiB a 256 px chip; level 9: 2.2 ms for 22.7 KiB
CODEC = "uint16-tiff-zstd"

_TIFF_MAGIC = b"II*\x00"
_NPY_MAGIC = b"\x93NUMPY"
_ASCII, _SHORT, _LONG = 2, 3, 4
_ZSTD_COMPRESSION = 50000
_HORIZONTAL_PREDICTOR = 2
_DESCRIPTION, _STRIP_OFFSETS, _STRIP_BYTES = 270, 273, 279


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
    """uint16 (H, W) values of a float32 chip under ``enc`` (no data: ``enc.nodata``)."""
    finite = np.isfinite(dem)
    steps = np.rint((dem.astype(np.float64) - enc.offset_m) / enc.scale_m)
    return np.where(finite, np.clip(steps, 0, _MAX_STEP), enc.nodata).astype(np.uint16)


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
    values = quantize(dem, enc)
    rows = imagecodecs.delta_encode(values, axis=1).tobytes()  # the TIFF's horizontal predictor
    strip = bytes(imagecodecs.zstd_encode(rows, _ZSTD_LEVEL))
    return _tiff(values.shape, strip, enc), enc


def _tiff(shape: tuple[int, ...], strip: bytes, enc: DemEncoding) -> bytes:
    """A little-endian one-strip TIFF of uint16 (H, W) pixels, ``strip`` the zstd frame of
    their row differences, with the description and GDAL tags of ``enc``."""
    height, width = shape
    gdal = (
        '<GDALMetadata><Item name="SCALE" sample="0" role="scale">'
        f'{enc.scale_m!r}</Item><Item name="OFFSET" sample="0" role="offset">'
        f"{enc.offset_m!r}</Item></GDALMetadata>"
    )
    texts = {
        _DESCRIPTION: json.dumps(enc.as_dict(), sort_keys=True),
        42112: gdal,  # GDAL_METADATA
        42113: str(enc.nodata),  # GDAL_NODATA
    }
    entries: list[tuple[int, int, int, int | bytes]] = [
        (256, _LONG, 1, width),
        (257, _LONG, 1, height),
        (258, _SHORT, 1, 16),
        (259, _SHORT, 1, _ZSTD_COMPRESSION),
        (262, _SHORT, 1, 1),  # BlackIsZero
        (_STRIP_OFFSETS, _LONG, 1, 0),  # set below
        (277, _SHORT, 1, 1),
        (278, _LONG, 1, height),
        (_STRIP_BYTES, _LONG, 1, len(strip)),
        (284, _SHORT, 1, 1),
        (317, _SHORT, 1, _HORIZONTAL_PREDICTOR),
        (339, _SHORT, 1, 1),  # unsigned integer
    ]
    for tag, text in texts.items():
        data = text.encode("ascii") + b"\x00"
        entries.append((tag, _ASCII, len(data), data))
    entries.sort(key=lambda e: e[0])
    ifd_size = 2 + 12 * len(entries) + 4
    pos = 8 + ifd_size
    blobs: list[bytes] = []
    resolved: list[tuple[int, int, int, int]] = []
    for tag, kind, count, value in entries:
        if isinstance(value, bytes):
            resolved.append((tag, kind, count, pos))
            padded = value + b"\x00" * (len(value) % 2)  # word boundaries
            blobs.append(padded)
            pos += len(padded)
        else:
            resolved.append((tag, kind, count, value))
    strip_at = pos
    ifd = [struct.pack("<H", len(resolved))]
    for tag, kind, count, value in resolved:
        if tag == _STRIP_OFFSETS:
            value = strip_at
        fmt = "<HHIHH" if kind == _SHORT else "<HHII"
        ifd.append(struct.pack(fmt, tag, kind, count, value, 0) if kind == _SHORT
                   else struct.pack(fmt, tag, kind, count, value))  # fmt: skip
    ifd.append(b"\x00\x00\x00\x00")  # no next IFD
    return b"".join([_TIFF_MAGIC, struct.pack("<I", 8), *ifd, *blobs, strip])


def is_npy(data: bytes | bytearray) -> bool:
    """Whether member bytes are a ``.npy`` array (a version-1 ``dem.npy``), not a ``dem.tif``."""
    return bytes(data[:6]) == _NPY_MAGIC


def decode_dem(data: bytes | bytearray) -> np.ndarray:
    """A ``dem.tif``'s float32 (H, W) metres (NaN: no data), as :func:`encode_dem` wrote it;
    ValueError for other bytes (the datasets name the member)."""
    values, enc = decode_dem_values(data)
    return dequantize(values, enc)


def decode_dem_values(data: bytes | bytearray) -> tuple[np.ndarray, DemEncoding]:
    """The uint16 (H, W) values of a ``dem.tif`` and their quantization; ValueError when the
    bytes are not such a file."""
    view = memoryview(data)
    if bytes(view[:4]) != _TIFF_MAGIC or len(view) < 10:
        raise ValueError("not a DEM chip TIFF (little-endian) nor a .npy array")
    try:
        (at,) = struct.unpack_from("<I", view, 4)
        (count,) = struct.unpack_from("<H", view, at)
        tags: dict[int, tuple[int, int, int]] = {}
        for i in range(count):
            tag, kind, n, value = struct.unpack_from("<HHII", view, at + 2 + 12 * i)
            tags[tag] = (kind, n, value & 0xFFFF if kind == _SHORT else value)
        width, height = tags[256][2], tags[257][2]
        layout = (tags[258][2], tags[259][2], tags[317][2], tags[277][2], tags[278][2])
        if layout != (16, _ZSTD_COMPRESSION, _HORIZONTAL_PREDICTOR, 1, height):
            raise ValueError(
                "not a one-strip uint16 zstd TIFF with horizontal differencing "
                f"(bits, compression, predictor, samples, rows per strip: {layout})"
            )
        _, n, start = tags[_DESCRIPTION]
        desc = json.loads(bytes(view[start : start + n]).rstrip(b"\x00"))
        enc = DemEncoding(float(desc["scale_m"]), float(desc["offset_m"]), int(desc["nodata"]))
        strip_at, strip_size = tags[_STRIP_OFFSETS][2], tags[_STRIP_BYTES][2]
    except (KeyError, TypeError, struct.error, json.JSONDecodeError) as exc:
        raise ValueError(f"bad DEM chip TIFF header: {exc!r}") from None
    if strip_at + strip_size > len(view):
        raise ValueError(f"DEM chip TIFF: strip of {strip_size} bytes past the end")
    raw = bytearray(2 * width * height)
    try:
        got = imagecodecs.zstd_decode(bytes(view[strip_at : strip_at + strip_size]), out=raw)
    except imagecodecs.ZstdError as exc:
        raise ValueError(f"DEM chip TIFF: bad zstd strip: {exc}") from None
    if len(got) != len(raw):
        raise ValueError(f"DEM chip TIFF: {len(got)} bytes for {width} x {height} uint16")
    values = np.frombuffer(raw, dtype="<u2").reshape(height, width)
    return imagecodecs.delta_decode(values, axis=1, out=values), enc
