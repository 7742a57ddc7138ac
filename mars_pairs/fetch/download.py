"""Verified, resumable, atomic downloads into the cache with requests + urllib3 retries.

One file: ``<cache>/<rel>`` appears only complete and verified (size, and MD5 when the archive
gives one), by a rename of ``<rel>.part``. An interrupted download leaves the ``.part`` file,
and the next attempt (or rerun) asks for the rest with ``Range: bytes=N-``; a server that
ignores the Range header (200) restarts it. A file already in the cache is not fetched again.

Retries: urllib3's ``Retry`` on the session retries connection errors, read timeouts before
the headers and 429/5xx statuses with exponential backoff; failures inside the body (truncated
bodies, stalls, wrong sizes, MD5 mismatches) are retried by this module's loop with the same
backoff. After the last attempt a ``FetchError`` names the URL and the reason.
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import requests
from requests.adapters import HTTPAdapter
from urllib3.util.retry import Retry

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import Cache

_CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+|\*)")
USER_AGENT = "mars-pairs-fetch/0.1"


@dataclass(frozen=True)
class RemoteFile:
    """One archive file: its archive-relative path, URL and what the archive says it is."""

    rel: PurePosixPath
    url: str
    size: int | None = None  # bytes
    md5: str | None = None  # hex digest, lower case


@dataclass(frozen=True)
class FetchPolicy:
    """Retries, backoff (seconds, doubled per retry), timeouts (seconds) and parallelism."""

    retries: int = 4
    backoff_s: float = 0.5
    backoff_max_s: float = 30.0
    connect_timeout_s: float = 10.0
    read_timeout_s: float = 60.0
    workers: int = 4
    chunk_bytes: int = 1 << 14  # what a killed download keeps is written in these steps


@dataclass(frozen=True)
class FetchResult:
    """What one ``fetch`` did: ``status`` is "cached", "downloaded" or "resumed"."""

    remote: RemoteFile
    path: Path
    status: str
    bytes_received: int


class _Retryable(Exception):
    """A failure inside the body (or a bad size/MD5): worth another attempt."""


class Downloader:
    """Fetches ``RemoteFile``s into a ``Cache``; thread-safe (one requests Session per thread)."""

    def __init__(self, cache: Cache, policy: FetchPolicy | None = None) -> None:
        self.cache = cache
        self.policy = policy or FetchPolicy()
        self._local = threading.local()

    # -- sessions --------------------------------------------------------------------------
    def session(self) -> requests.Session:
        """This thread's session, with urllib3 retries for connections and 5xx statuses."""
        s = getattr(self._local, "session", None)
        if s is None:
            p = self.policy
            retry = Retry(
                total=p.retries,
                connect=p.retries,
                read=p.retries,
                status=p.retries,
                backoff_factor=p.backoff_s,
                backoff_max=p.backoff_max_s,
                status_forcelist=(429, 500, 502, 503, 504),
                allowed_methods=frozenset({"GET", "HEAD"}),
                raise_on_status=False,
                respect_retry_after_header=True,
            )
            s = requests.Session()
            adapter = HTTPAdapter(max_retries=retry, pool_maxsize=max(4, p.workers))
            s.mount("http://", adapter)
            s.mount("https://", adapter)
            s.headers["User-Agent"] = USER_AGENT
            self._local.session = s
        return s

    def close(self) -> None:
        """Close this thread's session."""
        s = getattr(self._local, "session", None)
        if s is not None:
            s.close()
            self._local.session = None

    def head_size(self, url: str) -> int | None:
        """The Content-Length a HEAD request gives (None when the server does not say)."""
        timeout = (self.policy.connect_timeout_s, self.policy.read_timeout_s)
        try:
            r = self.session().head(url, timeout=timeout, allow_redirects=True)
        except requests.RequestException as exc:
            raise FetchError(url, f"HEAD failed: {type(exc).__name__}: {_short(exc)}") from None
        if r.status_code != 200:
            raise FetchError(url, f"HTTP {r.status_code} {r.reason} (HEAD)")
        length = r.headers.get("Content-Length")
        return int(length) if length is not None and length.isdigit() else None

    # -- one file --------------------------------------------------------------------------
    def fetch(
        self, remote: RemoteFile, on_bytes: Callable[[int], None] | None = None
    ) -> FetchResult:
        """Download ``remote`` to the cache (or find it there); FetchError after the retries."""
        target = self.cache.path(remote.rel, where=remote.url)
        if target.is_file() and (remote.size is None or target.stat().st_size == remote.size):
            return FetchResult(remote, target, "cached", 0)
        target.parent.mkdir(parents=True, exist_ok=True)
        part = target.with_name(target.name + ".part")
        if part.is_symlink():
            raise FetchError(remote.url, f"refused: {part} is a symlink")
        received, resumed = 0, part.is_file() and part.stat().st_size > 0
        last = "no attempt made"
        for attempt in range(self.policy.retries + 1):
            if attempt:
                time.sleep(
                    min(self.policy.backoff_max_s, self.policy.backoff_s * 2 ** (attempt - 1))
                )
            try:
                received += self._attempt(remote, part, on_bytes)
                self._verify_md5(remote, part)
            except _Retryable as exc:
                last = str(exc)
                continue
            except requests.RequestException as exc:
                last = f"{type(exc).__name__}: {_short(exc)}"
                continue
            os.replace(part, target)
            return FetchResult(remote, target, "resumed" if resumed else "downloaded", received)
        raise FetchError(remote.url, f"failed after {self.policy.retries + 1} attempts: {last}")

    def _attempt(
        self, remote: RemoteFile, part: Path, on_bytes: Callable[[int], None] | None
    ) -> int:
        """One GET (ranged when a part exists); appends to ``part``; returns bytes received."""
        offset = part.stat().st_size if part.is_file() else 0
        if remote.size is not None and offset > remote.size:
            part.unlink()
            offset = 0
        if remote.size is not None and offset == remote.size:
            return 0  # complete already: the caller checks its digest
        headers = {"Range": f"bytes={offset}-"} if offset else {}
        timeout = (self.policy.connect_timeout_s, self.policy.read_timeout_s)
        try:
            response = self.session().get(remote.url, headers=headers, stream=True, timeout=timeout)
        except requests.RequestException as exc:  # urllib3 has retried connecting and waiting
            raise FetchError(
                remote.url,
                f"no answer after {self.policy.retries} retries: {type(exc).__name__}: "
                f"{_short(exc)}",
            ) from None
        with response as r:
            if r.status_code == 416 and offset:
                part.unlink()
                raise _Retryable(f"HTTP 416 for a resume at byte {offset}; restarting")
            if r.status_code == 404 or r.status_code == 410:
                raise FetchError(
                    remote.url, f"HTTP {r.status_code} {r.reason} (not in the archive)"
                )
            if r.status_code not in (200, 206):  # urllib3 has already retried 429/5xx
                raise FetchError(
                    remote.url,
                    f"HTTP {r.status_code} {r.reason} after {self.policy.retries} retries",
                )
            if r.status_code == 200 or not offset:
                offset, mode = 0, "wb"  # the server sent the whole file
            else:
                start, total = _content_range(r.headers.get("Content-Range", ""))
                if start != offset:
                    part.unlink()
                    raise _Retryable(f"Content-Range starts at {start}, asked for {offset}")
                mode = "ab"
            length = r.headers.get("Content-Length")
            total = offset + int(length) if length is not None else None
            if r.status_code == 206 and mode == "ab":
                total = _content_range(r.headers["Content-Range"])[1] or total
            if remote.size is not None and total is not None and total != remote.size:
                raise _Retryable(f"server sends {total} bytes, the archive says {remote.size}")
            got = 0
            with open(part, mode) as fh:
                for chunk in r.iter_content(self.policy.chunk_bytes):
                    fh.write(chunk)
                    got += len(chunk)
                    if on_bytes is not None:
                        on_bytes(len(chunk))
                fh.flush()
                os.fsync(fh.fileno())
        size = part.stat().st_size
        expected = remote.size if remote.size is not None else total
        if expected is not None and size != expected:
            raise _Retryable(f"received {size} bytes of {expected}")
        return got

    def _verify_md5(self, remote: RemoteFile, part: Path) -> None:
        """Compare the part file's MD5 with the archive's; a mismatch discards the part."""
        if remote.md5 is None:
            return
        digest = hashlib.md5(usedforsecurity=False)
        with open(part, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        if digest.hexdigest() != remote.md5.lower():
            part.unlink()
            raise _Retryable(f"MD5 {digest.hexdigest()} differs from the archive's {remote.md5}")


def _content_range(header: str) -> tuple[int | None, int | None]:
    """(first byte, total size) of a ``Content-Range: bytes a-b/n`` header."""
    m = _CONTENT_RANGE.match(header.strip())
    if not m:
        return None, None
    return int(m[1]), None if m[3] == "*" else int(m[3])


def _short(exc: BaseException) -> str:
    text = str(exc)
    return text if len(text) <= 160 else text[:157] + "..."
