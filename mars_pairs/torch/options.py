"""What a torch dataset reads and how it decodes: one options type for every dataset class.

:class:`DatasetOptions` is the contract :class:`~mars_pairs.torch.MarsPairsDataset`,
:class:`~mars_pairs.torch.MarsPairsIterableDataset` and
:class:`~mars_pairs.torch.MarsPairsDataModule` share: pass one instance
(``MarsPairsDataset(root, opts)``), or its fields as keyword arguments
(``MarsPairsDataset(root, fields=("ground", "ortho"), verify=True)``); keyword arguments
override the instance's values. Values are checked when the options are made: a bad one is
an :class:`~mars_pairs.errors.ArgumentError` naming the option.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from mars_pairs.errors import ArgumentError
from mars_pairs.torch.decode import DEFAULT_FIELDS, KNOWN_FIELDS, out_dtype

Transform = Callable[[dict[str, Any]], dict[str, Any]]


def _ground_size(value: int | Sequence[int] | None) -> tuple[int, int] | None:
    """``ground_size`` as (H, W) pixels, or None."""
    if value is None:
        return None
    try:
        if isinstance(value, (int, np.integer)):
            size = (int(value), int(value))
        else:
            h, w = value
            size = (int(h), int(w))
    except (TypeError, ValueError):
        raise ArgumentError(f"ground_size: expected an int or (H, W), got {value!r}") from None
    if min(size) < 1:
        raise ArgumentError(f"ground_size: sizes must be positive, got {value!r}")
    return size


def _fields(value: str | Sequence[str]) -> tuple[str, ...]:
    fields = (value,) if isinstance(value, str) else tuple(value)
    bad = [f for f in fields if f not in KNOWN_FIELDS]
    if bad or not fields:
        raise ArgumentError(
            f"fields: unknown field(s) {bad}; expected some of {list(KNOWN_FIELDS)}"
        )
    return tuple(dict.fromkeys(fields))


@dataclass(frozen=True)
class DatasetOptions:
    """The options of a mars-pairs torch dataset (every dataset class takes the same ones).

    - ``fields``: the members to read (``mars_pairs.torch.ALL_FIELDS`` and the dense ones of
      ``output.members``); default ground, ortho, dem, viewshed.
    - ``transform``: a callable applied to each sample dict (:mod:`mars_pairs.torch.transforms`),
      after decoding and padding.
    - ``ground_size``: int or (H, W): ground images resized (bilinear) to this many pixels.
    - ``pad``: every sample the same size (default True, so a plain ``DataLoader`` batches):
      ground images smaller than the dataset's largest frame (or than ``ground_size``) are
      padded with zeros at the bottom and right, so ground pixel coordinates do not move, and
      ``ground_mask`` (bool [1, H, W], True on the image's own pixels) is added; ``corr``,
      ``corr_ground`` and the dense ground-grid fields are padded with NaN (no hit) and
      ``ortho_view`` / ``view_valid`` with 0 to the largest frame's grid. False: native sizes
      (a batch of mixed cameras then needs ``collate_samples``, which keeps them a list).
    - ``normalize_dem``: subtract each DEM chip's median elevation (metres).
    - ``image_dtype``: torch.uint8 (images 0..255, masks {0, 1}) or torch.float32 ([0, 1]).
    - ``verify``: check every member of each sample read (tar header, size, CRC-32C), as
      ``mars-pairs verify`` does.
    - ``localization``: add ``rover_px``, ``camera_px`` and ``heading_deg`` from ``meta.json``.
    """

    fields: tuple[str, ...] = DEFAULT_FIELDS
    transform: Transform | None = None
    ground_size: tuple[int, int] | None = None
    pad: bool = True
    normalize_dem: bool = False
    image_dtype: torch.dtype = torch.uint8
    verify: bool = False
    localization: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalised values are written once, here
        set_(self, "fields", _fields(self.fields))
        set_(self, "ground_size", _ground_size(self.ground_size))
        if self.transform is not None and not callable(self.transform):
            raise ArgumentError(f"transform: expected a callable, got {self.transform!r}")
        for name in ("pad", "normalize_dem", "verify", "localization"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise ArgumentError(f"{name}: expected True or False, got {value!r}")
            set_(self, name, bool(value))
        out_dtype("ground", self.image_dtype)  # ArgumentError for another dtype

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The option names (the keyword arguments every dataset class accepts)."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def split(
        cls, options: DatasetOptions | None, kwargs: Mapping[str, Any]
    ) -> tuple[DatasetOptions, dict[str, Any]]:
        """(options, the other keyword arguments): ``options`` (default ones if None) with the
        option names of ``kwargs`` replacing its values; the rest (the filters) handed back."""
        if options is not None and not isinstance(options, DatasetOptions):
            raise ArgumentError(f"options: expected a DatasetOptions, got {options!r}")
        names = set(cls.names())
        mine = {k: v for k, v in kwargs.items() if k in names}
        rest = {k: v for k, v in kwargs.items() if k not in names}
        base = options if options is not None else cls()
        return (dataclasses.replace(base, **mine) if mine else base), rest
