"""After ``python -m mars_pairs.warmup`` a new process generates a mission, builds it and runs
``mars-pairs viewshed`` (full circle and wedge) without compiling a numba kernel: every
dispatcher of the package it touched loaded its machine code from the cache (numba's own
counters, ``Dispatcher.stats``: cache hits and misses per signature)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent

# the fresh process: a one-stop mission (rendered in this process), a build of it (in this
# process) and the viewshed command; then each dispatcher's cache hits and misses
RUN = """
import io, json, sys
from contextlib import redirect_stdout
from pathlib import Path

sys.path.insert(0, sys.argv[2])
from mars_pairs.runtime import configure_process

configure_process()
import rasterio
from numba.core.dispatcher import Dispatcher

from mars_pairs.cli.main import main
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.synth import generate_mission
from support.configs import build_config

tmp = Path(sys.argv[1])
generate_mission(tmp / "m", seed=5, stops=1, images_per_stop=2, size="small", workers=1)
summary = run_build(build_config(tmp / "m", tmp / "ds"), workers=1, progress=False)
assert summary.samples > 0, summary
dem = tmp / "m" / "orbital" / "dem.tif"
with rasterio.open(dem) as ds:
    x, y = (ds.bounds.left + ds.bounds.right) / 2, (ds.bounds.bottom + ds.bounds.top) / 2
common = ["viewshed", "--dem", str(dem), "--x", str(x), "--y", str(y), "--height", "2"]
with redirect_stdout(io.StringIO()):
    for extra in (["--radius", "400"], ["--radius", "200", "--az-min", "10", "--az-max", "70"]):
        assert main([*common, "--out", str(tmp / "v.tif"), *extra]) == 0
stats = {}
for name, module in list(sys.modules.items()):
    if name.startswith("mars_pairs"):
        for attr, obj in vars(module).items():
            if isinstance(obj, Dispatcher) and obj.__module__ == name:
                hits, misses = obj.stats.cache_hits, obj.stats.cache_misses
                if hits or misses:
                    stats[f"{name}.{attr}"] = [sum(hits.values()), sum(misses.values())]
print(json.dumps(stats))
"""


@pytest.mark.slow
def test_after_the_warmup_a_new_process_compiles_nothing(tmp_path: Path) -> None:
    warm = subprocess.run(
        [sys.executable, "-m", "mars_pairs.warmup"], capture_output=True, text=True, timeout=900
    )
    assert warm.returncode == 0, warm.stderr
    done = subprocess.run(
        [sys.executable, "-c", RUN, str(tmp_path), str(TESTS)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    stats = json.loads(done.stdout.strip().splitlines()[-1])
    compiled = {name: s for name, s in stats.items() if s[1]}
    assert compiled == {}, f"compiled in the new process (hits, misses): {compiled}"
    # the kernels ran, each loaded from the cache: the viewshed, ray caster, resampler,
    # point sampler, the ortho's and the renderer's
    expected = {
        "mars_pairs.kernels.viewshed._viewshed_kernel",
        "mars_pairs.kernels.raycast._cast_kernel",
        "mars_pairs.kernels.resample.sample_affine",
        "mars_pairs.kernels.frustum.frustum_mask",
        "mars_pairs.synth.ortho.compose_ortho",
        "mars_pairs.synth.ortho.stamp_rocks",
        "mars_pairs.synth.render.render_depth",
        "mars_pairs.synth.render.shade",
    }
    assert expected <= set(stats), sorted(stats)
