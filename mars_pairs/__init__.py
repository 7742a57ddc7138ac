"""mars-pairs: paired aerial/ground ML datasets from Mars rover images and orbital maps."""

from mars_pairs.errors import ConfigError, LabelError, MarsPairsError, PlacesError, TerrainError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.store.query import Manifest
from mars_pairs.version import __version__

__all__ = [
    "CameraModel",
    "ConfigError",
    "LabelError",
    "Manifest",
    "MarsPairsDataset",
    "MarsPairsError",
    "MarsPairsIterableDataset",
    "MotionCounter",
    "Observation",
    "PlacesError",
    "TerrainError",
    "__version__",
]


def __getattr__(name: str) -> object:
    """Torch datasets load lazily, so that label and build code never imports torch."""
    if name in ("MarsPairsDataset", "MarsPairsIterableDataset", "collate_samples"):
        import mars_pairs.torch as dataset

        return getattr(dataset, name)
    raise AttributeError(f"module 'mars_pairs' has no attribute {name!r}")
