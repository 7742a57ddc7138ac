"""A build never deletes what it did not write, and refuses inputs that would hang it (issue 22).

- Built without ``--resume`` into a folder of someone else's files (tar shards, a
  ``manifest.parquet``, a ``parts/`` folder), the build refuses with one line (exit 2) and
  every file stays byte-identical; a finished dataset the user added a file to is refused as
  well, with or without ``--resume``; once the stranger's files are gone, it resumes.
- A FIFO given as the DEM, the ortho, the PLACES table or the config is refused with one line
  naming the key and the path, within a second, before anything opens it.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from support.configs import build_config, config_file

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def _write_config(path: Path, mission: Path, out: Path, **inputs: str) -> Path:
    return config_file(path, mission, out, inputs=inputs, output={"shard_size": 2})


def _files(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _someone_elses(out: Path) -> dict[str, str]:
    """A folder of another tool's dataset: tar shards, a manifest, a parts folder, a README."""
    (out / "shards").mkdir(parents=True)
    (out / "parts").mkdir()
    (out / "shards" / "my-webdataset-000.tar").write_bytes(b"not ours " * 100)
    (out / "shards" / "shard-000000-train.tar").write_bytes(b"named like ours, not ours")
    (out / "manifest.parquet").write_bytes(b"PAR1 someone else's manifest PAR1")
    (out / "parts" / "notes.parquet").write_bytes(b"PAR1 notes PAR1")
    (out / "README.txt").write_text("my dataset\n")
    return _files(out)


def test_a_build_into_a_folder_of_other_files_refuses_and_touches_nothing(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "theirs"
    before = _someone_elses(out)
    config = _write_config(tmp_path / "c.yaml", small_mission, out)
    for extra in ([], ["--dry-run"], ["--workers", "2"]):
        capsys.readouterr()
        assert main(["build", "--config", str(config), "--quiet", *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert "README.txt" in err and "nothing was removed" in err
        assert _files(out) == before  # no file removed, changed or added (no stamp either)
    # --resume over a folder without a stamp clears too: refused the same way
    with pytest.raises(ConfigError, match=r"README\.txt"):
        run_build(load_config(config), resume=True, progress=False)
    assert _files(out) == before


def test_a_finished_dataset_with_a_strangers_file_is_refused_but_resumes(
    small_mission: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    run_build(build_config(small_mission, out, output={"shard_size": 2}), progress=False)
    (out / "parts").mkdir()  # a finished build left none
    (out / "parts" / "my-notes.txt").write_text("mine\n")
    hidden = out / "shards" / ".scratch.tmp-1"  # like a temporary name, not one of ours
    hidden.write_text("mine too\n")
    before = _files(out)
    other = build_config(small_mission, out, output={"shard_size": 1})  # another build
    with pytest.raises(ConfigError, match=r"parts/my-notes\.txt.*nothing was removed"):
        run_build(other, progress=False)
    assert _files(out) == before
    # the same config resumed: refused the same way, the stranger's files left alone
    same = build_config(small_mission, out, output={"shard_size": 2})
    with pytest.raises(ConfigError, match=r"parts/my-notes\.txt.*nothing was removed"):
        run_build(same, resume=True, progress=False)
    assert _files(out) == before
    (out / "parts" / "my-notes.txt").unlink()
    hidden.unlink()
    summary = run_build(same, resume=True, progress=False)
    assert summary.chunks_resumed == summary.chunks_built + summary.chunks_resumed > 0


def test_a_rebuild_clears_its_own_dataset_and_its_killed_temporaries(
    small_mission: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    run_build(build_config(small_mission, out, output={"shard_size": 1}), progress=False)
    assert list((out / "shards").glob("shard-000003-*.tar"))
    (out / "shards" / ".shard-000001-train.tar.tmp-4242").write_bytes(b"half a shard")
    (out / "parts").mkdir()  # a finished build left none
    (out / "parts" / ".build.json.tmp-4242").write_bytes(b"{")
    run_build(build_config(small_mission, out, output={"shard_size": 2}), progress=False)
    names = set(_files(out))
    assert any(n.startswith("shards/shard-000001-") for n in names)
    assert not any(n.startswith("shards/shard-000002") for n in names)
    assert not any(".tmp-" in n for n in names)
    assert "parts/clearing.json" not in names


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("key", ["dem", "ortho", "places"])
def test_a_fifo_input_is_refused_at_once(small_mission: Path, tmp_path: Path, key: str) -> None:
    fifo = tmp_path / f"{key}.fifo"
    os.mkfifo(fifo)
    config = _write_config(tmp_path / "c.yaml", small_mission, tmp_path / "ds", **{key: str(fifo)})
    start = time.monotonic()
    with pytest.raises(ConfigError, match=rf"inputs\.{key}: {fifo} is a FIFO"):
        load_config(config)
    # the CLI: one line, exit 2, within a second (the FIFO never gets a writer)
    done = subprocess.run(
        [sys.executable, "-m", "mars_pairs.cli", "build", "--config", str(config), "--quiet"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=60,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and f"inputs.{key}" in done.stderr, done.stderr
    assert time.monotonic() - start < 30  # the interpreter's start-up, not a hang
    # a config built in code, its path swapped for a FIFO after parsing: run_build refuses
    ok = build_config(small_mission, tmp_path / "ds2")
    from dataclasses import replace

    bad = replace(ok, inputs=replace(ok.inputs, **{key: fifo}))
    start = time.monotonic()
    with pytest.raises(ConfigError, match=rf"inputs\.{key}: .* is a FIFO"):
        run_build(bad, workers=2, progress=False)
    assert time.monotonic() - start < 1.0
    assert not (tmp_path / "ds2").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_config_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fifo = tmp_path / "config.yaml"
    os.mkfifo(fifo)
    start = time.monotonic()
    assert main(["build", "--config", str(fifo), "--dry-run"]) == 2
    assert time.monotonic() - start < 1.0
    err = capsys.readouterr().err
    assert err == f"mars-pairs build: {fifo}: cannot read config: not a regular file (a FIFO)\n"
