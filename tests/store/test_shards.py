"""Shard members carry CRC-32C checksums; damaged reads name the shard and the member."""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

import numpy as np
import pytest

from mars_pairs.errors import DatasetError
from mars_pairs.store.integrity import checksum
from mars_pairs.store.manifest import MANIFEST_SCHEMA
from mars_pairs.store.members import MEMBERS
from mars_pairs.store.shards import (
    MemberLocation,
    ShardWriter,
    read_member,
    read_members,
    ustar_header,
)


def test_checksum_is_crc32c() -> None:
    # the standard CRC-32C check value (RFC 3720 / iSCSI)
    assert checksum(b"123456789") == 0xE3069283
    assert checksum(b"") == 0


def test_every_member_has_a_checksum_column() -> None:
    for m in MEMBERS:
        assert MANIFEST_SCHEMA.field(f"{m}_crc32c").type == "int64"


def test_locations_carry_the_checksum_and_verify_catches_a_flip(tmp_path: Path) -> None:
    with ShardWriter(tmp_path, "shards/s.tar") as shard:
        locs = shard.add("k1", {"dem.npy": b"x" * 1000, "meta.json": b"{}"})
    loc = locs["dem.npy"]
    assert loc.crc32c == checksum(b"x" * 1000)
    assert read_member(tmp_path, loc, verify=True) == b"x" * 1000
    path = tmp_path / "shards/s.tar"
    data = bytearray(path.read_bytes())
    data[loc.offset + 500] ^= 0xFF
    path.write_bytes(bytes(data))
    assert len(read_member(tmp_path, loc)) == 1000  # unverified: the bytes as they are
    with pytest.raises(DatasetError, match=r"shards/s\.tar: k1\.dem\.npy: checksum mismatch"):
        read_member(tmp_path, loc, name="k1.dem.npy", verify=True)


def test_short_reads_and_missing_shards_name_the_shard(tmp_path: Path) -> None:
    with ShardWriter(tmp_path, "s.tar") as shard:
        loc = shard.add("k", {"x.bin": b"1234"})["x.bin"]
    too_long = MemberLocation(loc.shard, loc.offset + 10_000, 4)
    with pytest.raises(DatasetError, match=r"s\.tar: k\.x\.bin: short read"):
        read_member(tmp_path, too_long, name="k.x.bin")
    with pytest.raises(DatasetError, match=r"gone\.tar: cannot read"):
        read_member(tmp_path, MemberLocation("gone.tar", 0, 4))


def test_read_members_opens_each_shard_once_and_names_the_member(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mars_pairs.store import shards

    with ShardWriter(tmp_path, "s.tar") as shard:
        locs = shard.add("k", {"a.bin": b"aa", "b.bin": b"bbb", "c.bin": b"c"})
    resolved: list[str] = []
    original = shards.shard_path

    def counted(root: Path, shard: str, member: str | None = None) -> Path:
        resolved.append(shard)
        return original(root, shard, member)

    monkeypatch.setattr(shards, "shard_path", counted)
    got = read_members(tmp_path, locs, key="k", verify=True)
    assert got == {"a.bin": b"aa", "b.bin": b"bbb", "c.bin": b"c"} and resolved == ["s.tar"]
    flipped = {**locs, "b.bin": MemberLocation("s.tar", locs["b.bin"].offset, 3, 0)}
    with pytest.raises(DatasetError, match=r"s\.tar: k\.b\.bin: checksum mismatch"):
        read_members(tmp_path, flipped, key="k", verify=True)


def test_repeated_keys_are_counted_and_sorted() -> None:
    import pyarrow as pa

    from mars_pairs.store.integrity import repeated_keys

    keys = pa.chunked_array([["b", "a", "b"], ["c", "a", "b"]])
    assert repeated_keys(keys) == [("a", 2), ("b", 3)]
    assert repeated_keys(pa.array(["x", "y"])) == []


def _tarfile_bytes(samples: list[tuple[str, dict[str, bytes]]]) -> bytes:
    """The shard tarfile itself writes for ``samples`` (the headers ``ShardWriter`` fixes)."""
    buf = io.BytesIO()
    with tarfile.TarFile(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for key, members in samples:
            for fld, data in members.items():
                info = tarfile.TarInfo(f"{key}.{fld}")
                info.size, info.mtime, info.mode = len(data), 0, 0o644
                info.uname = info.gname = ""
                tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def test_a_shard_is_the_tar_tarfile_writes_byte_for_byte(tmp_path):
    rng = np.random.default_rng(3)
    sizes = [0, 1, 511, 512, 513, 10240, 3001]
    samples = [
        (f"key{i}" + "k" * (88 if i == 2 else 0),  # one name of 100 bytes
         {f"f{j}.bin": rng.integers(0, 256, sizes[(i + j) % len(sizes)], np.uint8).tobytes()
          for j in range(3)})
        for i in range(6)
    ]  # fmt: skip
    with ShardWriter(tmp_path, "shard.tar") as shard:
        locations = [shard.add(key, members) for key, members in samples]
    raw = (tmp_path / "shard.tar").read_bytes()
    assert raw == _tarfile_bytes(samples)
    for (_, members), locs in zip(samples, locations, strict=True):
        for fld, data in members.items():
            assert raw[locs[fld].offset : locs[fld].offset + locs[fld].size] == data


_ERRORS = "surrogateescape"


@pytest.mark.parametrize("size", [0, 1, 512, 10**6, (8 << 30) - 1, 8 << 30])
@pytest.mark.parametrize("name", ["a.b", "x" * 100, "y" * 101, "d/" + "z" * 100, "caf\u00e9.json"])
def test_member_headers_are_tarfiles(name, size):
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = size, 0, 0o644
    info.uname = info.gname = ""
    try:
        expected: bytes | str = info.tobuf(tarfile.USTAR_FORMAT, tarfile.ENCODING, _ERRORS)
    except ValueError as exc:  # a name too long for ustar, a size past its 8 GiB
        expected = str(exc)
    try:
        got: bytes | str = ustar_header(name, size)
    except ValueError as exc:
        got = str(exc)
    assert got == expected
