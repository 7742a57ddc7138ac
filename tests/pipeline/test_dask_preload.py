"""``dask worker --preload mars_pairs.pipeline.builder.dask_preload``: a worker process starts
with the process settings applied and the build's kernels loaded (issue 24: a long-lived
cluster's first chunk finds a warm worker)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

SCRIPT = """
import json, os
from mars_pairs.kernels import raycast, viewshed
before = [len(viewshed._viewshed_kernel.signatures), len(raycast._cast_kernel.signatures)]
from mars_pairs.pipeline.builder.dask_preload import dask_setup
dask_setup(None)
after = [len(viewshed._viewshed_kernel.signatures), len(raycast._cast_kernel.signatures)]
print(json.dumps({"before": before, "after": after, "omp": os.environ.get("OMP_WAIT_POLICY")}))
"""


def test_the_preload_loads_the_kernels_and_applies_the_settings() -> None:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] == [0, 0]  # importing compiles nothing
    assert all(n >= 1 for n in got["after"])
    assert got["omp"] == "PASSIVE"
