"""Small built datasets shared by the torch tests (built once per session)."""

from __future__ import annotations

import tarfile
from pathlib import Path
from typing import Any

import pytest
from support.configs import mission_inputs

from mars_pairs.pipeline.build.run import run_build
from mars_pairs.pipeline.config import parse_config
from mars_pairs.synth import generate_mission


@pytest.fixture(scope="session")
def mission_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic Perseverance mission: 3 stops of 3 images (its rasters are the truth)."""
    root = tmp_path_factory.mktemp("mission")
    generate_mission(root, seed=1, mission="m2020", stops=3, images_per_stop=3, size="small")
    return root


def build(mission: Path, out: Path, **sections: Any) -> Path:
    doc: dict[str, Any] = {
        "inputs": mission_inputs(mission),
        "geometry": {"radius": 600, "ray_stride": 16},
        "chips": {"size_m": 128, "size_px": 128},
        "output": {"dir": str(out), "shard_size": 3},
        "splits": {"block_m": 100},
    }
    for name, values in sections.items():
        doc[name] = {**doc.get(name, {}), **values}
    summary = run_build(parse_config(doc, base=mission), workers=1, progress=False)
    assert summary.failures == 0
    return out


@pytest.fixture(scope="session")
def dataset_dir(mission_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """9 samples in 3 shards of 3, north-up chips of 128 m at 1 m, ray stride 16."""
    return build(mission_dir, tmp_path_factory.mktemp("built") / "ds")


@pytest.fixture(scope="session")
def heading_up_dir(mission_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same samples with heading-up chips of 96 m at 0.75 m (rotated grids)."""
    return build(
        mission_dir,
        tmp_path_factory.mktemp("built-heading") / "ds",
        chips={"size_m": 96, "size_px": 128, "orientation": "heading-up"},
    )


@pytest.fixture(scope="session")
def members(dataset_dir: Path) -> dict[str, bytes]:
    """Every tar member's bytes by name, read through tarfile (independent of the manifest)."""
    found: dict[str, bytes] = {}
    for shard in sorted((dataset_dir / "shards").glob("*.tar")):
        with tarfile.open(shard) as tar:
            for info in tar.getmembers():
                fh = tar.extractfile(info)
                assert fh is not None
                found[info.name] = fh.read()
    return found
