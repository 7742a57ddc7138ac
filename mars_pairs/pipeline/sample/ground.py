"""The ground image member, decoded and checked against the label before it enters a shard.

- JPEG / PNG (browse products): the original bytes, after a full decode with Pillow (a
  truncated or corrupted file fails here, naming the file; truncated images are never
  accepted). IMG products (PDS3 detached or attached label, PDS4): the array read with pdr,
  chosen by type (the image-like array of the product, whatever the label names it), 16-bit or
  float data stretched to 8 bits (the stretch recorded), then encoded.
- The decoded size is checked against the label's LINE_SAMPLES x LINES (PDS4: the array's
  Sample and Line axes). A uniformly resized image (a browse JPEG at 1/2 or 1/4) gets the
  label's camera re-expressed for its pixel grid (``CameraModel.scaled``) and the scale
  recorded; any other mismatch is an ImageError naming both sizes.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from PIL import Image, ImageFile

from mars_pairs.errors import ImageError
from mars_pairs.observation import Observation

#: Browse images smaller than this fraction of the label's grid are refused.
MIN_SCALE = 1.0 / 32.0
#: Percentiles of the 8-bit stretch of 16-bit and float images.
STRETCH_PERCENTILES = (0.5, 99.5)
_BROWSE = {".jpg": "ground.jpg", ".jpeg": "ground.jpg", ".png": "ground.png"}


@dataclass(frozen=True)
class GroundImage:
    """The ground member and what it did to the observation.

    ``observation`` is the input one, with camera, width and height re-expressed for the
    image's own pixel grid when the image is a resized copy of the product.
    """

    name: str
    data: bytes
    size: tuple[int, int]  # (width, height) pixels of the member
    observation: Observation
    meta: dict[str, Any] = field(default_factory=dict)
    #: when asked for: uint8 (H, W), (H, W, 3), or (H, W, 4) whose 4th band is padding (a
    #: browse image's RGB pixels as Pillow holds them, RGBX, handed on without a copy)
    pixels: np.ndarray | None = None


def ground_image(obs: Observation, encoding: str, keep_pixels: bool = False) -> GroundImage:
    """The checked ground member of ``obs``; ImageError (naming the file) on any fault.
    ``keep_pixels``: also hand on the decoded pixels (``GroundImage.pixels``, the member's
    own decode) for the dense members."""
    path = obs.image_path
    if path is None or not Path(path).is_file():
        raise ImageError(f"{obs.label_path}: no image file beside the label")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in _BROWSE and path != obs.label_path:
        data = _read(path)
        kept: list[np.ndarray] = []
        size = decoded_size(data, path, kept if keep_pixels else None)
        checked, meta = fit_to_label(obs, size, path)
        pixels = kept[0] if kept else None
        return GroundImage(_BROWSE[suffix], data, size, checked, meta, pixels)
    pixels, meta = read_product_pixels(obs)
    size = (pixels.shape[1], pixels.shape[0])
    checked, scale_meta = fit_to_label(obs, size, path)
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="PNG" if encoding == "png" else "JPEG", quality=95)
    kept_pixels = pixels if keep_pixels else None
    if kept_pixels is not None and encoding != "png":  # what a reader decodes: the JPEG's
        kept_pixels = _decoded(buf.getvalue())
    return GroundImage(
        f"ground.{encoding}", buf.getvalue(), size, checked, meta | scale_meta, kept_pixels
    )


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ImageError(f"{path}: cannot read image: {exc.strerror or exc}") from exc


def _decoded(data: bytes) -> np.ndarray:
    """The pixels of an encoded image: uint8 (H, W) or (H, W, 3)."""
    with Image.open(io.BytesIO(data)) as im:
        return _as_pixels(im)


def _as_pixels(im: Image.Image) -> np.ndarray:
    if im.mode not in ("L", "RGB"):
        im = im.convert("RGB")
    return np.asarray(im)


def _kept_pixels(im: Image.Image) -> np.ndarray:
    """A decoded image's pixels without a copy where Pillow exports them (Arrow): uint8
    (H, W) for L, (H, W, 4) RGBX for RGB (the 4th band padding); else ``_as_pixels``'s
    (H, W) or (H, W, 3) copy."""
    if im.mode in ("L", "RGB") and hasattr(im, "__arrow_c_array__"):
        try:
            arr = pa.array(im)
            if im.mode == "L":
                return np.asarray(arr.to_numpy(zero_copy_only=True)).reshape(im.height, im.width)
            padded = arr.values.to_numpy(zero_copy_only=True)  # RGBX, 4 bytes a pixel
            return np.asarray(padded).reshape(im.height, im.width, 4)
        except (ValueError, TypeError, pa.ArrowException):
            pass
    return _as_pixels(im)


def decoded_size(
    data: bytes, path: Path, pixels: list[np.ndarray] | None = None
) -> tuple[int, int]:
    """(width, height) of a JPEG/PNG after decoding every pixel; ImageError if it cannot be.
    ``pixels``: a list that receives the decoded pixels (uint8 (H, W) or (H, W, 3))."""
    if ImageFile.LOAD_TRUNCATED_IMAGES:
        raise ImageError(f"{path}: PIL.ImageFile.LOAD_TRUNCATED_IMAGES is on; refusing to decode")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                im.verify()  # structure and checksums (PNG CRCs)
            with Image.open(io.BytesIO(data)) as im:
                im.load()  # every pixel: a truncated or corrupted stream fails here
                size: tuple[int, int] = im.size
                if pixels is not None:
                    pixels.append(_kept_pixels(im))
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, ... on bad data
        raise ImageError(f"{path}: corrupted or truncated image: {exc}") from exc
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise ImageError(f"{path}: corrupted or truncated image: JPEG has no end marker")
    return size


def fit_to_label(
    obs: Observation, size: tuple[int, int], path: Path
) -> tuple[Observation, dict[str, Any]]:
    """The observation for an image of ``size`` = (width, height) pixels, and the meta.

    Equal to the label's grid: unchanged. A uniform resize (both axes by the same factor, to
    the pixel): the camera scaled by (sx, sy) = (width / label width, height / label height),
    which maps pixel edges x' + 0.5 = sx (x + 0.5). Anything else: ImageError.
    """
    width, height = size
    label = (obs.width, obs.height)
    meta: dict[str, Any] = {"label_size": list(label), "image_size": [width, height]}
    if (width, height) == label:
        return obs, meta | {"image_scale": [1.0, 1.0]}
    sx, sy = width / obs.width, height / obs.height
    uniform = abs(width - round(obs.width * sy)) <= 1 and abs(height - round(obs.height * sx)) <= 1
    if not uniform or min(sx, sy) < MIN_SCALE or max(sx, sy) > 1.0:
        raise ImageError(
            f"{path}: image is {width} x {height} pixels but the label {obs.label_path.name} "
            f"says {obs.width} x {obs.height} (LINE_SAMPLES x LINES): not a uniform "
            f"downscale between 1/{round(1 / MIN_SCALE)} and 1"
        )
    scaled = replace(obs, camera=obs.camera.scaled(sx, sy), width=width, height=height)
    return scaled, meta | {"image_scale": [sx, sy]}


def read_product_pixels(obs: Observation) -> tuple[np.ndarray, dict[str, Any]]:
    """The product's image as uint8 (H, W) or (H, W, 3), read with pdr, and its meta."""
    import pdr  # only decoded products (IMG) need it

    source = obs.label_path
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = pdr.read(str(source))
            key = _image_key(data, obs)
            arr = data[key]
    except ImageError:
        raise
    except Exception as exc:  # pdr raises many types on damaged or missing data
        raise ImageError(f"{obs.image_path}: cannot read the image with pdr: {exc}") from exc
    if not isinstance(arr, np.ndarray):  # pdr gives the label block when the data is missing
        raise ImageError(f"{obs.image_path}: pdr found no image data for {key!r}")
    pixels = _bands_last(np.asarray(arr), obs)
    meta: dict[str, Any] = {"source_array": key, "source_dtype": str(arr.dtype)}
    if pixels.dtype != np.uint8:
        pixels, stretch = stretch_to_uint8(pixels, obs)
        meta["stretch"] = stretch
    return pixels, meta


def _image_key(data: Any, obs: Observation) -> str:
    """The product's image array: the array-typed object whose shape matches the label best."""
    candidates: list[str] = []
    keys = data.keys()  # pdr.Data: the product's objects, data or not
    for key in keys:
        if key.lower() == "label":
            continue
        try:
            kind = data.type_of(key)
        except Exception:  # a missing data file: no candidate
            continue
        if kind is np.ndarray:
            candidates.append(key)
    if not candidates:
        raise ImageError(f"{obs.image_path}: the product holds no image array")
    if len(candidates) == 1:
        return candidates[0]
    for key in candidates:
        shape = np.shape(data[key])
        if {obs.height, obs.width} <= set(shape):
            return key
    return candidates[-1]


def _bands_last(arr: np.ndarray, obs: Observation) -> np.ndarray:
    """(H, W) or (H, W, 3): a band-first (B, H, W) array turned; other band counts refused."""
    arr = np.squeeze(arr)
    if arr.ndim == 3 and arr.shape[0] in (1, 3) and arr.shape[-1] not in (1, 3):
        arr = np.moveaxis(arr, 0, -1)
    arr = np.squeeze(arr) if arr.ndim == 3 and arr.shape[-1] == 1 else arr
    if arr.ndim == 2 or (arr.ndim == 3 and arr.shape[-1] == 3):
        return np.ascontiguousarray(arr)
    raise ImageError(f"{obs.image_path}: image array of shape {arr.shape}: not 1 or 3 bands")


def stretch_to_uint8(arr: np.ndarray, obs: Observation) -> tuple[np.ndarray, dict[str, Any]]:
    """A linear stretch of 16-bit / float data to 8 bits between two percentiles of its finite
    values; returns the pixels and the stretch (so a reader can invert it)."""
    values = np.asarray(arr, dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        raise ImageError(f"{obs.image_path}: image has no finite pixel values")
    lo, hi = (float(v) for v in np.percentile(values[finite], STRETCH_PERCENTILES))
    span = max(hi - lo, 1e-12)
    scaled = np.where(finite, (values - lo) / span * 255.0, 0.0)
    out = np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    stretch = {
        "method": "linear percentile",
        "percentiles": list(STRETCH_PERCENTILES),
        "low": lo,
        "high": hi,
        "source_dtype": str(arr.dtype),
        "formula": "u8 = clip(round((value - low) / (high - low) * 255), 0, 255)",
    }
    return out, stretch
