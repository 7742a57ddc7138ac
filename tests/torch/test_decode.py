"""JPEG members decode through simplejpeg to exactly Pillow's pixels (RGB and grey, resized,
the real archive's JPEGs); JPEGs simplejpeg would convert otherwise go to Pillow."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import simplejpeg
from PIL import Image

import mars_pairs.torch.decode as decode
from mars_pairs.torch.decode import decode_raw

SAMPLES = Path("/work/shared/pds-samples")


def pillow(data: bytes, mode: str, size: tuple[int, int] | None = None) -> np.ndarray:
    """The independent reference: Pillow's decode, conversion and bilinear resize."""
    with Image.open(io.BytesIO(data)) as im:
        im = im.convert(mode)
        if size is not None:
            im = im.resize((size[1], size[0]), Image.Resampling.BILINEAR)
        return np.asarray(im)


def jpeg(data: bytes, mode: str) -> bytes:
    """``data`` re-encoded by Pillow as a JPEG in ``mode``."""
    buf = io.BytesIO()
    Image.open(io.BytesIO(data)).convert(mode).save(buf, "JPEG", quality=90)
    return buf.getvalue()


@pytest.fixture
def simplejpeg_calls(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The colourspaces simplejpeg was asked to decode to."""
    calls: list[str] = []
    real = simplejpeg.decode_jpeg

    def counted(data: Any, colorspace: str = "rgb", **kwargs: Any) -> Any:
        calls.append(colorspace)
        return real(data, colorspace=colorspace, **kwargs)

    monkeypatch.setattr(decode.simplejpeg, "decode_jpeg", counted)
    return calls


def ground_jpegs(members: dict[str, bytes]) -> dict[str, bytes]:
    found = {name: data for name, data in members.items() if name.endswith(".jpg")}
    assert found, "the built dataset has no JPEG ground member"
    return found


def test_ground_members_decode_to_pillows_pixels(
    members: dict[str, bytes], simplejpeg_calls: list[str]
) -> None:
    grounds = ground_jpegs(members)
    for name, data in grounds.items():
        ours = decode_raw("ground", data)
        assert ours.dtype == np.uint8 and ours.shape[2] == 3, name
        np.testing.assert_array_equal(ours, pillow(data, "RGB"), err_msg=name)
    assert len(simplejpeg_calls) == len(grounds)  # every one through simplejpeg


def test_resized_ground_is_pillows_resize(members: dict[str, bytes]) -> None:
    for name, data in list(ground_jpegs(members).items())[:3]:
        for size in ((100, 130), (257, 190)):
            ours = decode_raw("ground", data, ground_size=size)
            np.testing.assert_array_equal(ours, pillow(data, "RGB", size), err_msg=name)


def test_grey_jpegs_as_rgb_and_grey(members: dict[str, bytes], simplejpeg_calls: list[str]) -> None:
    data = jpeg(next(iter(ground_jpegs(members).values())), "L")
    np.testing.assert_array_equal(decode_raw("ground", data), pillow(data, "RGB"))
    grey = decode_raw("ortho", data)  # an "L" field stored as a JPEG
    assert grey.ndim == 2
    np.testing.assert_array_equal(grey, pillow(data, "L"))
    assert simplejpeg_calls == ["RGB", "GRAY"]


def test_jpegs_simplejpeg_would_convert_otherwise_go_to_pillow(
    members: dict[str, bytes], simplejpeg_calls: list[str]
) -> None:
    colour = next(iter(ground_jpegs(members).values()))
    # colour read as grey: Pillow's luma, not libjpeg's Y
    np.testing.assert_array_equal(decode_raw("ortho", colour), pillow(colour, "L"))
    cmyk = jpeg(colour, "CMYK")
    np.testing.assert_array_equal(decode_raw("ground", cmyk), pillow(cmyk, "RGB"))
    assert simplejpeg_calls == []


def test_a_jpeg_over_the_pixel_limit_is_refused_before_decoding(
    members: dict[str, bytes], monkeypatch: pytest.MonkeyPatch, simplejpeg_calls: list[str]
) -> None:
    data = next(iter(ground_jpegs(members).values()))
    monkeypatch.setattr(decode, "MAX_MEMBER_PIXELS", 100)
    with pytest.raises(ValueError, match="over the limit of 100 pixels"):
        decode_raw("ground", data)
    assert simplejpeg_calls == []


def test_a_truncated_jpeg_is_a_value_error(members: dict[str, bytes]) -> None:
    data = next(iter(ground_jpegs(members).values()))
    with pytest.raises((ValueError, OSError)):
        decode_raw("ground", data[: len(data) // 2])


def test_real_archive_jpegs_decode_to_pillows_pixels() -> None:
    files = sorted(SAMPLES.glob("*/*.jpg"))[:6]
    if not files:
        pytest.skip(f"no real JPEGs under {SAMPLES}")
    for path in files:
        data = path.read_bytes()
        np.testing.assert_array_equal(decode_raw("ground", data), pillow(data, "RGB"), str(path))
