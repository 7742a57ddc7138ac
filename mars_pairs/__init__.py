"""mars-pairs: paired aerial/ground ML datasets from Mars rover images and orbital maps."""

from mars_pairs.camera import CameraModel
from mars_pairs.errors import ConfigError, LabelError, MarsPairsError, PlacesError, TerrainError
from mars_pairs.observation import MotionCounter, Observation

__version__ = "0.1.0"

__all__ = [
    "CameraModel",
    "ConfigError",
    "LabelError",
    "MarsPairsError",
    "MotionCounter",
    "Observation",
    "PlacesError",
    "TerrainError",
    "__version__",
]
