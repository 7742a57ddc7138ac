"""Shared fixtures: the real PDS samples beside the checkout (skipped when absent) and the
synthetic missions, generated once per session (``support.missions``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

from support.missions import MissionCache
from support.real_samples import SAMPLES

# Property tests give the same verdict on every machine: examples come from a fixed seed
# (derandomize) and no example database carries failures from one run to the next; every
# bug hypothesis found is kept as an explicit example in the tests.
settings.register_profile("mars-pairs", derandomize=True, database=None, deadline=None)
settings.load_profile("mars-pairs")


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    """../shared/pds-samples, or skip the test with a message saying it is absent."""
    if not SAMPLES.is_dir():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    return SAMPLES


@pytest.fixture(scope="session")
def missions(tmp_path_factory: pytest.TempPathFactory) -> MissionCache:
    """Synthetic missions by parameters, each generated once per session (read only; a test
    that changes one takes ``missions.copy(tmp_path / "m", **params)``)."""
    return MissionCache(tmp_path_factory.mktemp("missions"))


@pytest.fixture(scope="session")
def small_mission(missions: MissionCache) -> Path:
    """A 4-image synthetic Perseverance mission (2 stops x 2 images, seed 3). Read only."""
    return missions(seed=3, stops=2, images_per_stop=2)
