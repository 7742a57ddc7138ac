"""Process settings are applied by an explicit call, never by importing the package."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mars_pairs.runtime import (
    PROCESS_DEFAULTS,
    build_settings,
    configure_process,
    is_build_setting,
    take_build_settings,
)

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import json, os
import mars_pairs.kernels.viewshed
import mars_pairs.pipeline.builder.worker
from numba.np.ufunc import parallel
seen = {"after_import": os.environ.get("OMP_WAIT_POLICY"),
        "openmp_loaded_on_import": parallel._is_initialized}
from mars_pairs.runtime import configure_process
configure_process()
seen["after_call"] = os.environ.get("OMP_WAIT_POLICY")
print(json.dumps(seen))
"""


def _probe(env: dict[str, str]) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_importing_the_kernels_leaves_the_environment_alone_and_the_call_sets_it() -> None:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = str(ROOT)
    seen = _probe(env)
    assert seen["after_import"] is None
    # the call still comes before OpenMP reads it: importing does not load the threading layer
    assert seen["openmp_loaded_on_import"] is False
    assert seen["after_call"] == "PASSIVE"


def test_a_value_the_user_set_wins() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_WAIT_POLICY": "ACTIVE"}
    assert _probe(env)["after_call"] == "ACTIVE"
    environ: dict[str, str] = {}
    configure_process(environ)
    assert environ == dict(PROCESS_DEFAULTS)


def test_the_command_line_configures_its_process(monkeypatch: pytest.MonkeyPatch) -> None:
    from mars_pairs.cli.main import main

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with pytest.raises(SystemExit):
        main(["--version"])
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"


def test_build_settings_are_the_named_ones_only() -> None:
    driver = {
        "GDAL_HTTP_TIMEOUT": "30",
        "AWS_PROFILE": "mars",
        "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".tif",
        "HTTPS_PROXY": "http://proxy:3128",
        "OMP_WAIT_POLICY": "PASSIVE",
        "HOME": "/home/driver",
        "PATH": "/driver/bin",
        "MY_SECRET_TOKEN": "x",
    }
    assert build_settings(driver) == {
        "GDAL_HTTP_TIMEOUT": "30",
        "AWS_PROFILE": "mars",
        "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".tif",
        "HTTPS_PROXY": "http://proxy:3128",
        "OMP_WAIT_POLICY": "PASSIVE",
    }
    assert not is_build_setting("PATH")


def test_a_worker_takes_the_drivers_settings_and_keeps_the_rest() -> None:
    worker = {"PATH": "/worker/bin", "AWS_PROFILE": "stale", "GDAL_CACHEMAX": "64"}
    take_build_settings({"AWS_PROFILE": "mars", "GDAL_HTTP_TIMEOUT": "30"}, worker)
    # GDAL_CACHEMAX: unset in the driver since the server started, so unset here too
    assert worker == {"PATH": "/worker/bin", "AWS_PROFILE": "mars", "GDAL_HTTP_TIMEOUT": "30"}
    with pytest.raises(ValueError, match="PATH"):
        take_build_settings({"PATH": "/driver/bin"}, worker)
