"""The demo's first build names each phase before the build's bar: the kernels loading (or
compiling) in the background, the mission's terrain, traverse and rendering, and when each is
done."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from mars_pairs.cli.build import _ensure_synthetic, phase_line
from mars_pairs.cli.main import main
from mars_pairs.pipeline.config import parse_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _doc(root: Path) -> dict[str, Any]:
    mission = root / "mission"
    return {
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


def _config(root: Path):
    return parse_config(_doc(root), base=root)


def test_first_build_prints_a_line_per_phase(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _config(tmp_path)
    _ensure_synthetic(config)
    out = capsys.readouterr().out.splitlines()
    expected = [
        "loading the kernels in the background",
        "generating the synthetic m2020 mission in",
        "  m2020: terrain: 1024 x 1024 m DEM at 1 m, ortho at 0.25 m",
        "  m2020: traverse: 1 stops, 1 sites",
        "mission generated (",
        "kernels ready (",
    ]
    at = [next((i for i, line in enumerate(out) if line.startswith(e)), -1) for e in expected]
    assert -1 not in at and at == sorted(at), out
    # the kernels' line gives the loading's own time and the wait after the mission
    (line,) = [ln for ln in out if ln.startswith("kernels ready (")]
    assert re.fullmatch(
        r"kernels ready \(\d+ s, beside the mission; \d+ s waited after it\); building \.\.\.",
        line,
    ), line
    assert (tmp_path / "mission" / "truth.parquet").is_file()
    # a second run finds the mission and says nothing
    _ensure_synthetic(config)
    assert capsys.readouterr().out == ""


#: the build's last timing line: each phase's own time
PHASES = re.compile(
    r"phases: (mission generation (?P<mission>\d+\.\d) s, )?build (?P<build>\d+\.\d) s, "
    r"finish (?P<finish>\d+\.\d) s"
)


def test_the_build_prints_each_phase_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The first build (its mission rendered by the build's 2 workers) names the mission's
    generation, the build and its finish; a second one, the mission there, only the last two."""
    config = tmp_path / "build.yaml"
    config.write_text(yaml.safe_dump(_doc(tmp_path)))
    assert main(["build", "--config", str(config), "--workers", "2", "--quiet"]) == 0
    out = capsys.readouterr().out.splitlines()
    phases = [m for m in map(PHASES.fullmatch, out) if m]
    assert len(phases) == 1 and phases[0]["mission"] is not None, out
    generated = [ln for ln in out if ln.startswith("mission generated (")]
    assert len(generated) == 1 and out.index(generated[0]) < out.index(phases[0].string), out
    assert (tmp_path / "dataset" / "dataset.json").is_file()
    args = ["build", "--config", str(config), "--out", str(tmp_path / "again"), "--quiet"]
    assert main(args) == 0
    out = capsys.readouterr().out.splitlines()
    (again,) = [m for m in map(PHASES.fullmatch, out) if m]
    assert again["mission"] is None and not any(ln.startswith("mission generated") for ln in out)


def test_phase_line_gives_the_finish_as_the_rest() -> None:
    assert (
        phase_line(58.04, 5.0, 5.7)
        == "phases: mission generation 58.0 s, build 5.0 s, finish 0.7 s"
    )
    assert phase_line(None, 5.0, 4.9) == "phases: build 5.0 s, finish 0.0 s"
