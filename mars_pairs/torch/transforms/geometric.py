"""Geometric transforms: one affine map of the ground image and/or of the chips, which moves
the keypoints and the chip georeferencing with the pixels (see the package docstring)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from mars_pairs.errors import ArgumentError
from mars_pairs.store.members import CHIP_GRID_FIELDS
from mars_pairs.torch.georef import bounds_of, rotation_of

CHIP_FIELDS = ("ortho", "dem", "viewshed")
#: Optional chip-grid members (``output.members``) that move with the chips.
_NEAREST = ("viewshed", "ground_on_map_cover", "ground_px", "terrain_on_map")  # masks, maps
_NAN_FILL = ("dem", "ground_px")
_LABEL_FILL = ("terrain_on_map",)  # classes: 255 (no label) where nothing moved in


def _chip_mode(name: str) -> str:
    return "nearest" if name in _NEAREST else "bilinear"


def _chip_fill(name: str) -> float:
    if name in _LABEL_FILL:
        return 255.0
    return math.nan if name in _NAN_FILL else 0.0


Sample = dict[str, Any]


# -- affine maps (3 x 3, float64, acting on (x, y, 1) pixel-edge coordinates) -------------------


def _translate(tx: float, ty: float) -> np.ndarray:
    return np.array([[1.0, 0.0, tx], [0.0, 1.0, ty], [0.0, 0.0, 1.0]])


def _scale(sx: float, sy: float) -> np.ndarray:
    return np.array([[sx, 0.0, 0.0], [0.0, sy, 0.0], [0.0, 0.0, 1.0]])


def _rotation_ccw(degrees: float) -> np.ndarray:
    """Turns image content ``degrees`` counterclockwise as displayed (rows down)."""
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def _move_points(points: torch.Tensor, m_inv: np.ndarray) -> torch.Tensor:
    """[2, ...] (x, y) points under the 3 x 3 map ``m_inv`` (NaN stays NaN)."""
    x, y = points[0].double(), points[1].double()
    nx = m_inv[0, 0] * x + m_inv[0, 1] * y + m_inv[0, 2]
    ny = m_inv[1, 0] * x + m_inv[1, 1] * y + m_inv[1, 2]
    return torch.stack([nx, ny]).to(points.dtype)


def _warp(
    image: torch.Tensor, m: np.ndarray, out_hw: tuple[int, int], mode: str, fill: float
) -> torch.Tensor:
    """[C, H, W] resampled so that new pixel p samples old point m @ p (pixel-edge
    coordinates); ``fill`` outside the old image. Same dtype as given (uint8 rounded)."""
    _, h, w = image.shape
    oh, ow = out_hw
    ys, xs = torch.meshgrid(
        torch.arange(oh, dtype=torch.float64) + 0.5,
        torch.arange(ow, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    sx = m[0, 0] * xs + m[0, 1] * ys + m[0, 2]
    sy = m[1, 0] * xs + m[1, 1] * ys + m[1, 2]
    grid = torch.stack([2.0 * sx / w - 1.0, 2.0 * sy / h - 1.0], dim=-1)[None].float()
    src = image.float()[None]
    out = F.grid_sample(src, grid, mode=mode, padding_mode="border", align_corners=False)[0]
    outside = (sx < 0) | (sx > w) | (sy < 0) | (sy > h)
    out[:, outside] = fill
    return like_image(out, image)


def like_image(values: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    if image.dtype == torch.uint8:
        return values.round().clamp_(0, 255).to(torch.uint8)
    return values.to(image.dtype)


def _resize(image: torch.Tensor, out_hw: tuple[int, int], mode: str) -> torch.Tensor:
    kwargs: dict[str, Any] = {"mode": mode}
    if mode == "bilinear":
        kwargs.update(align_corners=False, antialias=True)
    out = F.interpolate(image.float()[None], size=out_hw, **kwargs)[0]
    return like_image(out, image)


class _Geometric:
    """A transform made of one affine map of the ground image and/or of the chips."""

    target: str

    def _ground_map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]] | None:
        return None

    def _chip_map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]] | None:
        return None

    def _apply_ground(self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]) -> Any:
        return _warp(image, m, hw, "bilinear", 0.0)

    def _apply_chip(
        self, name: str, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]
    ) -> torch.Tensor:
        return _warp(image, m, hw, _chip_mode(name), _chip_fill(name))

    def __call__(self, sample: Sample) -> Sample:
        out = dict(sample)
        if self.target in ("ground", "both"):
            made = self._ground_map(*ground_hw(sample, "corr_ground", "dense_ground"))
            if made is not None:
                m, new_hw = made
                if "ground" in out:
                    out["ground"] = self._apply_ground(sample["ground"], m, new_hw)
                if "ground_mask" in out:  # bool: moved as 0 / 255, True where > 127
                    as_u8 = sample["ground_mask"].to(torch.uint8) * 255
                    out["ground_mask"] = self._apply_ground(as_u8, m, new_hw) > 127
                if "terrain" in out:  # classes on the ground grid: nearest, 255 outside
                    out["terrain"] = _warp(sample["terrain"], m, new_hw, "nearest", 255.0)
                for name in ("corr_ground", "dense_ground"):
                    if name in out:
                        out[name] = _move_points(sample[name], np.linalg.inv(m))
                if "ground_px" in out:  # image pixel centres (integers): edges are +0.5
                    moved = _move_points(out["ground_px"] + 0.5, np.linalg.inv(m))
                    out["ground_px"] = moved - 0.5
        if self.target in ("chip", "both"):
            made = self._chip_map(*chip_hw(sample, "corr", "transform", *LOCALIZATION_POINTS))
            if made is not None:
                m, new_hw = made
                for name in CHIP_FIELDS + CHIP_GRID_FIELDS:
                    if name in out:
                        out[name] = self._apply_chip(name, out[name], m, new_hw)
                if "corr" in out:
                    out["corr"] = _move_points(sample["corr"], np.linalg.inv(m))
                out.update(move_localization(sample, np.linalg.inv(m)))
                if "transform" in out:
                    t = sample["transform"].double().numpy()
                    affine = (np.array([t[0:3], t[3:6], [0.0, 0.0, 1.0]]) @ m)[:2].ravel()
                    out["transform"] = torch.tensor(affine, dtype=torch.float64)
                    out["bounds"] = torch.tensor(bounds_of(affine, *new_hw), dtype=torch.float64)
                    out["rotation"] = torch.tensor(rotation_of(affine), dtype=torch.float64)
        return out


LOCALIZATION_POINTS = ("rover_px", "camera_px")


def move_localization(sample: Sample, m_inv: np.ndarray) -> Sample:
    """The localization targets of ``sample`` under the chip map ``m_inv`` (old chip pixel ->
    new, pixel-edge coordinates): ``rover_px`` and ``camera_px`` ([2] column, row) move as
    points; ``heading_deg`` (clockwise from the chip's up, degrees) turns with the direction
    (sin h, -cos h) it names in chip pixels (a mirror reverses its sense)."""
    out: Sample = {}
    for name in LOCALIZATION_POINTS:
        if name in sample:
            out[name] = _move_points(torch.as_tensor(sample[name]), m_inv)
    if "heading_deg" in sample:
        h = math.radians(float(sample["heading_deg"]))
        dx, dy = m_inv[:2, :2] @ np.array([math.sin(h), -math.cos(h)])
        heading = math.degrees(math.atan2(dx, -dy)) % 360.0
        out["heading_deg"] = torch.tensor(heading, dtype=torch.float64)
    return out


def ground_hw(sample: Sample, *needing: str) -> tuple[int, int]:
    """The ground image's (H, W); ArgumentError when a field that moves with it is there
    without the image (its size is unknown)."""
    if "ground" in sample:
        return tuple(sample["ground"].shape[-2:])
    if any(k in sample for k in needing):
        raise ArgumentError(f"a ground transform needs the ground field to move {needing}")
    return (1, 1)


def chip_hw(sample: Sample, *needing: str) -> tuple[int, int]:
    """The chips' (H, W); ArgumentError when a field that moves with them is there without
    any chip."""
    for name in CHIP_FIELDS + CHIP_GRID_FIELDS:
        if name in sample:
            return tuple(sample[name].shape[-2:])
    if any(k in sample for k in needing):
        raise ArgumentError(
            f"a chip transform needs a chip field ({CHIP_FIELDS}) to move {needing}"
        )
    return (1, 1)


def check_target(target: str, allowed: Sequence[str] = ("ground", "chip", "both")) -> str:
    if target not in allowed:
        raise ArgumentError(f"target: expected one of {list(allowed)}, got {target!r}")
    return target


def size_hw(value: int | Sequence[int] | None, name: str) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        h, w = (value, value) if isinstance(value, (int, np.integer)) else value
        size = (int(h), int(w))
    except (TypeError, ValueError):
        raise ArgumentError(f"{name}: expected an int or (H, W), got {value!r}") from None
    if min(size) < 1:
        raise ArgumentError(f"{name}: sizes must be positive, got {value!r}")
    return size


# -- the transforms ----------------------------------------------------------------------------


class Resize(_Geometric):
    """Resize the ground image to ``ground`` and/or the chips to ``chip`` ((H, W) or an int).

    Bilinear with antialiasing (viewshed: nearest); keypoints scale exactly, the chip
    transform's pixel size grows by the same factor.
    """

    def __init__(
        self, ground: int | Sequence[int] | None = None, chip: int | Sequence[int] | None = None
    ) -> None:
        self.ground, self.chip = size_hw(ground, "ground"), size_hw(chip, "chip")
        self.target = "both"

    def _ground_map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]] | None:
        if self.ground is None:
            return None
        return _scale(w / self.ground[1], h / self.ground[0]), self.ground

    def _chip_map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]] | None:
        if self.chip is None:
            return None
        return _scale(w / self.chip[1], h / self.chip[0]), self.chip

    def _apply_ground(self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]) -> Any:
        return _resize(image, hw, "bilinear")

    def _apply_chip(
        self, name: str, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]
    ) -> torch.Tensor:
        if _chip_mode(name) == "nearest":
            return _resize(image, hw, "nearest-exact")
        return _resize(image, hw, "bilinear")  # NaN in the DEM spreads to its neighbours


class Crop(_Geometric):
    """Cut the window (top, left, height, width), in pixels, out of the ground image or the
    chips (``target``); the window must lie inside the image."""

    def __init__(self, top: int, left: int, height: int, width: int, target: str) -> None:
        self.box = tuple(int(v) for v in (top, left, height, width))
        self.target = check_target(target, ("ground", "chip"))

    def _map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]]:
        top, left, height, width = self.box
        if top < 0 or left < 0 or height < 1 or width < 1 or top + height > h or left + width > w:
            raise ArgumentError(f"crop {self.box} does not fit a {h} x {w} image")
        return _translate(left, top), (height, width)

    _ground_map = _chip_map = _map

    def _cut(self, image: torch.Tensor) -> torch.Tensor:
        top, left, height, width = self.box
        return image[..., top : top + height, left : left + width].clone()

    def _apply_ground(self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]) -> Any:
        return self._cut(image)

    def _apply_chip(
        self, name: str, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]
    ) -> torch.Tensor:
        return self._cut(image)


class Flip(_Geometric):
    """Mirror the ground image or the chips (``target``): ``axis`` "horizontal" (left-right)
    or "vertical" (top-bottom). A mirrored chip's transform has a positive determinant."""

    def __init__(self, axis: str = "horizontal", target: str = "ground") -> None:
        if axis not in ("horizontal", "vertical"):
            raise ArgumentError(f"axis: expected 'horizontal' or 'vertical', got {axis!r}")
        self.axis, self.target = axis, check_target(target)

    def _map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]]:
        if self.axis == "horizontal":
            return np.array([[-1.0, 0.0, w], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), (h, w)
        return np.array([[1.0, 0.0, 0.0], [0.0, -1.0, h], [0.0, 0.0, 1.0]]), (h, w)

    _ground_map = _chip_map = _map

    def _flip(self, image: torch.Tensor) -> torch.Tensor:
        return torch.flip(image, dims=(-1,) if self.axis == "horizontal" else (-2,))

    def _apply_ground(self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]) -> Any:
        return self._flip(image)

    def _apply_chip(
        self, name: str, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]
    ) -> torch.Tensor:
        return self._flip(image)


class Rotate(_Geometric):
    """Turn the ground image or the chips (``target``) ``degrees`` counterclockwise as
    displayed, about the image centre, keeping the size (corners outside the old image are
    0, NaN in the DEM). On a chip this turns its up direction ``degrees`` clockwise on the
    map: ``rotation`` grows by ``degrees``. Multiples of 90 degrees are exact (no resampling;
    a non-square image swaps its height and width)."""

    def __init__(self, degrees: float, target: str = "chip") -> None:
        self.degrees, self.target = float(degrees), check_target(target)

    def _quarter_turns(self) -> int | None:
        k = self.degrees / 90.0
        return round(k) % 4 if abs(k - round(k)) < 1e-9 else None

    def _map(self, h: int, w: int) -> tuple[np.ndarray, tuple[int, int]]:
        k = self._quarter_turns()
        new_hw = (w, h) if k in (1, 3) else (h, w)
        m = _translate(w / 2, h / 2) @ np.linalg.inv(_rotation_ccw(self.degrees))
        m = m @ _translate(-new_hw[1] / 2, -new_hw[0] / 2)
        if k is not None:
            m = np.round(m, 9)  # exact quarter turns: integer maps
        return m, new_hw

    _ground_map = _chip_map = _map

    def _turn(
        self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int], **kw: Any
    ) -> torch.Tensor:
        k = self._quarter_turns()
        if k is not None:
            return torch.rot90(image, k, dims=(-2, -1)).clone()
        return _warp(image, m, hw, **kw)

    def _apply_ground(self, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]) -> Any:
        return self._turn(image, m, hw, mode="bilinear", fill=0.0)

    def _apply_chip(
        self, name: str, image: torch.Tensor, m: np.ndarray, hw: tuple[int, int]
    ) -> torch.Tensor:
        return self._turn(image, m, hw, mode=_chip_mode(name), fill=_chip_fill(name))


class NorthUp:
    """Turn heading-up chips north-up (``rotation`` becomes 0): ``Rotate(-rotation)``."""

    def __call__(self, sample: Sample) -> Sample:
        rotation = float(sample["rotation"])
        if abs(rotation) < 1e-12:
            return dict(sample)
        return Rotate(-rotation, target="chip")(sample)
