"""mars-pairs: paired aerial/ground ML datasets from Mars rover images and orbital maps.

The public API, importable from here (``from mars_pairs import ...``):

- reading the archive: :func:`read_observation` (a PDS3/PDS4 label -> :class:`Observation`),
  :class:`CameraModel`, :class:`Places` (the PLACES table -> a :class:`Pose` on the map);
- building: :func:`load_config` (YAML -> :class:`BuildConfig`), :func:`run_build`,
  :func:`generate_mission` (the synthetic mission), :func:`compute_viewshed`;
- reading a dataset: :class:`Manifest`, :class:`MarsPairsDataset`,
  :class:`MarsPairsIterableDataset`, :class:`MarsPairsLoader`, :func:`collate_samples`,
  :func:`verify_dataset`, :func:`inspect_dataset`;
- every exception of :mod:`mars_pairs.errors` (base :class:`MarsPairsError`).

``import mars_pairs`` stays light (every command and worker imports it first): the errors and
the version are imported with it, every other name on first use (``__getattr__``: torch,
numba, rasterio, pyarrow, pydantic, lxml load then); type checkers and IDEs see them through
the ``TYPE_CHECKING`` imports below.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mars_pairs.errors import (
    ArgumentError,
    BuildError,
    ConfigError,
    ContentError,
    CoverageError,
    DatasetError,
    DuplicateKeyError,
    FetchError,
    FolderLockedError,
    ImageError,
    LabelError,
    MarsPairsError,
    MissingMemberError,
    PlacesError,
    SampleIndexError,
    SampleKeyError,
    StageError,
    StorageError,
    TerrainError,
    TerrainLabelError,
    UsageError,
    WorkerDiedError,
    WorkerStartError,
)
from mars_pairs.version import __version__

if TYPE_CHECKING:
    from mars_pairs.geometry.camera import CameraModel
    from mars_pairs.geometry.places import Places, Pose
    from mars_pairs.kernels.viewshed import compute_viewshed
    from mars_pairs.observation import MotionCounter, Observation
    from mars_pairs.pds import read_observation
    from mars_pairs.pipeline.builder.run import run_build
    from mars_pairs.pipeline.config import BuildConfig, load_config
    from mars_pairs.store.inspect import inspect_dataset
    from mars_pairs.store.query import Manifest
    from mars_pairs.store.verify import verify_dataset
    from mars_pairs.synth import generate_mission
    from mars_pairs.torch import (
        MarsPairsDataset,
        MarsPairsIterableDataset,
        MarsPairsLoader,
        collate_samples,
    )

__all__ = [
    "ArgumentError",
    "BuildConfig",
    "BuildError",
    "CameraModel",
    "ConfigError",
    "ContentError",
    "CoverageError",
    "DatasetError",
    "DuplicateKeyError",
    "FetchError",
    "FolderLockedError",
    "ImageError",
    "LabelError",
    "Manifest",
    "MarsPairsDataset",
    "MarsPairsError",
    "MarsPairsIterableDataset",
    "MarsPairsLoader",
    "MissingMemberError",
    "MotionCounter",
    "Observation",
    "Places",
    "PlacesError",
    "Pose",
    "SampleIndexError",
    "SampleKeyError",
    "StageError",
    "StorageError",
    "TerrainError",
    "TerrainLabelError",
    "UsageError",
    "WorkerDiedError",
    "WorkerStartError",
    "__version__",
    "collate_samples",
    "compute_viewshed",
    "generate_mission",
    "inspect_dataset",
    "load_config",
    "read_observation",
    "run_build",
    "verify_dataset",
]

#: The names imported on first use: name -> the module that defines it.
_LAZY = {
    "BuildConfig": "mars_pairs.pipeline.config",
    "CameraModel": "mars_pairs.geometry.camera",
    "Manifest": "mars_pairs.store.query",
    "MarsPairsDataset": "mars_pairs.torch",
    "MarsPairsIterableDataset": "mars_pairs.torch",
    "MarsPairsLoader": "mars_pairs.torch",
    "MotionCounter": "mars_pairs.observation",
    "Observation": "mars_pairs.observation",
    "Places": "mars_pairs.geometry.places",
    "Pose": "mars_pairs.geometry.places",
    "collate_samples": "mars_pairs.torch",
    "compute_viewshed": "mars_pairs.kernels.viewshed",
    "generate_mission": "mars_pairs.synth",
    "inspect_dataset": "mars_pairs.store.inspect",
    "load_config": "mars_pairs.pipeline.config",
    "read_observation": "mars_pairs.pds",
    "run_build": "mars_pairs.pipeline.builder.run",
    "verify_dataset": "mars_pairs.store.verify",
}


def __getattr__(name: str) -> object:
    """The names of ``_LAZY``, imported on first use (torch, numba, rasterio load then)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'mars_pairs' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
