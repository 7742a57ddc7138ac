"""One options type for both torch datasets: an instance or keyword arguments, checked once."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import pytest
import torch

from mars_pairs.errors import ArgumentError, DatasetError
from mars_pairs.torch import DatasetOptions, MarsPairsDataset, MarsPairsIterableDataset


def test_options_are_frozen_and_checked_once() -> None:
    opts = DatasetOptions(fields=["ground", "ortho"], ground_size=64)
    assert opts.fields == ("ground", "ortho") and opts.ground_size == (64, 64)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.verify = True  # type: ignore[misc]  # the point: frozen
    for bad, named in (
        ({"fields": ("ground", "nope")}, "fields"),
        ({"ground_size": (0, 4)}, "ground_size"),
        ({"transform": 3}, "transform"),
        ({"verify": "yes"}, "verify"),
        ({"image_dtype": torch.int16}, "image_dtype"),
    ):
        with pytest.raises(ArgumentError, match=named):
            DatasetOptions(**bad)  # type: ignore[arg-type]  # the point: bad values


def test_both_datasets_take_the_same_options(dataset_dir: Path) -> None:
    opts = DatasetOptions(fields=("ortho", "dem"), normalize_dem=True)
    with (
        MarsPairsDataset(dataset_dir, opts) as ds,
        MarsPairsDataset(dataset_dir, fields=("ortho", "dem"), normalize_dem=True) as kw,
        MarsPairsIterableDataset(dataset_dir, opts, shuffle_buffer=1) as stream,
    ):
        assert ds.options == kw.options == stream.options == opts
        first = next(iter(stream))
        assert set(first) >= {"ortho", "dem"} and "ground" not in first
        assert abs(float(first["dem"].nanmedian())) < 1.0  # normalised
    # keyword arguments override the instance's values; filters pass through
    with MarsPairsDataset(dataset_dir, opts, fields=("ortho",), split="train") as ds:
        assert ds.options.fields == ("ortho",) and ds.options.normalize_dem
        assert set(ds.filters) == {"split"}
    # the streaming dataset's own parameters are its shuffling; every option is the shared type's
    own = set(inspect.signature(MarsPairsIterableDataset).parameters)
    assert own == {"root", "options", "shuffle_buffer", "seed", "kwargs"}
    with pytest.raises(ArgumentError, match="options"):
        MarsPairsDataset(dataset_dir, {"fields": ("ortho",)})  # type: ignore[arg-type]


def test_the_streaming_dataset_reaches_localization(dataset_dir: Path) -> None:
    """``localization=`` (once missing from the streaming dataset) reaches its reads: this
    dataset was built without the targets, so both classes refuse the same way."""
    errors = []
    for cls in (MarsPairsDataset, MarsPairsIterableDataset):
        with cls(dataset_dir, fields=("ortho",), localization=True) as ds:
            assert ds.options.localization
            with pytest.raises(DatasetError, match="no localization targets") as err:
                next(iter(ds)) if cls is MarsPairsIterableDataset else ds[0]
            errors.append(str(err.value).split(":")[-1])
    assert errors[0] == errors[1]
