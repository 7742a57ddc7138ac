"""Small built datasets shared by the torch tests (built once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from support.builds import build
from support.members import tar_members
from support.missions import MissionCache


@pytest.fixture(scope="session")
def mission_dir(missions: MissionCache) -> Path:
    """A synthetic Perseverance mission: 3 stops of 3 images (its rasters are the truth)."""
    return missions(seed=1, stops=3, images_per_stop=3)


@pytest.fixture(scope="session")
def dataset_dir(mission_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """9 samples in 3 shards of 3, north-up chips of 128 m at 1 m, ray stride 16."""
    out = tmp_path_factory.mktemp("built") / "ds"
    return build(mission_dir, out, fine=True, output={"shard_size": 3})


@pytest.fixture(scope="session")
def heading_up_dir(mission_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same samples with heading-up chips of 96 m at 0.75 m (rotated grids)."""
    return build(
        mission_dir,
        tmp_path_factory.mktemp("built-heading") / "ds",
        fine=True,
        chips={"size_m": 96, "size_px": 128, "orientation": "heading-up"},
        output={"shard_size": 3},
    )


@pytest.fixture(scope="session")
def members(dataset_dir: Path) -> dict[str, bytes]:
    """Every tar member's bytes by name, read through tarfile (independent of the manifest)."""
    return tar_members(dataset_dir)
