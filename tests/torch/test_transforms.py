"""Transforms keep the pairing: each one checked against the untransformed sample.

For every transform: the keypoints' map points are unchanged (chip transform composed with
the pixel map); the ground image sampled at the moved ground keypoints gives the old values,
and the chips sampled at the moved chip keypoints give the old values (exactly for flips,
crops and quarter turns); the chips agree with the orbital rasters read by rasterio through
the new transform (independent truth); bounds and rotation follow the transform. A broken
transform (an image moved without its keypoints) fails the same checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
import torch

from mars_pairs.errors import ArgumentError, MarsPairsError
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset
from mars_pairs.torch.transforms import (
    ColorJitter,
    Compose,
    Crop,
    Flip,
    NorthUp,
    RandomCrop,
    RandomFlip,
    RandomRotate,
    Resize,
    Rotate,
    ToFloat,
    keypoints,
)

Sample = dict[str, Any]


def bilinear(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """img [H, W] sampled at xy [N, 2] (pixel-edge coordinates), NaN outside the centres."""
    h, w = img.shape
    x, y = np.nan_to_num(xy[:, 0] - 0.5, nan=-9.0), np.nan_to_num(xy[:, 1] - 0.5, nan=-9.0)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    out = np.full(len(xy), np.nan)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    x0, y0, fx, fy = x0[ok], y0[ok], fx[ok], fy[ok]
    out[ok] = (
        img[y0, x0] * (1 - fx) * (1 - fy)
        + img[y0, x0 + 1] * fx * (1 - fy)
        + img[y0 + 1, x0] * (1 - fx) * fy
        + img[y0 + 1, x0 + 1] * fx * fy
    )
    return out


def nearest(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h, w = img.shape
    xy = np.nan_to_num(xy, nan=-9.0)
    c, r = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
    out = np.full(len(xy), np.nan)
    ok = (c >= 0) & (r >= 0) & (c < w) & (r < h)
    out[ok] = img[r[ok], c[ok]]
    return out


def to_map(transform: torch.Tensor, pts: np.ndarray) -> np.ndarray:
    a, b, c, d, e, f = transform.numpy()
    return np.stack([a * pts[:, 0] + b * pts[:, 1] + c, d * pts[:, 0] + e * pts[:, 1] + f], 1)


def inverse(transform: torch.Tensor) -> torch.Tensor:
    a, b, c, d, e, f = transform.tolist()
    det = a * e - b * d
    t = (e / det, -b / det, (b * f - c * e) / det, -d / det, a / det, (c * d - a * f) / det)
    return torch.tensor(t, dtype=torch.float64)


def grid_points(sample: Sample, key: str) -> np.ndarray:
    """Every keypoint cell (N, 2) of ``corr`` or ``corr_ground``, NaN where no hit."""
    return sample[key].reshape(2, -1).T.double().numpy()


@pytest.fixture(scope="module")
def samples(dataset_dir: Path) -> list[Sample]:
    with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as ds:
        return [ds[i] for i in range(0, len(ds), 2)]


@pytest.fixture(scope="module")
def rasters(mission_dir: Path) -> dict[str, Any]:
    out = {n: rasterio.open(mission_dir / "orbital" / f"{n}.tif") for n in ("ortho", "dem")}
    yield out
    for src in out.values():
        src.close()


def raster_truth(src: Any, sample: Sample, step: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The raster sampled (rasterio, nearest) at the map points of every ``step``-th chip pixel
    centre under the sample's transform; and those pixels' (row, column) indices."""
    h, w = sample["ortho"].shape[-2:]
    rows, cols = np.meshgrid(np.arange(0, h, step), np.arange(0, w, step), indexing="ij")
    centres = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], 1)
    xy = to_map(sample["transform"], centres)
    values = np.array([v[0] for v in src.sample(xy)], dtype=np.float64)
    if src.nodata is not None:
        values[values == src.nodata] = np.nan
    return values, np.stack([rows.ravel(), cols.ravel()], 1)


def check_pairing(
    before: Sample, after: Sample, exact: bool, rasters: dict[str, Any] | None = None
) -> None:
    """The checks of the module docstring for one transformed sample."""
    # 1. every keypoint names the same map point
    old_map = to_map(before["transform"], grid_points(before, "corr"))
    new_map = to_map(after["transform"], grid_points(after, "corr"))
    hit = np.isfinite(old_map).all(1)
    assert hit.sum() > 50
    np.testing.assert_array_equal(np.isfinite(new_map).all(1), hit)
    np.testing.assert_allclose(new_map[hit], old_map[hit], atol=1e-3)  # map units (metres)
    # 2. the same ground values at the moved ground keypoints
    old_g, new_g = grid_points(before, "corr_ground"), grid_points(after, "corr_ground")
    for ch in range(3):
        a = bilinear(before["ground"][ch].double().numpy(), old_g)
        b = bilinear(after["ground"][ch].double().numpy(), new_g)
        both = np.isfinite(a) & np.isfinite(b)
        assert both.sum() > 50
        if exact:
            np.testing.assert_array_equal(a[both], b[both])
        else:  # resampled twice (the transform, then here): a little blur, no shift (a few
            # points by a rotated image's filled corners differ more)
            error = np.abs(a[both] - b[both])
            assert np.median(error) <= 2.0 and np.percentile(error, 90) <= 3.0, ch
    # 3. the same chip values at the moved chip keypoints
    old_c, new_c = grid_points(before, "corr"), grid_points(after, "corr")
    for name, tolerance in (("ortho", 8.0), ("dem", 0.25)):
        a = bilinear(before[name][0].double().numpy(), old_c)
        b = bilinear(after[name][0].double().numpy(), new_c)
        both = np.isfinite(a) & np.isfinite(b)
        assert both.sum() > 50
        if exact:
            # (float32 keypoints: x' = w - x rounds in the last bits)
            np.testing.assert_allclose(a[both], b[both], rtol=0, atol=1e-3)
        else:
            assert np.median(np.abs(a[both] - b[both])) < tolerance, name
    v_old = nearest(before["viewshed"][0].numpy(), old_c)
    v_new = nearest(after["viewshed"][0].numpy(), new_c)
    both = np.isfinite(v_old) & np.isfinite(v_new)
    if exact:
        np.testing.assert_array_equal(v_old[both], v_new[both])
    elif (before["viewshed"][0].numpy() > 0).sum() >= 50:
        # every visible pixel of the new mask lies on (or next to) a visible old pixel (a
        # view of a few pixels, a zoom looking down, may vanish when a chip shrinks)
        rows, cols = np.nonzero(after["viewshed"][0].numpy())
        assert len(rows) > 0
        xy = to_map(after["transform"], np.stack([cols + 0.5, rows + 0.5], 1))
        old_px = to_map(inverse(before["transform"]), xy)
        mask = before["viewshed"][0].numpy() > 0
        grown = mask.copy()  # dilated by one pixel (nearest resampling moves edges by one)
        for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
            grown |= np.roll(mask, (dr, dc), axis=(0, 1))
        assert np.nanmean(nearest(grown.astype(float), old_px)) > 0.97
    # 4. bounds and rotation follow the transform
    h, w = after["ortho"].shape[-2:]
    corners = to_map(after["transform"], np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
    expected = [*corners.min(0), *corners.max(0)]
    np.testing.assert_allclose(after["bounds"].numpy(), expected, atol=1e-6)
    _, b, _, _, e, _ = after["transform"].numpy()  # up (-row) is (-b, -e) on the map
    rotation = math.radians(float(after["rotation"]))
    assert math.isclose(math.sin(rotation), -b / math.hypot(b, e), abs_tol=1e-9)
    assert math.isclose(math.cos(rotation), -e / math.hypot(b, e), abs_tol=1e-9)
    # 5. the chips are the orbital rasters seen through the new transform
    if rasters is not None:
        truth, rc = raster_truth(rasters["ortho"], after)
        chip = after["ortho"][0].double().numpy()[rc[:, 0], rc[:, 1]]
        inside = np.isfinite(truth) & (chip > 0)
        assert inside.sum() > 100
        assert np.corrcoef(truth[inside], chip[inside])[0, 1] > 0.85
        truth, rc = raster_truth(rasters["dem"], after)
        dem = after["dem"][0].double().numpy()[rc[:, 0], rc[:, 1]]
        inside = np.isfinite(truth) & np.isfinite(dem)
        assert np.median(np.abs(truth[inside] - dem[inside])) < 0.3  # metres


EXACT: dict[str, Callable[[Sample], Sample]] = {
    "flip ground left-right": Flip("horizontal", "ground"),
    "flip ground top-bottom": Flip("vertical", "ground"),
    "flip chip left-right": Flip("horizontal", "chip"),
    "flip chip top-bottom": Flip("vertical", "chip"),
    "crop ground": Crop(40, 100, 300, 500, target="ground"),
    "crop chip": Crop(10, 20, 100, 90, target="chip"),
    "rotate chip 90": Rotate(90, target="chip"),
    "rotate chip -90": Rotate(-90, target="chip"),
    "rotate chip 180": Rotate(180, target="chip"),
    "rotate ground 90": Rotate(90, target="ground"),
    "flip both": Flip("horizontal", "both"),
}


RESAMPLED: dict[str, Callable[[Sample], Sample]] = {
    "resize ground": Resize(ground=(300, 412)),
    "resize chip": Resize(chip=96),
    "resize chip up": Resize(chip=(160, 200)),
    "rotate chip 30": Rotate(30, target="chip"),
    "rotate chip -115": Rotate(-115, target="chip"),
    "rotate ground 12": Rotate(12, target="ground"),
    "a training pipeline": Compose(
        [
            Resize(ground=(240, 330), chip=112),
            Rotate(25, target="chip"),
            Flip("horizontal", "ground"),
            Crop(8, 8, 96, 96, target="chip"),
        ]
    ),
}


@pytest.mark.parametrize("name", sorted(EXACT))
def test_exact_transforms_keep_the_pairing(
    name: str, samples: list[Sample], rasters: dict[str, Any]
) -> None:
    for s in samples:
        copy = {k: v.clone() for k, v in s.items() if isinstance(v, torch.Tensor)}
        t = EXACT[name](s)
        check_pairing(s, t, exact=True, rasters=rasters if "chip" in name else None)
        assert t["ground"].dtype == s["ground"].dtype == torch.uint8
        for k, v in copy.items():  # the input is not changed
            assert torch.equal(s[k].nan_to_num(-1), v.nan_to_num(-1)), k


@pytest.mark.parametrize("name", sorted(RESAMPLED))
def test_resampling_transforms_keep_the_pairing(
    name: str, samples: list[Sample], rasters: dict[str, Any]
) -> None:
    for s in samples:
        check_pairing(s, RESAMPLED[name](s), exact=False, rasters=rasters)


def test_a_transform_that_forgets_the_keypoints_fails_the_checks(samples: list[Sample]) -> None:
    s = samples[1]
    broken = dict(s, ground=torch.flip(s["ground"], dims=(-1,)))  # image moved, keypoints not
    with pytest.raises(AssertionError):
        check_pairing(s, broken, exact=True)
    broken = dict(s, ortho=torch.rot90(s["ortho"], 1, dims=(-2, -1)))
    with pytest.raises(AssertionError):
        check_pairing(s, broken, exact=True)
    turned = Rotate(20)(s)  # chips turned, keypoints and transform left behind
    broken = dict(s, **{k: turned[k] for k in ("ortho", "dem", "viewshed")})
    with pytest.raises(AssertionError):
        check_pairing(s, broken, exact=False)
    shrunk = Resize(ground=(300, 412))(s)  # ground resized, its keypoints left behind
    with pytest.raises(AssertionError):
        check_pairing(s, dict(shrunk, corr_ground=s["corr_ground"]), exact=False)


def test_rotation_sets_the_chip_rotation_and_north_up_undoes_it(
    samples: list[Sample], rasters: dict[str, Any]
) -> None:
    s = samples[0]
    assert float(s["rotation"]) == 0.0
    for degrees in (30.0, 90.0, -45.0):
        t = Rotate(degrees)(s)
        assert float(t["rotation"]) == pytest.approx(degrees % 360.0, abs=1e-9)
        back = NorthUp()(t)
        assert float(back["rotation"]) == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(back["transform"].numpy(), s["transform"].numpy(), atol=1e-6)
        check_pairing(s, back, exact=degrees % 90 == 0, rasters=rasters)


def test_heading_up_chips_turn_north_up(heading_up_dir: Path, rasters: dict[str, Any]) -> None:
    with MarsPairsDataset(heading_up_dir, fields=ALL_FIELDS) as ds:
        for i in range(0, len(ds), 3):
            s = ds[i]
            assert float(s["rotation"]) == pytest.approx(s["meta"]["azimuth_deg"] % 360, abs=1.0)
            t = NorthUp()(s)
            a, b, _, d, e, _ = t["transform"].numpy()
            assert abs(b) < 1e-9 and abs(d) < 1e-9 and a > 0 and e < 0
            check_pairing(s, t, exact=False, rasters=rasters)


def test_colour_jitter_changes_values_only(samples: list[Sample]) -> None:
    s = samples[2]
    t = ColorJitter(0.3, 0.3, 0.3, generator=torch.Generator().manual_seed(1))(s)
    assert t["ground"].dtype == torch.uint8 and t["ground"].shape == s["ground"].shape
    assert not torch.equal(t["ground"], s["ground"])
    for key in ("ortho", "dem", "viewshed", "corr", "corr_ground", "transform", "bounds"):
        assert torch.equal(t[key], s[key]), key
    check_pairing(s, dict(t, ground=s["ground"]), exact=True)


def test_to_float_is_the_float_dataset(dataset_dir: Path, samples: list[Sample]) -> None:
    with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS, image_dtype=torch.float32) as ds:
        floats = ds[0]
    t = ToFloat()(samples[0])
    for name in ALL_FIELDS:
        assert t[name].dtype == torch.float32 and torch.equal(t[name], floats[name]), name
    assert torch.equal(ToFloat()(t)["ground"], t["ground"])  # float input stays


def test_random_transforms_are_reproducible_and_keep_the_pairing(
    samples: list[Sample],
) -> None:
    def pipeline(seed: int) -> Compose:
        gen = torch.Generator().manual_seed(seed)
        return Compose(
            [
                RandomFlip(0.5, "horizontal", "ground", generator=gen),
                RandomRotate((-40, 40), target="chip", generator=gen),
                RandomRotate(target="ground", quarter_turns=True, generator=gen),
                RandomCrop(100, target="chip", generator=gen),
                ColorJitter(generator=gen),
            ]
        )

    s = samples[3]
    a, b, c = pipeline(0)(s), pipeline(0)(s), pipeline(1)(s)
    for k in ("ground", "ortho", "dem", "corr", "corr_ground", "transform"):
        assert torch.equal(a[k].nan_to_num(-1), b[k].nan_to_num(-1)), k
    assert not torch.equal(a["transform"], c["transform"])
    undone = dict(a)
    undone["ground"] = Compose(pipeline(0).transforms[:3])(s)["ground"]  # no colour jitter
    check_pairing(s, undone, exact=False)


def test_keypoints_inside_both_images(samples: list[Sample]) -> None:
    t = Crop(100, 200, 200, 300, target="ground")(samples[0])
    ground, chip = keypoints(t)
    assert len(ground) == len(chip) > 10
    assert (ground[:, 0] >= 0).all() and (ground[:, 0] <= 300).all()
    assert (ground[:, 1] >= 0).all() and (ground[:, 1] <= 200).all()
    everything, _ = keypoints(t, inside=False)
    assert len(everything) > len(ground)


def test_bad_transform_arguments_are_argument_errors(samples: list[Sample]) -> None:
    s = samples[0]
    with pytest.raises(ArgumentError, match="does not fit"):
        Crop(0, 0, 10_000, 10, target="chip")(s)
    with pytest.raises(ArgumentError, match="target"):
        Flip("horizontal", target="map")
    with pytest.raises(ArgumentError, match="axis"):
        Flip("diagonal")
    no_ground = {k: v for k, v in s.items() if k != "ground"}
    with pytest.raises(MarsPairsError, match="needs the ground field"):
        Resize(ground=64)(no_ground)
    with pytest.raises(ValueError):  # ArgumentError is a ValueError too
        Resize(chip=0)
