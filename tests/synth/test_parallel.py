"""Rendering a mission over processes writes the same files, byte for byte, as rendering it
in one process."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from mars_pairs.errors import ArgumentError
from mars_pairs.synth import generate_mission

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _digests(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_two_workers_write_the_bytes_of_one(tmp_path: Path) -> None:
    runs = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        result = generate_mission(out, seed=3, mission="m2020", stops=2, images_per_stop=3,
                                  terrain_labels=True, workers=workers)  # fmt: skip
        assert result["images"] == 6
        runs[workers] = _digests(out)
    serial, parallel = runs[1], runs[2]
    assert sum(name.endswith(".jpg") for name in serial) == 6
    assert any(name.startswith("ai4mars/") for name in serial)
    assert parallel == serial  # the same files (no temporary one left), the same bytes


def test_workers_below_one_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ArgumentError, match="workers"):
        generate_mission(tmp_path / "m", workers=0)
