"""``build --resume`` and ``--dry-run`` guard what they keep.

- A resume after an input file changed (the PLACES table, the DEM, the ortho, a VRT's source
  tile) is refused, naming the input and what changed, the folder untouched; the same bytes
  written again (a newer mtime) still resume.
- A resume over a folder holding a file no build stamp there lists (a stranger's shard named
  like an unfinished chunk's, ``parts/notes.parquet``, ``notes.txt``) is refused untouched;
  a killed build's own leftover shards resume.
- The dry run of a config whose synthetic mission is still to generate plans it from its
  preset (exit 0), and a FIFO given as a file input is "expected a regular file".
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest
import yaml

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder import fingerprints
from mars_pairs.pipeline.builder import stamp as stamps
from mars_pairs.pipeline.builder.layout import part_paths
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import BuildConfig, load_config
from support.configs import build_config, config_doc, config_file

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _files(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


ONE_A_CHUNK = {"shard_size": 1, "keep_parts": True}  # parts are deleted to fake a kill


def _config(mission: Path, tmp_path: Path, out: Path) -> tuple[BuildConfig, Path]:
    """A cheap config of one label a chunk over ``mission``, its PLACES table a copy."""
    places = tmp_path / "places.csv"
    if not places.exists():
        shutil.copyfile(mission / "places" / "best_interp.csv", places)
    return build_config(mission, out, places=places, output=ONE_A_CHUNK), places


def _killed_after(out: Path, done: int, chunks: int = 4) -> None:
    """Make a finished build look killed after chunk ``done - 1``: the later chunks' commit
    markers (manifest parts) gone, their shards and failure parts left as written."""
    for k in range(done, chunks):
        part_paths(out, k)[1].unlink()


def _cli_yaml(mission: Path, tmp_path: Path, out: Path) -> Path:
    """``_config``'s config as ``tmp_path/c.yaml``, for the CLI."""
    places = tmp_path / "places.csv"
    return config_file(tmp_path / "c.yaml", mission, out, places=places, output=ONE_A_CHUNK)


def test_a_resume_after_the_places_table_changed_is_refused(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    config, places = _config(small_mission, tmp_path, out)
    run_build(config, progress=False)
    _killed_after(out, 2)
    original = places.read_bytes()
    lines = original.decode().splitlines(keepends=True)
    fields = lines[3].split(",")  # a ROVER row: move its easting (column 8) by 11.9 m
    fields[8] = f"{float(fields[8]) + 11.9:.4f}"
    lines[3] = ",".join(fields)
    places.write_text("".join(lines))
    before = _files(out)
    with pytest.raises(ConfigError, match=r"cannot resume: inputs\.places changed") as err:
        run_build(config, resume=True, progress=False)
    assert str(places) in str(err.value) and "content (sha256" in str(err.value)
    assert _files(out) == before
    # the dry run refuses the same way, in one line
    yaml_path = _cli_yaml(small_mission, tmp_path, out)
    assert main(["build", "--config", str(yaml_path), "--dry-run", "--resume"]) == 2
    printed = capsys.readouterr().err
    assert printed.count("\n") == 1 and "inputs.places changed" in printed, printed
    assert _files(out) == before
    # the same bytes again (a newer mtime): the content is what counts, the build resumes
    places.write_bytes(original)
    summary = run_build(config, resume=True, progress=False)
    assert (summary.chunks_built, summary.chunks_resumed) == (2, 2)


def test_a_changed_vrt_source_tile_or_a_large_raster_is_noticed(
    small_mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    tile = tiles / "dem-000.tif"
    shutil.copyfile(small_mission / "orbital" / "dem.tif", tile)
    vrt = tmp_path / "dem.vrt"
    vrt.write_text(
        '<VRTDataset rasterXSize="1" rasterYSize="1"><VRTRasterBand dataType="Float32" band="1">'
        '<SimpleSource><SourceFilename relativeToVRT="1">tiles/dem-000.tif</SourceFilename>'
        "</SimpleSource><SimpleSource>"
        '<SourceFilename relativeToVRT="0">/vsicurl/https://example.org/t.tif</SourceFilename>'
        "</SimpleSource></VRTRasterBand></VRTDataset>"
    )
    first = fingerprints.file_fingerprint(vrt)
    assert [s["path"] for s in first["sources"]] == [
        str(tiles / "dem-000.tif"),
        "/vsicurl/https://example.org/t.tif",
    ]
    assert first["sources"][1] == {"path": "/vsicurl/https://example.org/t.tif"}
    with tile.open("r+b") as fh:  # one byte of the tile changed, the VRT itself not
        fh.seek(2000)
        byte = fh.read(1)
        fh.seek(2000)
        fh.write(bytes([byte[0] ^ 1]))
    second = fingerprints.file_fingerprint(vrt)
    assert second != first and second["sha256"] == first["sha256"]
    stamp = {"config": {}, "labels": "", "count": 1}
    old = {**stamp, "inputs": {"places": {}, "dem": first, "ortho": {}}}
    new = {**stamp, "inputs": {"places": {}, "dem": second, "ortho": {}}}
    why = stamps.stamp_difference(old, new)
    assert why is not None and why.startswith("inputs.dem changed since the interrupted build")
    assert f"source {tile}: content" in why
    # a file over the hashed size: its size and mtime, not its content
    monkeypatch.setattr(fingerprints, "HASHED_BYTES", 1000)
    big = fingerprints.file_fingerprint(tile)
    assert "sha256" not in big and big["mtime_ns"] == tile.stat().st_mtime_ns
    os.utime(tile, ns=(big["mtime_ns"] + 10**9, big["mtime_ns"] + 10**9))
    why = stamps.stamp_difference(
        {**stamp, "inputs": {"places": {}, "dem": big, "ortho": {}}},
        {
            **stamp,
            "inputs": {"places": {}, "dem": fingerprints.file_fingerprint(tile), "ortho": {}},
        },
    )
    assert why is not None and "mtime_ns" in why
    # a stamp of no input fingerprint (an older build) is not resumed
    assert "no fingerprint of its inputs" in (stamps.stamp_difference(stamp, new) or "")


def test_a_resume_refuses_a_strangers_files_and_keeps_its_own_leftovers(
    small_mission: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    config, _ = _config(small_mission, tmp_path, out)
    run_build(config, progress=False)
    _killed_after(out, 1)  # chunks 1..3 unfinished, their shards left (a kill before the part)
    assert list((out / "shards").glob("shard-000001-*.tar"))
    (shard3,) = (out / "shards").glob("shard-000003-*.tar")  # one shard: one split
    theirs = {
        shard3.relative_to(out).as_posix(): b"SOMEONE ELSES DATA",
        "parts/notes.parquet": b"PAR1 notes PAR1",
        "parts/failures-000002.parquet": b"not a parquet file",
    }
    yaml_path = _cli_yaml(small_mission, tmp_path, out)
    for rel, data in theirs.items():
        kept = (out / rel).read_bytes() if (out / rel).exists() else None
        (out / rel).write_bytes(data)
        before = _files(out)
        with pytest.raises(ConfigError, match=rf"holds {rel}.*refusing to resume in"):
            run_build(config, resume=True, progress=False)
        assert _files(out) == before
        capsys.readouterr()
        assert main(["build", "--config", str(yaml_path), "--dry-run", "--resume"]) == 2
        printed = capsys.readouterr().err
        assert rel in printed
        assert ("does not read as" in printed) == (rel != "parts/notes.parquet"), printed
        if kept is None:
            (out / rel).unlink()
        else:
            (out / rel).write_bytes(kept)
    assert shard3.exists()  # the build's own shard of the unfinished chunk 3
    summary = run_build(config, resume=True, progress=False)
    assert (summary.chunks_built, summary.chunks_resumed) == (3, 1)
    # over a finished build: a stranger's file at the top, or a shard beyond its chunks
    for rel in ("notes.txt", "shards/shard-000007-train.tar", "shards/shard-000007.tar"):
        (out / rel).write_bytes(b"mine\n")
        before = _files(out)
        with pytest.raises(ConfigError, match=rf"holds {rel}"):
            run_build(config, resume=True, progress=False)
        assert _files(out) == before
        (out / rel).unlink()
    assert run_build(config, resume=True, progress=False).chunks_resumed == 4


def test_the_dry_run_plans_a_synthetic_mission_still_to_generate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "mission"
    doc = {
        "inputs": {
            "synthetic": {"root": "mission", "stops": 5, "images_per_stop": 2, "size": "small"},
            "labels": "mission/labels/*.xml",
            "places": "mission/places/best_interp.csv",
            "dem": "mission/orbital/dem.tif",
            "ortho": "mission/orbital/ortho.tif",
        },
        "output": {"dir": "ds", "shard_size": 4},
    }
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert main(["build", "--config", str(path), "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert f"generates it at {root} first (size small: 5 stops x 2 images = 10 labels)" in printed
    assert "labels: 10 " in printed and "chunks: 3 of up to 4 labels" in printed
    assert main(["build", "--config", str(path), "--dry-run", "--resume", "--limit", "3"]) == 0
    assert "labels: 3 " in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]  # nothing written
    # the rest is still checked: an input the generation does not write, a stranger's folder
    doc["inputs"]["ortho"] = "elsewhere/ortho.tif"
    path.write_text(yaml.safe_dump(doc))
    assert main(["build", "--config", str(path), "--dry-run"]) == 2
    assert "inputs.ortho: no such file" in capsys.readouterr().err
    doc["inputs"]["ortho"] = "mission/orbital/ortho.tif"
    path.write_text(yaml.safe_dump(doc))
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "README.txt").write_text("mine\n")
    assert main(["build", "--config", str(path), "--dry-run"]) == 2
    assert "README.txt" in capsys.readouterr().err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("key", ["places", "dem", "ortho"])
def test_a_fifo_or_a_folder_as_a_file_input_expects_a_regular_file(
    small_mission: Path, tmp_path: Path, key: str
) -> None:
    fifo = tmp_path / f"{key}.fifo"
    os.mkfifo(fifo)
    for bad, kind in ((fifo, "a FIFO"), (tmp_path, "a folder")):
        doc = config_doc(small_mission, tmp_path / "ds", inputs={key: str(bad)})
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump(doc))
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert str(err.value).endswith(f"inputs.{key}: {bad} is {kind}, expected a regular file")
