"""The dense members' files (``store.dense_codec``): lossless one-strip zstd TIFFs that GDAL
reads as written, and the readers of the datasets before them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mars_pairs.store.dense_codec import (
    CODECS,
    V2_MEMBERS,
    decode_dense,
    dense_member,
    encode_dense,
    version_suffixes,
)
from mars_pairs.store.float_tiff import encode_float_tiff
from mars_pairs.store.members import DENSE_FIELDS, MEMBER_FILES
from mars_pairs.store.strip_tiff import FLOAT_PREDICTOR, read_strip_tiff, write_strip_tiff
from mars_pairs.torch.decode import MEMBER_SUFFIXES, decode_member, decode_raw
from support.members import tiff_array


def _array(field: str, rng: np.random.Generator) -> np.ndarray:
    """A dense field's array as the build makes it: NaN runs in the float grids (sky, no
    hit), 0/255 masks, sparse colours."""
    shape = {"hits": (23, 31, 3), "ground_px": (64, 64, 2), "ground_on_map": (64, 64, 3)}
    dtype = np.dtype(CODECS[field].dtype)
    size = shape.get(field, (23, 31) if field not in ("ground_on_map_cover",) else (64, 64))
    if dtype.kind == "f":
        values = rng.normal(4.4e6 if field == "hits" else 300.0, 50.0, size=size).astype(dtype)
        values[:5] = np.nan  # the sky
        values[7, 3:9] = np.nan
        return values
    if field in ("view_valid", "ground_on_map_cover"):
        return (rng.random(size) > 0.7).astype(np.uint8) * np.uint8(255)
    return rng.integers(0, 256, size=size, dtype=np.uint8)


@pytest.mark.parametrize("field", list(CODECS))
def test_every_dense_field_round_trips_bit_for_bit_and_gdal_reads_it(field: str) -> None:
    values = _array(field, np.random.default_rng(7))
    data = encode_dense(field, values)
    back = decode_dense(data)
    assert back.dtype == values.dtype and back.shape == values.shape and back.flags.writeable
    assert back.tobytes() == values.tobytes()  # the NaN bits too
    gdal = tiff_array(data)
    assert gdal.dtype == values.dtype and np.ascontiguousarray(gdal).tobytes() == values.tobytes()


def test_every_dense_file_is_a_tif_member_the_datasets_name() -> None:
    assert set(CODECS) == set(DENSE_FIELDS)
    files = {f for names in MEMBER_FILES.values() for f in names}
    assert (
        files
        == {dense_member(f) for f in DENSE_FIELDS}
        == {MEMBER_SUFFIXES[f] for f in DENSE_FIELDS}
    )
    with pytest.raises(ValueError, match="not a dense field"):
        dense_member("ortho")


def test_ground_px_is_the_file_float_tiff_writes() -> None:
    values = _array("ground_px", np.random.default_rng(3))
    assert encode_dense("ground_px", values) == encode_float_tiff(values)


def test_the_float_grids_take_the_floating_point_predictor() -> None:
    """Predictor 3 halves a smooth float grid against none (the same pixels either way)."""
    rows, cols = np.mgrid[0:75, 0:103]
    smooth = (100.0 + 0.37 * rows + 0.11 * cols).astype(np.float32)
    plain = write_strip_tiff(smooth, predictor=1, level=1, texts={})
    predicted = encode_dense("range", smooth)
    assert len(predicted) < 0.75 * len(plain)
    assert CODECS["range"].predictor == FLOAT_PREDICTOR
    assert read_strip_tiff(predicted)[0].tobytes() == smooth.tobytes()


@pytest.mark.parametrize("field", list(CODECS))
def test_the_torch_decoder_reads_each_file_as_its_format_2_member(field: str) -> None:
    """decode_member of a .tif gives the tensor the format 2 member (.npy, .png) gives."""
    import io

    from PIL import Image

    values = _array(field, np.random.default_rng(11))
    new = decode_member(field, encode_dense(field, values), image_dtype=torch.float32)
    if field in V2_MEMBERS and V2_MEMBERS[field].endswith(".png"):
        buf = io.BytesIO()
        Image.fromarray(values).save(buf, format="PNG")
        old_bytes = buf.getvalue()
    elif field in V2_MEMBERS:
        buf = io.BytesIO()
        np.save(buf, values, allow_pickle=False)
        old_bytes = buf.getvalue()
    else:  # ground_px: the same .tif in format 2
        old_bytes = encode_dense(field, values)
    old = decode_member(field, old_bytes, image_dtype=torch.float32)
    assert new.dtype == old.dtype and new.shape == old.shape
    assert torch.equal(new.nan_to_num(-7.0), old.nan_to_num(-7.0))


def test_a_grey_ground_on_map_reads_as_rgb_as_its_png_did() -> None:
    grey = np.random.default_rng(5).integers(0, 256, size=(16, 16), dtype=np.uint8)
    raw = decode_raw("ground_on_map", encode_dense("ground_on_map", grey))
    assert raw.shape == (16, 16, 3) and all(np.array_equal(raw[..., k], grey) for k in range(3))


def test_bytes_that_are_no_dense_file_are_a_value_error() -> None:
    data = encode_dense("range", _array("range", np.random.default_rng(1)))
    with pytest.raises(ValueError):
        decode_dense(data[:-40])  # a truncated strip
    with pytest.raises(ValueError, match="over the limit"):
        decode_dense(data, max_pixels=100)
    with pytest.raises(ValueError, match="expected float64"):
        decode_raw("hits", data)  # float32 pixels where hits are float64


def test_older_versions_name_their_own_members() -> None:
    assert version_suffixes(3) == {}
    v2 = version_suffixes(2)
    assert v2["range"] == "range.npy" and v2["ground_on_map"] == "ground_on_map.png"
    assert "ground_px" not in v2 and "dem" not in v2  # both .tif in format 2
    v1 = version_suffixes(1)
    assert v1["ground_px"] == "ground_px.npy" and v1["dem"] == "dem.npy"
    assert v1["hits"] == "hits.npy"
