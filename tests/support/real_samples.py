"""Where the real data lies: ``../shared`` beside the checkout (``SHARED``), its PDS samples."""

from __future__ import annotations

from pathlib import Path

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
SAMPLES = SHARED / "pds-samples"


def sample_labels() -> list[Path]:
    """Every real label in the samples folder (empty when it is absent)."""
    if not SAMPLES.is_dir():
        return []
    return sorted(SAMPLES.glob("msl/*.LBL")) + sorted(SAMPLES.glob("m2020/*.xml"))
