"""The processes of a build die with it (issue 22).

``mars-pairs build --workers 2`` is SIGKILLed at 10 seeded random moments (start-up, pool
start, mid-build); within 2 s no process of the build is left (fork server, workers,
resource tracker: found by a marker in their environment), and a ``--resume`` after the last
kill gives the bytes of an undisturbed build. A Ctrl-C (SIGINT to the process group, as a
terminal sends it) while the workers start prints no traceback and leaves no process.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import random
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from support.configs import config_file
from support.missions import MissionCache

ROOT = Path(__file__).resolve().parents[2]
MARK = "MARS_PAIRS_TEST_BUILD"
#: How long the processes of a killed build may take to end (seconds): a worker inside a long
#: call that holds the GIL (loading compiled kernels on a loaded machine) ends when it returns;
#: a process that outlives its build never ends, so a generous grace tests the same property.
GRACE_S = 20.0

pytestmark = [
    pytest.mark.skipif(
        not sys.platform.startswith("linux"), reason="scans /proc for the build's processes"
    ),
    pytest.mark.slow,  # kills builds: more than ~3 s a test (`make test-fast` skips them)
]


def _config(path: Path, mission: Path, out: Path) -> Path:
    return config_file(path, mission, out, output={"shard_size": 1})


def _marked(tag: str) -> list[int]:
    """Live processes whose environment holds ``MARK=tag``."""
    needle = f"{MARK}={tag}".encode()
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                if needle in f.read().split(b"\0"):
                    found.append(int(entry))
        except OSError:  # gone, or a zombie
            continue
    return found


def _left_after(tag: str, seconds: float) -> list[int]:
    """The marked processes still alive ``seconds`` from now (empty as soon as none is)."""
    deadline = time.monotonic() + seconds
    while (left := _marked(tag)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def _start(config: Path, tag: str, *extra: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), MARK: tag}
    cmd = [sys.executable, "-m", "mars_pairs.cli", "build", "--config", str(config)]
    return subprocess.Popen(
        [*cmd, "--workers", "2", "--quiet", *extra],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group, as a terminal's job
    )


def _digest(out: Path) -> dict[str, str]:
    shards = sorted(p.relative_to(out).as_posix() for p in out.glob("shards/*.tar"))
    names = ["manifest.parquet", "failures.parquet", *shards]
    return {str(name): hashlib.sha256((out / name).read_bytes()).hexdigest() for name in names}


def _reap(tag: str) -> None:
    for pid in _marked(tag):  # a failed test leaves nothing behind either
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_build_killed_at_random_moments_leaves_no_process_and_resumes(
    small_mission: Path, tmp_path: Path
) -> None:
    reference = tmp_path / "reference"
    run_build(load_config(_config(tmp_path / "ref.yaml", small_mission, reference)), progress=False)
    out = tmp_path / "ds"
    config = _config(tmp_path / "c.yaml", small_mission, out)
    rng = random.Random(22)
    tag = uuid.uuid4().hex
    try:
        for moment in sorted(rng.uniform(0.1, 4.0) for _ in range(10)):
            build = _start(config, tag, "--resume")
            time.sleep(moment)
            build.kill()
            build.wait(timeout=30)
            assert _left_after(tag, GRACE_S) == [], f"processes left after a kill at {moment:.2f} s"
            build.stderr.close()
        build = _start(config, tag, "--resume")
        _, err = build.communicate(timeout=300)
        assert build.returncode == 0, err.decode()[-2000:]
        assert _left_after(tag, GRACE_S) == []
    finally:
        _reap(tag)
    assert _digest(out) == _digest(reference)


def _fork_server(tag: str, timeout: float) -> int | None:
    """The pid of the build's fork server, as soon as it exists (None after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for pid in _marked(tag):
            with contextlib.suppress(OSError), open(f"/proc/{pid}/cmdline", "rb") as f:
                if b"forkserver import main" in f.read():
                    return pid
        time.sleep(0.005)
    return None


def _deaf_to_sigint(pid: int) -> bool:
    """Whether process ``pid`` blocks or ignores SIGINT."""
    with open(f"/proc/{pid}/status") as f:
        masks = [int(line.split()[1], 16) for line in f if line.startswith(("SigBlk", "SigIgn"))]
    return any(mask & (1 << (signal.SIGINT - 1)) for mask in masks)


@pytest.mark.slow
def test_ctrl_c_while_the_fork_server_starts_is_quiet_and_leaves_no_process(
    small_mission: Path, tmp_path: Path
) -> None:
    config = _config(tmp_path / "c.yaml", small_mission, tmp_path / "ds")
    tag = uuid.uuid4().hex
    try:
        build = _start(config, tag)
        server = _fork_server(tag, timeout=60)
        assert server is not None, "no fork server started"
        # from its first moment (it still imports the build's modules), not after
        assert _deaf_to_sigint(server)
        time.sleep(0.2)  # the driver is past the server's start; the server still imports
        os.killpg(build.pid, signal.SIGINT)  # what a terminal's Ctrl-C sends
        _, err = build.communicate(timeout=60)
        assert _left_after(tag, GRACE_S) == []
    finally:
        _reap(tag)
    text = err.decode()
    assert "Traceback" not in text, text
    assert "mars-pairs build: interrupted" in text, text
    assert build.returncode == 130, text


@pytest.mark.slow
def test_ctrl_c_mid_build_prints_the_tools_line_only(
    missions: MissionCache, tmp_path: Path
) -> None:
    """Once the workers build (a shard is written), a Ctrl-C prints one line: no traceback,
    no resource tracker "leaked semaphore" warning for the locks of the killed workers."""
    mission = missions(seed=3, stops=4, images_per_stop=2)  # 8 labels, a shard each
    out = tmp_path / "ds"
    config = _config(tmp_path / "c.yaml", mission, out)
    tag = uuid.uuid4().hex
    try:
        build = _start(config, tag)
        deadline = time.monotonic() + 120
        while not list(out.glob("shards/*.tar")) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert list(out.glob("shards/*.tar")), "no shard written"
        os.killpg(build.pid, signal.SIGINT)  # what a terminal's Ctrl-C sends
        _, err = build.communicate(timeout=60)
        assert _left_after(tag, GRACE_S) == []
    finally:
        _reap(tag)
    assert err.decode() == "mars-pairs build: interrupted\n"
    assert build.returncode == 130  # the CLI's Ctrl-C status
