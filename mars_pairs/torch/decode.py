"""Member bytes -> arrays -> tensors: the two decoding stages of every dataset read.

Stage 1 decodes a member to its compact array (uint8 images channels last, float32 DEM and
correspondence); stage 2 writes its [C, H, W] tensor in one pass.

The DEM chip is a quantized uint16 TIFF (``store.dem_codec``: 0.13 ms a 256 px chip) and
``ground_px`` a lossless float32 TIFF (``store.float_tiff``) in format version 2, both
``.npy`` in version 1; every dense member is a lossless TIFF (``store.dense_codec``) from
version 3, a ``.npy`` array or a PNG image in version 2; told apart by the member's first
bytes.

JPEG members are decoded by simplejpeg (libjpeg-turbo, accurate DCT and fancy upsampling:
the pixels Pillow gives), 0.43 ms against Pillow's 0.84 ms for the demo's 384 px ground
images; PNG members, and JPEGs simplejpeg does not take as they are (CMYK, a colour JPEG read
as grey), by Pillow."""

from __future__ import annotations

import io
import json
import warnings
from functools import lru_cache
from typing import Any

import numpy as np
import pyarrow as pa
import simplejpeg
import torch
from PIL import Image

from mars_pairs.errors import ArgumentError
from mars_pairs.store.dem_codec import DEM_MEMBER, decode_dem, is_npy
from mars_pairs.store.dense_codec import decode_dense
from mars_pairs.store.float_tiff import decode_float_tiff
from mars_pairs.store.members import DENSE_FIELDS, OPTIONAL_FIELDS
from mars_pairs.store.strip_tiff import is_tiff

DEFAULT_FIELDS = ("ground", "ortho", "dem", "viewshed")


#: Every default member's field (the optional ones: ``store.members.OPTIONAL_FIELDS``).
ALL_FIELDS = ("ground", "ortho", "dem", "viewshed", "corr")
KNOWN_FIELDS = ALL_FIELDS + OPTIONAL_FIELDS


#: uint8 with image_dtype=torch.uint8
IMAGE_FIELDS = ("ground", "ortho", "viewshed", "ortho_view", "view_valid", "ground_on_map",
                "ground_on_map_cover")  # fmt: skip
MASK_FIELDS = ("viewshed", "view_valid", "ground_on_map_cover")  # {0, 1}
#: class labels: uint8 whatever ``image_dtype`` (0..254 classes, 255 no label)
LABEL_FIELDS = ("terrain", "terrain_on_map")


#: tar member suffixes of the fields (the ground image's is in the manifest's ground_member;
#: older formats' suffixes: ``store.dense_codec.version_suffixes``)
MEMBER_SUFFIXES = {
    "ground": "ground.jpg",
    "ortho": "ortho.png",
    "dem": DEM_MEMBER,
    "viewshed": "viewshed.png",
    "corr": "corr.npy",
    "meta": "meta.json",
    "range": "range.tif",
    "depth": "depth.tif",
    "hits": "hits.tif",
    "ortho_view": "ortho_view.tif",
    "view_valid": "view_valid.tif",
    "dem_view": "dem_view.tif",
    "ground_on_map": "ground_on_map.tif",
    "ground_on_map_cover": "ground_on_map_cover.tif",
    "ground_px": "ground_px.tif",
    "terrain": "terrain.png",
    "terrain_on_map": "terrain_on_map.png",
}


#: the most pixels an image member may have (a full-frame Navcam image has 20 Mpx); a larger
#: one (a decompression bomb: a few KB of PNG for 20000 x 20000 pixels) is a ValueError, which
#: the datasets report as a DatasetError naming the shard and the member
MAX_MEMBER_PIXELS = 64_000_000

UINT8_DIVISORS = {"ground": 255.0, "ortho": 255.0, "viewshed": 1.0}  # float32 = uint8 / this


def _image_u8(
    data: bytes | bytearray, mode: str, size: tuple[int, int] | None = None
) -> np.ndarray:
    """Decode an image to uint8 [H, W] or [H, W, C] (resized to ``size`` (H, W) if given);
    ValueError for an image of more than MAX_MEMBER_PIXELS pixels, before its pixels are
    decoded."""
    if data[:2] == b"\xff\xd8":  # JPEG start of image
        fast = _jpeg_u8(data, mode)
        if fast is not None:
            if size is not None and fast.shape[:2] != tuple(size):
                resized = Image.fromarray(fast).resize(
                    (size[1], size[0]), Image.Resampling.BILINEAR
                )
                return _pil_array(resized)
            return fast
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # checked below
            opened = Image.open(io.BytesIO(data))
    except Image.DecompressionBombError as exc:
        raise ValueError(f"image over the pixel limit: {exc}") from None
    with opened as im:
        _check_pixels(im.width, im.height)
        if im.mode != mode:
            im = im.convert(mode)
        if size is not None and (im.height, im.width) != tuple(size):
            im = im.resize((size[1], size[0]), Image.Resampling.BILINEAR)
        return _pil_array(im)


def _check_pixels(width: int, height: int) -> None:
    """ValueError for an image of more than MAX_MEMBER_PIXELS pixels."""
    if width * height > MAX_MEMBER_PIXELS:
        raise ValueError(
            f"{width} x {height} pixels: over the limit of {MAX_MEMBER_PIXELS} "
            "pixels an image member may have"
        )


#: simplejpeg's output colourspace for a Pillow mode, by the JPEG's own colourspace (those
#: for which libjpeg-turbo's conversion is Pillow's: grey to RGB repeats the grey value;
#: Pillow's RGB to L is its own luma formula, not libjpeg's Y, so that one goes to Pillow)
_JPEG_COLOURSPACES = {
    "RGB": {"YCbCr": "RGB", "RGB": "RGB", "Gray": "RGB"},
    "L": {"Gray": "GRAY"},
}


def _jpeg_u8(data: bytes | bytearray, mode: str) -> np.ndarray | None:
    """A JPEG's uint8 pixels in ``mode`` ("RGB" [H, W, 3] or "L" [H, W]) by simplejpeg, None
    where Pillow should decode it (a colourspace simplejpeg would convert differently, a
    header it cannot read: Pillow then names the fault); ValueError over MAX_MEMBER_PIXELS
    pixels, from the header, before any pixel is decoded."""
    try:
        height, width, colourspace, _ = simplejpeg.decode_jpeg_header(data)
    except ValueError:
        return None
    target = _JPEG_COLOURSPACES.get(mode, {}).get(colourspace)
    if target is None:
        return None
    _check_pixels(width, height)
    pixels = np.asarray(simplejpeg.decode_jpeg(data, colorspace=target))
    return pixels[..., 0] if target == "GRAY" else pixels


def _pil_array(im: Image.Image) -> np.ndarray:
    """An "L" or "RGB" image's pixels as numpy, zero-copy through Pillow's Arrow export.

    (``np.asarray(im)`` copies the pixels through ``tobytes``; asking PIL for float32 is
    slower still.) Falls back to ``np.asarray`` on Pillow without Arrow support.
    """
    if im.mode in ("L", "RGB") and hasattr(im, "__arrow_c_array__"):
        try:
            im.load()
            arr = pa.array(im)
            if im.mode == "L":
                return np.asarray(arr.to_numpy(zero_copy_only=True).reshape(im.height, im.width))
            pixels = arr.values.to_numpy(zero_copy_only=True)  # RGBX, 4 bytes a pixel
            return np.asarray(pixels.reshape(im.height, im.width, 4)[..., :3])
        except (ValueError, TypeError, pa.ArrowException):
            pass
    return np.asarray(im)


def _decode_npy(data: bytes | bytearray) -> np.ndarray:
    """A .npy array; zero-copy (and writable) over a ``bytearray``."""
    head = bytes(data[:12])
    if head[:6] != b"\x93NUMPY" or head[6] not in (1, 2):
        return np.asarray(np.load(io.BytesIO(data), allow_pickle=False))  # numpy names the fault
    if head[6] == 1:
        end = 10 + int.from_bytes(head[8:10], "little")
    else:
        end = 12 + int.from_bytes(head[8:12], "little")
    shape, fortran, dtype = _npy_header(bytes(data[:end]))
    count = int(np.prod(shape, dtype=np.int64))
    arr = np.frombuffer(data, dtype=dtype, count=count, offset=end)
    arr = arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)
    return arr if arr.flags.writeable else arr.copy()


@lru_cache(maxsize=256)
def _npy_header(header: bytes) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran order, dtype) of a .npy header, parsed by numpy once per distinct
    header (numpy evaluates the header's dict literal, which costs about as much as reading
    the DEM chip it describes)."""
    buf = io.BytesIO(header)
    version = np.lib.format.read_magic(buf)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(buf)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(buf)
    if dtype.hasobject:
        raise ValueError("object arrays are not allowed")
    return tuple(shape), bool(fortran), dtype


def decode_raw(
    field: str,
    data: bytes | bytearray,
    ground_size: tuple[int, int] | None = None,
    normalize_dem: bool = False,
) -> np.ndarray:
    """Stage 1: a member's compact array (uint8 images, channels last; float32 DEM / corr)."""
    if field == "ground":
        return _image_u8(data, "RGB", ground_size)
    if field in ("ortho", "viewshed"):
        return _image_u8(data, "L")
    if field == "dem":
        dem = _decode_npy(data).astype(np.float32, copy=False) if is_npy(data) else decode_dem(data)
        if normalize_dem:
            finite = np.isfinite(dem)
            centre = float(np.median(dem[finite])) if finite.any() else 0.0
            dem = np.where(finite, dem - centre, np.float32(0.0)).astype(np.float32)
        return dem
    if field == "ground_px":
        return _decode_npy(data) if is_npy(data) else decode_float_tiff(data)
    if field in DENSE_FIELDS and is_tiff(data):  # format version 3 on
        return _dense_tiff(field, data)
    if field in ("corr", "range", "depth", "dem_view"):
        return _decode_npy(data).astype(np.float32, copy=False)
    if field == "hits":  # float64: map coordinates in the millions
        return _decode_npy(data).astype(np.float64, copy=False)
    if field == "ground_on_map":
        return _image_u8(data, "RGB")
    if field in ("ortho_view", "view_valid", "ground_on_map_cover", *LABEL_FIELDS):
        return _image_u8(data, "L")
    raise ArgumentError(f"unknown field {field!r}; expected one of {list(KNOWN_FIELDS)}")


#: the stage-1 dtype of each dense field a TIFF holds (``store.dense_codec.CODECS``)
_DENSE_DTYPES = {"hits": np.dtype(np.float64), "range": np.dtype(np.float32),
                 "depth": np.dtype(np.float32), "dem_view": np.dtype(np.float32)}  # fmt: skip


def _dense_tiff(field: str, data: bytes | bytearray) -> np.ndarray:
    """A dense member's TIFF (``store.dense_codec``) as its stage-1 array: uint8 images and
    masks (``ground_on_map`` RGB, a grey one's value repeated, as from its PNG), float32
    grids, float64 ``hits``; ValueError for a TIFF of another pixel type or over
    MAX_MEMBER_PIXELS pixels."""
    pixels = decode_dense(data, MAX_MEMBER_PIXELS)
    want = _DENSE_DTYPES.get(field, np.dtype(np.uint8))
    if pixels.dtype != want:
        raise ValueError(f"{field} TIFF: {pixels.dtype} pixels, expected {want}")
    if field == "ground_on_map" and pixels.ndim == 2:
        return np.repeat(pixels[..., None], 3, axis=2)
    return pixels


def chw_shape(raw: np.ndarray) -> tuple[int, int, int]:
    """The [C, H, W] shape of a stage-1 array."""
    return (1, *raw.shape) if raw.ndim == 2 else (raw.shape[2], raw.shape[0], raw.shape[1])


TORCH_DTYPES = {
    np.dtype(np.uint8): torch.uint8,
    np.dtype(np.float32): torch.float32,
    np.dtype(np.float64): torch.float64,
}


def out_dtype(field: str, image_dtype: torch.dtype) -> np.dtype:
    """The numpy dtype of a field's tensor: ``image_dtype`` for images, float64 for ``hits``
    (map coordinates), else float32."""
    if field == "hits":
        return np.dtype(np.float64)
    if field in LABEL_FIELDS:
        return np.dtype(np.uint8)
    if field in IMAGE_FIELDS and image_dtype == torch.uint8:
        return np.dtype(np.uint8)
    if image_dtype not in (torch.float32, torch.uint8):
        raise ArgumentError(
            f"image_dtype: expected torch.uint8 or torch.float32, got {image_dtype}"
        )
    return np.dtype(np.float32)


def finish_chw(field: str, raw: np.ndarray, out: np.ndarray) -> None:
    """Stage 2: write the [C, H, W] tensor of a stage-1 array into ``out``, in one pass.

    float32 ``out``: images in [0, 1], viewshed {0, 1}; uint8 ``out`` (images only): images
    as they are (0..255), viewshed {0, 1}.

    (numpy, not torch: torch's strided uint8 -> float copy is several times slower here and
    spawns intra-op threads in the main process.)
    """
    chw = raw[None] if raw.ndim == 2 else raw.transpose(2, 0, 1)
    if field in ("ground", "ortho", "ortho_view", "ground_on_map") and out.dtype != np.uint8:
        # transposing uint8 then dividing contiguously beats one strided divide
        np.divide(np.ascontiguousarray(chw), np.float32(255.0), out=out)
    elif field in MASK_FIELDS:
        np.greater(chw, 127, out=out, casting="unsafe")
    else:
        np.copyto(out, chw, casting="same_kind")


def decode_member(
    field: str,
    data: bytes | bytearray,
    *,
    ground_size: tuple[int, int] | None = None,
    normalize_dem: bool = False,
    image_dtype: torch.dtype = torch.uint8,
) -> Any:
    """Decode one member's bytes into its tensor (or dict, for ``meta``)."""
    if field == "meta":
        return json.loads(data)
    raw = decode_raw(field, data, ground_size, normalize_dem)
    out = np.empty(chw_shape(raw), dtype=out_dtype(field, image_dtype))
    finish_chw(field, raw, out)
    return torch.from_numpy(out)
