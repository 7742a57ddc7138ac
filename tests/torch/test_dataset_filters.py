"""The torch datasets filter with ManifestFilter: they refuse what Manifest.filter and the
CLI refuse, with the same one-line ArgumentError, before any shard is opened."""

from __future__ import annotations

from pathlib import Path

import pytest

from mars_pairs.errors import ArgumentError
from mars_pairs.torch import MarsPairsDataset, MarsPairsIterableDataset
from tests.support.manifests import write_place_manifest


@pytest.fixture(scope="module")
def placed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("placed")
    write_place_manifest(root)
    return root


@pytest.mark.parametrize("cls", [MarsPairsDataset, MarsPairsIterableDataset])
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bbox_lonlat": (0, 10, 1, -10)}, r"bbox_lonlat: S \(10\) is north of N \(-10\)"),
        ({"near": (0, 0, -5)}, "near: RADIUS_M: expected a positive radius"),
        ({"sol": (9, 1)}, r"sol: FIRST \(9\) is after LAST \(1\)"),
        ({"split": "training"}, "its splits are test, train, val"),
        ({"instrument": "NAVCAM"}, "its instruments are MCZ_LEFT, MCZ_RIGHT, NAVCAM_LEFT"),
        ({"nearby": (1, 2, 3)}, r"unknown filter argument\(s\) \['nearby'\]"),
    ],
)
def test_torch_datasets_refuse_what_the_cli_refuses(
    placed: Path, cls: type, kwargs: dict, match: str
) -> None:
    with pytest.raises(ArgumentError, match=match):
        cls(placed, **kwargs)
