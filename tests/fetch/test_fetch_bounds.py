"""A fetch is bounded in time and size against servers that misbehave on purpose (a raw HTTP
server on 127.0.0.1, ``support.hostile_server``): every file finishes or fails with a
FetchError naming its URL, within its deadline, and no part above its size limit is left.

No test times the code: each runs the fetch on a thread and only checks that it ended (the
generous join bound is what a hang would hit, not a budget), with short deadlines set through
the policy."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path, PurePosixPath

import pytest

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import Cache
from mars_pairs.fetch.download import MAX_BYTES, Downloader, FetchPolicy, RemoteFile
from mars_pairs.fetch.run import _cancelled_on_interrupt
from support.hostile_server import hostile_server  # noqa: F401  (the fixture)

HANG = 120.0  # seconds a thread is given before the test calls it hung (far past any deadline)


def policy(**kw) -> FetchPolicy:
    base = dict(retries=1, backoff_s=0.01, connect_timeout_s=5.0, read_timeout_s=5.0)
    return FetchPolicy(**(base | kw))


def remote(server, path: str, kind: str = "data", size: int | None = None) -> RemoteFile:
    rel = PurePosixPath("files" + path + (".csv" if kind == "places" else ".bin"))
    return RemoteFile(rel, server.url + path, kind=kind, size=size)


def run(dl: Downloader, rf: RemoteFile) -> BaseException | object:
    """``dl.fetch(rf)`` on a thread; its result or exception (asserts it ended)."""
    out: list[BaseException | object] = []

    def go() -> None:
        try:
            out.append(dl.fetch(rf))
        except BaseException as exc:
            out.append(exc)

    t = threading.Thread(target=go, daemon=True)
    t.start()
    t.join(HANG)
    assert not t.is_alive(), f"{rf.url}: the fetch did not end"
    return out[0]


def parts(root: Path) -> list[Path]:
    return [p for p in root.rglob("*.part")]


@pytest.mark.parametrize("path", ["/slow-body", "/slow-headers"])
def test_a_trickling_server_fails_at_the_deadline(hostile_server, tmp_path, path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy(deadline_s=2.0))
    err = run(dl, remote(hostile_server, path))
    assert isinstance(err, FetchError), err
    assert hostile_server.url + path in str(err) and "deadline of 2 s" in str(err)


def test_retry_after_is_capped(hostile_server, tmp_path) -> None:  # noqa: F811
    # Retry-After: 100000 would sleep 21,600 s (urllib3's cap); here 0.2 s, two attempts
    dl = Downloader(Cache(tmp_path), policy(retry_after_max_s=0.2, deadline_s=60.0))
    err = run(dl, remote(hostile_server, "/retry-after"))
    assert isinstance(err, FetchError) and "503" in str(err), err
    assert hostile_server.requests["/retry-after"] >= 2  # it did retry, after the capped wait


def test_retry_after_never_outlasts_the_deadline(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy(retry_after_max_s=1000.0, deadline_s=1.0))
    err = run(dl, remote(hostile_server, "/retry-after"))
    assert isinstance(err, FetchError) and "deadline" in str(err), err


def test_a_malformed_content_length_is_a_fetch_error(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy())
    err = run(dl, remote(hostile_server, "/bad-length"))
    assert isinstance(err, FetchError), err
    assert "malformed Content-Length header 'abc'" in str(err)
    assert not parts(tmp_path)


def test_an_endless_body_stops_at_the_kinds_limit(hostile_server, tmp_path) -> None:  # noqa: F811
    limits = dict(MAX_BYTES) | {"places": 64 << 10}
    dl = Downloader(Cache(tmp_path), policy(max_bytes=limits))
    err = run(dl, remote(hostile_server, "/endless", kind="places"))
    assert isinstance(err, FetchError) and "65536-byte limit of a places file" in str(err), err
    assert not parts(tmp_path) and not list(tmp_path.rglob("endless*"))
    assert hostile_server.requests["/endless"] == 1  # refused, not retried


def test_an_endless_body_stops_at_the_archives_size(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy())
    err = run(dl, remote(hostile_server, "/endless", kind="places", size=5000))
    assert isinstance(err, FetchError) and "the 5000 bytes the archive gives it" in str(err), err
    assert not parts(tmp_path)


def test_a_huge_content_length_is_refused_before_the_body(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy())
    err = run(dl, remote(hostile_server, "/huge", kind="pds4_label"))
    assert isinstance(err, FetchError), err
    assert "refused: 1000000000000000 bytes, over the 16777216-byte limit" in str(err)
    assert not parts(tmp_path)


def test_an_encoding_never_asked_for_is_refused(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy())
    err = run(dl, remote(hostile_server, "/gzip", kind="places"))
    assert isinstance(err, FetchError) and "encoded (gzip)" in str(err), err
    assert not parts(tmp_path)
    assert sum(p.stat().st_size for p in tmp_path.rglob("*") if p.is_file()) < 1 << 20


def test_an_interrupt_cancels_queued_and_running_downloads(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy(deadline_s=600.0, workers=2))
    files = [remote(hostile_server, "/slow-body") for _ in range(20)]
    files = [
        RemoteFile(PurePosixPath(f"q/{k}.bin"), f.url, kind="data") for k, f in enumerate(files)
    ]
    done = threading.Event()
    caught: list[BaseException] = []

    def driver() -> None:
        try:
            with _cancelled_on_interrupt(dl, ThreadPoolExecutor(max_workers=2)) as pool:
                futures = [pool.submit(dl.fetch, f) for f in files]
                while hostile_server.requests["/slow-body"] < 2:
                    threading.Event().wait(0.05)
                raise KeyboardInterrupt  # as Ctrl-C does in the loop over the futures
        except KeyboardInterrupt as exc:
            caught.append(exc)
            for fut in futures:
                assert fut.cancelled() or isinstance(fut.exception(), FetchError)
        finally:
            done.set()

    t = threading.Thread(target=driver, daemon=True)
    t.start()
    assert done.wait(HANG), "the interrupted fetch did not stop"
    assert caught, "the interrupt did not reach the caller"
    assert hostile_server.requests["/slow-body"] <= 2  # the queue was never started
    assert dl.cancelled


def test_a_good_file_still_downloads(hostile_server, tmp_path) -> None:  # noqa: F811
    dl = Downloader(Cache(tmp_path), policy(deadline_s=30.0))
    out = run(dl, remote(hostile_server, "/ok"))
    assert not isinstance(out, BaseException), out
    assert out.path.read_bytes() == b"0123456789abcdef"
