"""Downloads against a real loopback server: verify, resume, retry, refuse; nothing half-written."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path, PurePosixPath

import numpy as np
import pytest
import requests

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import Cache, archive_path
from mars_pairs.fetch.download import Downloader, FetchPolicy, RemoteFile, Validator, sidecar
from support import fetch_server

served = fetch_server.served  # the loopback server fixture
FAST = FetchPolicy(retries=2, backoff_s=0.01, connect_timeout_s=2.0, read_timeout_s=0.4, workers=2)
REL = "DATA/RDR/SURFACE/1429/PRODUCT.IMG"


def _publish(root: Path, rel: str = REL, n: int = 300_000) -> bytes:
    data = np.random.default_rng(7).integers(0, 256, n, dtype=np.uint8).tobytes()
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return data


def _remote(srv, data: bytes, rel: str = REL, *, md5: bool = True, size: bool = True):
    return RemoteFile(
        PurePosixPath(rel),
        f"{srv.url}/{rel}",
        size=len(data) if size else None,
        md5=hashlib.md5(data).hexdigest() if md5 else None,
    )


def _no_debris(cache_root: Path) -> list[str]:
    return sorted(str(p.relative_to(cache_root)) for p in cache_root.rglob("*") if p.is_file())


def test_download_verifies_and_a_rerun_fetches_nothing(served, tmp_path):
    srv, root = served
    data = _publish(root)
    dl = Downloader(Cache(tmp_path / "cache"), FAST)
    first = dl.fetch(_remote(srv, data))
    assert first.status == "downloaded" and first.path.read_bytes() == data
    assert first.path == (tmp_path / "cache" / REL).resolve()
    srv.reset_log()
    again = dl.fetch(_remote(srv, data))
    assert again.status == "cached" and srv.log == []


def test_500s_are_retried_then_succeed(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, "500", "500")
    res = Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert res.path.read_bytes() == data
    assert [e.status for e in srv.requests_for(REL)] == [500, 500, 200]


def test_persistent_500_fails_naming_the_url_and_writes_nothing(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, *["500"] * 10)
    with pytest.raises(FetchError, match=r"127\.0\.0\.1.*PRODUCT\.IMG: HTTP 500") as info:
        Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert info.value.url.endswith(REL)
    assert len(srv.requests_for(REL)) == FAST.retries + 1
    assert _no_debris(tmp_path / "c") == []


def test_404_fails_at_once(served, tmp_path):
    srv, _ = served
    remote = RemoteFile(PurePosixPath("nope/X.LBL"), f"{srv.url}/nope/X.LBL")
    with pytest.raises(FetchError, match="HTTP 404"):
        Downloader(Cache(tmp_path / "c"), FAST).fetch(remote)
    assert len(srv.requests_for("nope/X.LBL")) == 1
    assert _no_debris(tmp_path / "c") == []


def test_slow_answers_time_out_and_are_retried(served, tmp_path):
    srv, root = served
    data = _publish(root, n=1000)
    srv.fault(REL, "slow")
    res = Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert res.path.read_bytes() == data and len(srv.requests_for(REL)) == 2


def test_always_slow_fails_naming_the_url(served, tmp_path):
    srv, root = served
    data = _publish(root, n=1000)
    srv.fault(REL, *["slow"] * 10)
    with pytest.raises(FetchError, match=r"PRODUCT\.IMG: no answer after 2 retries.*Timeout"):
        Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert _no_debris(tmp_path / "c") == []


def test_truncated_body_resumes_with_a_range_request(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, "truncate")
    res = Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert res.path.read_bytes() == data
    first, second = srv.requests_for(REL)
    assert first.range is None and 0 < first.sent < len(data)
    kept = int(second.range.removeprefix("bytes=").removesuffix("-"))
    assert 0 < kept <= first.sent and second.status == 206
    assert second.sent == len(data) - kept  # the rest only


def test_md5_mismatch_is_retried_then_fails_and_leaves_nothing(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, "corrupt")
    res = Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert res.path.read_bytes() == data  # one bad copy, then a good one
    srv.fault(REL, *["corrupt"] * 10)
    with pytest.raises(FetchError, match="MD5"):
        Downloader(Cache(tmp_path / "d"), FAST).fetch(_remote(srv, data))
    assert _no_debris(tmp_path / "d") == []


def test_wrong_size_fails_naming_both_sizes(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, *["longer"] * 10)
    with pytest.raises(FetchError, match=f"{len(data) + 100} bytes, the archive says {len(data)}"):
        Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data))
    assert not (tmp_path / "c" / REL).exists()


def test_without_md5_a_short_body_is_still_caught_by_content_length(served, tmp_path):
    srv, root = served
    data = _publish(root)
    srv.fault(REL, *["truncate"] * 10)
    with pytest.raises(FetchError):
        Downloader(Cache(tmp_path / "c"), FAST).fetch(_remote(srv, data, md5=False, size=False))
    assert not (tmp_path / "c" / REL).exists()  # only the .part, never the real name


def test_a_part_left_by_a_kill_is_resumed_with_if_range(served, tmp_path):
    srv, root = served
    data = _publish(root)
    cache = Cache(tmp_path / "c")
    part = cache.path(REL).with_name("PRODUCT.IMG.part")
    part.parent.mkdir(parents=True)
    part.write_bytes(data[:123_456])
    url = f"{srv.url}/{REL}"
    etag = requests.head(url, timeout=5).headers["ETag"]  # what the first answer carried
    sidecar(part).write_bytes(Validator(url, etag).dump(None))
    res = Downloader(cache, FAST).fetch(_remote(srv, data))
    assert res.status == "resumed" and res.path.read_bytes() == data
    (req,) = srv.requests_for(REL)
    assert req.range == "bytes=123456-" and req.sent == len(data) - 123_456
    assert req.if_range == etag and req.status == 206
    assert not part.exists() and not sidecar(part).exists()


def test_a_part_without_a_validator_is_restarted_not_stitched(served, tmp_path):
    srv, root = served
    data = _publish(root)
    cache = Cache(tmp_path / "c")
    part = cache.path(REL).with_name("PRODUCT.IMG.part")
    part.parent.mkdir(parents=True)
    part.write_bytes(b"x" * 123_456)  # nothing says which version of the file this began
    res = Downloader(cache, FAST).fetch(_remote(srv, data, md5=False))
    assert res.status == "downloaded" and res.path.read_bytes() == data
    (req,) = srv.requests_for(REL)
    assert req.range is None and req.sent == len(data)


@pytest.mark.parametrize(
    "entry", ["../etc/passwd", "/etc/passwd", "a/../../b", "a\\..\\b", "C:/x", "", "a/..", "./.."]
)
def test_paths_that_escape_the_root_are_refused(entry):
    with pytest.raises(FetchError, match=r"refused|empty"):
        archive_path(entry)


def test_symlinks_inside_the_cache_are_refused(tmp_path):
    cache = Cache(tmp_path / "c")
    (tmp_path / "c").mkdir()
    (tmp_path / "elsewhere").mkdir()
    os.symlink(tmp_path / "elsewhere", tmp_path / "c" / "DATA")
    with pytest.raises(FetchError, match="symlink"):
        cache.path("DATA/x.LBL")
    assert cache.path("./INDEX/RDRINDEX.LBL") == (tmp_path / "c" / "INDEX" / "RDRINDEX.LBL")


def _whole_part(cache: Cache, url: str, data: bytes) -> Path:
    """A ``.part`` holding the whole file, with the validator of the answer that began it."""
    part = cache.path(REL).with_name("PRODUCT.IMG.part")
    part.parent.mkdir(parents=True, exist_ok=True)
    part.write_bytes(data)
    sidecar(part).write_bytes(
        Validator(url, requests.head(url, timeout=5).headers["ETag"]).dump(None)
    )
    return part


@pytest.mark.parametrize("known_size", [True, False])
def test_a_whole_part_is_checked_and_kept_not_fetched_again(served, tmp_path, known_size):
    """The resume of a whole part is answered 416 with ``Content-Range: bytes */N``."""
    srv, root = served
    data = _publish(root)
    cache = Cache(tmp_path / "c")
    part = _whole_part(cache, f"{srv.url}/{REL}", data)
    res = Downloader(cache, FAST).fetch(_remote(srv, data, md5=known_size, size=known_size))
    assert res.status == "resumed" and res.bytes_received == 0 and res.path.read_bytes() == data
    (req,) = srv.requests_for(REL)
    assert (req.range, req.status) == (f"bytes={len(data)}-", 416)
    assert not part.exists() and not sidecar(part).exists()


def test_a_416_without_the_size_asks_a_head(served, tmp_path):
    srv, root = served
    data = _publish(root)
    cache = Cache(tmp_path / "c")
    _whole_part(cache, f"{srv.url}/{REL}", data)
    srv.reset_log()
    srv.fault(REL, "416-bare")
    res = Downloader(cache, FAST).fetch(_remote(srv, data, md5=False, size=False))
    assert res.status == "resumed" and res.path.read_bytes() == data
    assert [e.status for e in srv.requests_for(REL)] == [416]
    assert [e.status for e in srv.requests_for(REL, "HEAD")] == [200]


def test_a_whole_part_that_fails_its_check_is_fetched_again(served, tmp_path):
    srv, root = served
    data = _publish(root)
    cache = Cache(tmp_path / "c")
    _whole_part(cache, f"{srv.url}/{REL}", data[:-1] + bytes([data[-1] ^ 0xFF]))
    res = Downloader(cache, FAST).fetch(_remote(srv, data))  # its MD5 differs
    assert res.status == "downloaded" and res.path.read_bytes() == data
    assert [e.status for e in srv.requests_for(REL)] == [416, 200]
