"""Shared fixtures: the real PDS samples beside the checkout (skipped when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

SAMPLES = Path(__file__).resolve().parents[1].parent / "shared" / "pds-samples"


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    """../shared/pds-samples, or skip the test with a message saying it is absent."""
    if not SAMPLES.is_dir():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    return SAMPLES


def sample_labels() -> list[Path]:
    """Every real label in the samples folder (empty when it is absent)."""
    if not SAMPLES.is_dir():
        return []
    return sorted(SAMPLES.glob("msl/*.LBL")) + sorted(SAMPLES.glob("m2020/*.xml"))
