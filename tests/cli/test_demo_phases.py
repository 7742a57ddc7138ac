"""The demo's first build names each phase before the build's bar: the kernels compiling in
the background, the mission's terrain, traverse and rendering, and when each is done."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mars_pairs.cli.build import _ensure_synthetic
from mars_pairs.pipeline.config import parse_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _config(root: Path):
    mission = root / "mission"
    doc = {
        "inputs": {
            "synthetic": {
                "root": str(mission),
                "mission": "m2020",
                "seed": 2,
                "stops": 1,
                "images_per_stop": 1,
                "size": "small",
            },
            "labels": str(mission / "labels" / "*.xml"),
            "places": str(mission / "places" / "best_interp.csv"),
            "dem": str(mission / "orbital" / "dem.tif"),
            "ortho": str(mission / "orbital" / "ortho.tif"),
        },
        "output": {"dir": str(root / "dataset")},
    }
    return parse_config(doc, base=root)


def test_first_build_prints_a_line_per_phase(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _config(tmp_path)
    _ensure_synthetic(config)
    out = capsys.readouterr().out.splitlines()
    expected = [
        "compiling the build's kernels in the background",
        "generating the synthetic m2020 mission in",
        "  m2020: terrain: 1024 x 1024 m DEM at 1 m, ortho at 0.25 m",
        "  m2020: traverse: 1 stops, 1 sites",
        "mission generated (",
        "kernels compiled (",
    ]
    at = [next((i for i, line in enumerate(out) if line.startswith(e)), -1) for e in expected]
    assert -1 not in at and at == sorted(at), out
    # the kernels' line gives the compile's own time and the wait after the mission
    (line,) = [ln for ln in out if ln.startswith("kernels compiled (")]
    assert re.fullmatch(
        r"kernels compiled \(\d+ s, beside the mission; \d+ s waited after it\); building \.\.\.",
        line,
    ), line
    assert (tmp_path / "mission" / "truth.parquet").is_file()
    # a second run finds the mission and says nothing
    _ensure_synthetic(config)
    assert capsys.readouterr().out == ""
