"""The member checks ``mars-pairs verify`` and ``MarsPairsDataset(verify=True)`` share
(:mod:`mars_pairs.store.integrity`) and dataset.json, on a small tar written here."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from mars_pairs.errors import ArgumentError, DatasetError
from mars_pairs.store.dataset_info import read_dataset_info
from mars_pairs.store.filter_args import strings
from mars_pairs.store.integrity import BLOCK, MemberSpec, check_member, shard_path
from mars_pairs.store.shards import MemberLocation, ShardWriter, read_member

MEMBERS = {"ground.jpg": b"J" * 700, "ortho.png": b"P" * 300, "meta.json": b'{"a": 1}'}


@pytest.fixture()
def shard(tmp_path: Path) -> tuple[Path, dict[str, dict[str, MemberSpec]]]:
    """A dataset folder with one shard of two samples, and each member's spec."""
    specs: dict[str, dict[str, MemberSpec]] = {}
    with ShardWriter(tmp_path, "shards/s.tar") as writer:
        for key in ("a", "b"):
            locations = writer.add(key, MEMBERS)
            specs[key] = {
                name.split(".")[0]: MemberSpec(
                    key,
                    name.split(".")[0],
                    loc.offset,
                    loc.size,
                    loc.crc32c,
                    "ground.jpg" if name.startswith("ground") else None,
                )
                for name, loc in locations.items()
            }
    return tmp_path, specs


def check(root: Path, spec: MemberSpec) -> str | None:
    path = shard_path(root, "shards/s.tar")
    with open(path, "rb") as fh:

        def read(offset: int, size: int) -> bytes:
            fh.seek(offset)
            return fh.read(size)

        data, problem = check_member(spec, read, os.path.getsize(path))
    assert (data is None) == (problem is not None)
    return problem


def test_intact_members_pass(shard: tuple[Path, dict]) -> None:
    root, specs = shard
    for members in specs.values():
        for spec in members.values():
            assert check(root, spec) is None, spec


def test_a_member_of_another_sample_is_caught_by_its_header(shard: tuple[Path, dict]) -> None:
    root, specs = shard
    a, b = specs["a"]["ortho"], specs["b"]["ortho"]
    swapped = MemberSpec("a", "ortho", b.offset, b.size, b.crc32c)  # b's bytes, b's checksum
    assert check(root, swapped) == f"tar header names 'b.ortho.png' at offset {b.offset - BLOCK}"
    other_field = MemberSpec("a", "ortho", specs["a"]["meta"].offset, a.size, a.crc32c)
    assert "tar header names 'a.meta.json'" in check(root, other_field)
    ground = specs["a"]["ground"]
    renamed = MemberSpec("a", "ground", ground.offset, ground.size, ground.crc32c, "ground.png")
    assert "tar header names 'a.ground.jpg'" in check(root, renamed)


def test_sizes_offsets_and_checksums(shard: tuple[Path, dict]) -> None:
    root, specs = shard
    meta = specs["b"]["meta"]
    cases = {
        "size 9 in the manifest, 8 in the tar header": {"size": meta.size + 1},
        "not after a tar header": {"offset": meta.offset + 1},
        "past the end of the shard": {"size": 1 << 60},
        "no valid offset/size": {"offset": None},
        "checksum mismatch": {"crc32c": (meta.crc32c or 0) ^ 1},
    }
    for reason, change in cases.items():
        spec = MemberSpec(**{**meta.__dict__, **change})
        problem = check(root, spec)
        assert problem is not None and reason in problem, (reason, problem)
    assert check(root, MemberSpec(**{**meta.__dict__, "crc32c": None})) is None  # unknown
    assert check(root, MemberSpec(**{**meta.__dict__, "crc32c": -1})) is None


@pytest.mark.parametrize(
    ("path", "reason"),
    [
        ("../../etc/passwd", "leaves the dataset folder"),
        ("shards/../../s.tar", "leaves the dataset folder"),
        ("/dev/zero", "is absolute"),
        ("\\\\server\\share\\s.tar", "is absolute"),
        ("C:/s.tar", "is absolute"),
        ("", "bad shard path"),
        ("shards/s\x00.tar", "NUL byte"),
        ("shards", "not a regular file"),
    ],
)
def test_shard_paths_stay_inside_the_dataset(
    shard: tuple[Path, dict], path: str, reason: str
) -> None:
    root, _ = shard
    with pytest.raises(DatasetError, match=reason) as err:
        shard_path(root, path, "a.ortho.png")
    assert err.value.member == "a.ortho.png" and path in err.value.path


def test_symlinks_and_fifos(
    shard: tuple[Path, dict], tmp_path_factory: pytest.TempPathFactory
) -> None:
    root, _ = shard
    outside = tmp_path_factory.mktemp("outside") / "x.tar"
    outside.write_bytes(b"x" * 1024)
    (root / "shards" / "out.tar").symlink_to(outside)
    with pytest.raises(DatasetError, match="resolves outside the dataset folder"):
        shard_path(root, "shards/out.tar")
    (root / "shards" / "in.tar").symlink_to(root / "shards" / "s.tar")  # inside: fine
    assert shard_path(root, "shards/in.tar") == (root / "shards" / "s.tar").resolve()
    os.mkfifo(root / "shards" / "fifo.tar")  # opening it would block
    with pytest.raises(DatasetError, match="not a regular file"):
        shard_path(root, "shards/fifo.tar")
    with pytest.raises(FileNotFoundError):
        shard_path(root, "shards/missing.tar")


def test_dataset_json_is_required_with_a_ray_stride(tmp_path: Path) -> None:
    path = tmp_path / "dataset.json"
    with pytest.raises(DatasetError, match=r"dataset\.json: missing"):
        read_dataset_info(tmp_path)
    bad = {
        "[1, 2]": "expected a JSON object",
        "{": "unreadable",
        "{}": "config.geometry.ray_stride: expected a positive integer, got None",
        '{"config": {"geometry": {"ray_stride": 0}}}': "ray_stride: expected a positive",
        '{"config": {"geometry": {"ray_stride": true}}}': "ray_stride: expected a positive",
        '{"config": {"geometry": {"ray_stride": 8}}, "chip": {"size_px": "64"}}': "size_px",
        '{"config": {"geometry": {"ray_stride": 8}}, "crs": 4326}': "crs: expected a string",
    }
    for text, reason in bad.items():
        path.write_text(text)
        with pytest.raises(DatasetError, match=reason):
            read_dataset_info(tmp_path)
    path.write_text(json.dumps({"config": {"geometry": {"ray_stride": 8}}, "crs": "WKT"}))
    info = read_dataset_info(tmp_path)
    assert (info.ray_stride, info.crs, info.chip_px) == (8, "WKT", None)


def test_an_empty_list_of_values_is_an_argument_error() -> None:
    with pytest.raises(ArgumentError, match="split: expected a string or a non-empty list"):
        strings([], "split")
    assert strings(("train",), "split") == ["train"]


def test_read_member_stays_inside_the_dataset_and_the_shard(shard: tuple[Path, dict]) -> None:
    root, specs = shard
    meta = specs["a"]["meta"]
    assert (
        read_member(root, MemberLocation("shards/s.tar", meta.offset, meta.size))
        == (MEMBERS["meta.json"])
    )
    cases = {
        "../../etc/passwd": (meta.offset, "leaves the dataset folder"),
        "/dev/zero": (meta.offset, "is absolute"),
        "shards/s.tar": (1 << 60, "past the end of the shard"),
    }
    for path, (size, reason) in cases.items():
        with pytest.raises(DatasetError, match=reason) as err:
            read_member(root, MemberLocation(path, meta.offset, size), name="a.meta.json")
        assert err.value.path == path and err.value.member == "a.meta.json"
