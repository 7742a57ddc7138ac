"""Verified, resumable, atomic downloads into the cache with requests + urllib3 retries.

One file: ``<cache>/<rel>`` appears only complete and verified, by a rename of ``<rel>.part``:
its size (the archive's, else the answer's Content-Length), its MD5 when the archive gives one,
and its content (``validate.check_file`` for its kind: a label parses, a table has its label's
size, an image decodes in full); an HTML answer (``Content-Type: text/html``) is refused for
any file that is not HTML. A file failing a check is discarded, never renamed into place.

Validators (ETag, Last-Modified) are kept beside the files as ``<name>.meta.json``:

- resume: the answer that starts a ``.part`` leaves its validator in ``<name>.part.meta.json``;
  an interrupted download (a retry or a rerun) asks for the rest with ``Range: bytes=N-`` and
  ``If-Range: <that validator>``, so a remote file replaced meanwhile comes whole (200), never
  stitched; a part without a validator is restarted from zero. A part that is already whole
  (the server answers 416 with the file's size, ``Content-Range: bytes */N``, or a HEAD with
  the part's validator gives that size) is checked and renamed into place, not fetched again.
- revalidation: a ``mutable`` file (archive tables: indexes, inventories, collection labels,
  PLACES) is asked for on every fetch with ``If-None-Match`` / ``If-Modified-Since`` from its
  ``<name>.meta.json``; 304 keeps the cached file, 200 replaces it (checked, atomically).
  Products (labels, images) are immutable: once in the cache they are not requested again;
  a cached one failing ``validate.quick_check`` (an HTML page, a JPEG without its end marker,
  a cut label: what older releases could keep) is removed and fetched again.

Retries: urllib3's ``Retry`` on the session retries connection errors, read timeouts before
the headers and 429/5xx statuses with exponential backoff (a ``Retry-After`` obeyed up to
``FetchPolicy.retry_after_max_s``); failures inside the body (truncated bodies, stalls, wrong
sizes, MD5 mismatches) are retried by this module's loop with the same backoff. After the last
attempt a ``FetchError`` names the URL and the reason.

Bounds: every file has a total deadline (``FetchPolicy.deadline_s``, all attempts and waits
included: a socket timeout alone lets a server trickle headers or a body at 1 byte/s for ever),
enforced by shutting the file's sockets down from a timer thread (``_Sockets``), which also
cancels every download in flight at once when the run is interrupted (``Downloader.cancel``).
No file grows past the size the archive gives it, else its answer's Content-Length, else its
kind's limit (``MAX_BYTES``): a larger answer is stopped there and its part removed. An answer
with a ``Content-Encoding`` other than ``identity`` (never asked for: the client sends
``Accept-Encoding: identity``) is refused before its body is read, and malformed
``Content-Length`` or ``Content-Range`` headers are a ``FetchError`` naming the URL, never a
traceback.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from types import MappingProxyType
from typing import Any

import requests
from requests.adapters import HTTPAdapter
from urllib3.connection import HTTPConnection, HTTPSConnection
from urllib3.connectionpool import HTTPConnectionPool, HTTPSConnectionPool
from urllib3.exceptions import MaxRetryError, NameResolutionError
from urllib3.util.retry import Retry

from mars_pairs.errors import ArgumentError, ContentError, FetchError
from mars_pairs.fetch.cache import Cache
from mars_pairs.fetch.validate import (
    KINDS,
    Extent,
    check_content_type,
    check_file,
    kind_of,
    quick_check,
)
from mars_pairs.store.atomic import atomic_write_bytes

_CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+|\*)")
_UNSATISFIED_RANGE = re.compile(r"bytes \*/(\d+)")
USER_AGENT = "mars-pairs-fetch/0.1"


@dataclass(frozen=True)
class RemoteFile:
    """One archive file: its archive-relative path, URL and what the archive says it is."""

    rel: PurePosixPath
    url: str
    size: int | None = None  # bytes
    md5: str | None = None  # hex digest, lower case
    #: what the file must be (``validate.KINDS``); None: the kind its name says
    kind: str | None = None
    #: an archive table that changes between releases: revalidated on every fetch
    mutable: bool = False
    #: the local label describing this file (a PDS3 index label for its table, a product
    #: label for its image, the collection label for its inventory), for the content check
    label: Path | None = None
    #: for an ``.IMG``, the size its label gives it, read with the label's other facts
    #: (``products.with_label_facts``) so that the checks do not parse the label again;
    #: None: read from ``label`` when checked
    extent: Extent | None = None

    def __post_init__(self) -> None:
        if self.kind is not None and self.kind not in KINDS:
            raise ArgumentError(f"{self.url}: unknown file kind {self.kind!r}; one of {KINDS}")

    @property
    def file_kind(self) -> str:
        """The kind checked on download (``kind``, else by the file name)."""
        return self.kind if self.kind is not None else kind_of(self.rel)


_MiB, _GiB = 1 << 20, 1 << 30
#: The most bytes a file of each kind (``validate.KINDS``) may have when the archive does not
#: give its size: PDS3 labels are bounded at 1 MiB of text by the reader and PDS4 labels run to
#: a few hundred KB; the largest real tables (the Curiosity PLACES table, 77 MB; the Mastcam
#: cumulative index, a few hundred MB) and images (Mastcam IMG, tens of MB) sit far below theirs.
MAX_BYTES: Mapping[str, int] = MappingProxyType(
    {
        "pds3_label": 16 * _MiB,
        "pds4_label": 16 * _MiB,
        "html": 16 * _MiB,
        "places": 2 * _GiB,
        "inventory": 2 * _GiB,
        "csv": 2 * _GiB,
        "pds3_table": 8 * _GiB,
        "jpeg": 512 * _MiB,
        "png": 512 * _MiB,
        "img": 4 * _GiB,
        "geotiff": 8 * _GiB,
        "data": 8 * _GiB,
    }
)


@dataclass(frozen=True)
class FetchPolicy:
    """Retries, backoff (seconds, doubled per retry), timeouts (seconds), the total deadline of
    one file (seconds, every attempt and wait included), the longest ``Retry-After`` obeyed
    (seconds), the size limit of each kind of file (bytes, ``MAX_BYTES``) and parallelism."""

    retries: int = 4
    backoff_s: float = 0.5
    backoff_max_s: float = 30.0
    connect_timeout_s: float = 10.0
    read_timeout_s: float = 60.0
    deadline_s: float = 900.0
    retry_after_max_s: float = 60.0
    max_bytes: Mapping[str, int] = field(default_factory=lambda: MAX_BYTES)
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
    """A failure inside the body (or a bad size/MD5/content): worth another attempt."""


class _NotModified(Exception):
    """The server answered 304 to a revalidation: the cached file is current."""


@dataclass(frozen=True)
class Validator:
    """What identifies one version of a remote file: its ETag and Last-Modified headers."""

    url: str
    etag: str | None = None
    last_modified: str | None = None  # the HTTP date, as the server wrote it
    size: int | None = None  # bytes of the cached file it describes (None for a part)

    @property
    def known(self) -> bool:
        return bool(self.etag or self.last_modified)

    @property
    def if_range(self) -> str | None:
        """The If-Range value: a strong ETag, else the Last-Modified date, else None."""
        if self.etag and not self.etag.startswith("W/"):
            return self.etag
        return self.last_modified

    @classmethod
    def of(cls, url: str, headers: requests.structures.CaseInsensitiveDict[str]) -> Validator:
        return cls(url, headers.get("ETag"), headers.get("Last-Modified"))

    def dump(self, size: int | None) -> bytes:
        doc = {"url": self.url, "etag": self.etag, "last_modified": self.last_modified}
        return json.dumps(doc | {"size": size}, indent=1).encode()

    @classmethod
    def read(cls, path: Path, url: str) -> Validator | None:
        """The validator stored at ``path`` for ``url``; None if absent, unreadable or other."""
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(doc, dict) or doc.get("url") != url:
            return None
        fields = [doc.get(k) for k in ("etag", "last_modified")]
        size = doc.get("size")
        if not all(f is None or isinstance(f, str) for f in fields) or not (
            size is None or isinstance(size, int)
        ):
            return None
        return cls(url, fields[0], fields[1], size)


class _Sockets:
    """The sockets each thread's connections opened, so that another thread (a deadline's
    timer, an interrupt) can shut them down: a blocked read then returns at once. A thread
    marked expired has every socket it opens next shut down too, until ``renew``."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[int, set[socket.socket]] = {}
        self._expired: set[int] = set()
        self.all_expired = False

    def add(self, sock: socket.socket) -> None:
        me = threading.get_ident()
        with self._lock:
            self._open.setdefault(me, set()).add(sock)
            dead = self.all_expired or me in self._expired
        if dead:
            _shutdown(sock)

    def expire(self, thread: int | None = None) -> None:
        """Shut down the sockets of ``thread`` (None: of every thread, for good)."""
        with self._lock:
            if thread is None:
                self.all_expired = True
                socks = [s for group in self._open.values() for s in group]
            else:
                self._expired.add(thread)
                socks = list(self._open.get(thread, ()))
        for sock in socks:
            _shutdown(sock)

    def renew(self) -> None:
        """This thread's next sockets are not shut down (a new file's deadline starts)."""
        me = threading.get_ident()
        with self._lock:
            self._expired.discard(me)
            self._open.pop(me, None)


def _shutdown(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):  # already closed
        sock.shutdown(socket.SHUT_RDWR)


def _watched_pools(sockets: _Sockets) -> dict[str, type[HTTPConnectionPool]]:
    """urllib3 pool classes whose connections register their socket with ``sockets``."""

    class Watched(HTTPConnection):
        def connect(self) -> None:
            super().connect()
            sockets.add(self.sock)

    class WatchedTLS(HTTPSConnection):
        def connect(self) -> None:
            super().connect()
            sockets.add(self.sock)

    class Pool(HTTPConnectionPool):
        ConnectionCls = Watched

    class TLSPool(HTTPSConnectionPool):
        ConnectionCls = WatchedTLS

    return {"http": Pool, "https": TLSPool}


class _WatchedAdapter(HTTPAdapter):
    """requests' adapter over pools whose sockets a ``_Sockets`` knows."""

    def __init__(self, sockets: _Sockets, **kwargs: Any) -> None:
        self._sockets = sockets
        super().__init__(**kwargs)

    def init_poolmanager(self, *args: Any, **kwargs: Any) -> None:
        super().init_poolmanager(*args, **kwargs)
        self.poolmanager.pool_classes_by_scheme = _watched_pools(self._sockets)


class _BoundedRetry(Retry):
    """urllib3's ``Retry`` whose waits (backoff, ``Retry-After``) end early at the file's
    deadline or on cancel, a ``Retry-After`` capped at ``retry_after_max_s``; a host name that
    does not resolve is not retried (the answer does not change in the seconds of a backoff:
    offline, or a wrong host)."""

    downloader: Downloader | None = None
    retry_after_max_s: float = 60.0

    def new(self, **kw: Any) -> _BoundedRetry:
        new = super().new(**kw)
        assert isinstance(new, _BoundedRetry)
        new.downloader, new.retry_after_max_s = self.downloader, self.retry_after_max_s
        return new

    def increment(  # type: ignore[override]  # (urllib3's own signature, passed on whole)
        self,
        method: str | None = None,
        url: str | None = None,
        response: Any = None,
        error: Exception | None = None,
        _pool: Any = None,
        _stacktrace: Any = None,
    ) -> Retry:
        if isinstance(error, NameResolutionError):
            raise MaxRetryError(_pool, url or "", error) from error
        return super().increment(method, url, response, error, _pool, _stacktrace)

    def get_retry_after(self, response: Any) -> float | None:
        try:
            after = super().get_retry_after(response)
        except Exception:  # a malformed Retry-After: fall back to the backoff
            return None
        return None if after is None else min(after, self.retry_after_max_s)

    def sleep(self, response: Any = None) -> None:
        wait = None
        if self.respect_retry_after_header and response is not None:
            wait = self.get_retry_after(response)
        if wait is None:
            wait = self.get_backoff_time()
        if self.downloader is not None:
            self.downloader.wait(wait)
        elif wait > 0:
            time.sleep(wait)


def sidecar(path: Path) -> Path:
    """Where the validator of a cached file (or of a ``.part``) is kept: ``<name>.meta.json``."""
    return path.with_name(path.name + ".meta.json")


def _discard(part: Path) -> None:
    """Remove a part and its validator (a part that cannot be resumed)."""
    part.unlink(missing_ok=True)
    sidecar(part).unlink(missing_ok=True)


class Downloader:
    """Fetches ``RemoteFile``s into a ``Cache``; thread-safe (one requests Session per thread)."""

    def __init__(self, cache: Cache, policy: FetchPolicy | None = None) -> None:
        self.cache = cache
        self.policy = policy or FetchPolicy()
        self._local = threading.local()
        self._sockets = _Sockets()
        self._cancelled = threading.Event()

    # -- bounds ----------------------------------------------------------------------------
    def cancel(self) -> None:
        """Stop every download in flight at once (their sockets shut down, their waits ended)
        and refuse new ones: each ends in a ``FetchError`` saying it was cancelled."""
        self._cancelled.set()
        self._sockets.expire()

    @property
    def cancelled(self) -> bool:
        return self._cancelled.is_set()

    def _deadline(self) -> float:
        return float(getattr(self._local, "deadline", float("inf")))

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds``, ending early at this thread's deadline or on cancel."""
        left = min(seconds, self._deadline() - time.monotonic())
        if left > 0:
            self._cancelled.wait(left)

    def _check_bounds(self, url: str) -> None:
        """FetchError when the run was cancelled or this thread's file is past its deadline."""
        if self._cancelled.is_set():
            raise FetchError(url, "cancelled (the fetch was interrupted)")
        if time.monotonic() >= self._deadline():
            raise FetchError(
                url,
                f"not finished within its deadline of {self.policy.deadline_s:g} s "
                "(fetch.deadline_s)",
            )

    # -- sessions --------------------------------------------------------------------------
    def session(self) -> requests.Session:
        """This thread's session, with urllib3 retries for connections and 5xx statuses."""
        s = getattr(self._local, "session", None)
        if s is None:
            p = self.policy
            retry = _BoundedRetry(
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
            retry.downloader, retry.retry_after_max_s = self, p.retry_after_max_s
            s = requests.Session()
            adapter = _WatchedAdapter(
                self._sockets, max_retries=retry, pool_maxsize=max(4, p.workers)
            )
            s.mount("http://", adapter)
            s.mount("https://", adapter)
            s.headers["User-Agent"] = USER_AGENT
            s.headers["Accept-Encoding"] = "identity"  # the archive's bytes, ranges into them
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
        return _length(self._head(url).headers)

    def _head(self, url: str) -> requests.Response:
        """A 200 answer to a HEAD request; FetchError naming ``url`` otherwise."""
        timeout = (self.policy.connect_timeout_s, self.policy.read_timeout_s)
        try:
            r = self.session().head(url, timeout=timeout, allow_redirects=True)
        except requests.RequestException as exc:
            raise FetchError(url, f"HEAD failed: {type(exc).__name__}: {_short(exc)}") from None
        if r.status_code != 200:
            raise FetchError(url, f"HTTP {r.status_code} {r.reason} (HEAD)")
        return r

    def _whole_size(self, url: str, answer: requests.Response, started: Validator) -> int | None:
        """Bytes of the remote file a 416 answer to a resume says it has (``Content-Range:
        bytes */N``), else a HEAD's Content-Length if its validator is the part's; or None."""
        m = _UNSATISFIED_RANGE.fullmatch(answer.headers.get("Content-Range", "").strip())
        if m:
            return int(m[1])
        try:
            head = self._head(url)
        except FetchError:
            return None
        if Validator.of(url, head.headers).if_range != started.if_range:
            return None  # another version of the file than the one the part began
        return _length(head.headers)

    # -- one file --------------------------------------------------------------------------
    def fetch(
        self, remote: RemoteFile, on_bytes: Callable[[int], None] | None = None
    ) -> FetchResult:
        """Download ``remote`` to the cache (or find it there); FetchError after the retries.

        A product (``mutable`` False) in the cache is returned without a request; a mutable
        table is revalidated with its stored ETag / Last-Modified (304 keeps it, 200 replaces
        it). What lands under the real name passed the size, MD5 and ``kind`` checks.
        """
        target = self.cache.path(remote.rel, where=remote.url)
        meta = sidecar(target)
        known: Validator | None = None
        if target.is_file() and (remote.size is None or target.stat().st_size == remote.size):
            if not remote.mutable:
                try:
                    quick_check(
                        target,
                        remote.file_kind,
                        label=remote.label,
                        where=remote.url,
                        extent=remote.extent,
                    )
                    return FetchResult(remote, target, "cached", 0)
                except ContentError:
                    target.unlink()  # damaged in the cache (e.g. kept by an older release)
            else:
                known = Validator.read(meta, remote.url)
                if known is not None and known.size != target.stat().st_size:
                    known = None  # the cached file is not the one the validator describes
        part = target.with_name(target.name + ".part")
        for path in (part, sidecar(part), meta):
            if path.is_symlink():
                raise FetchError(remote.url, f"refused: {path} is a symlink")
        self._check_bounds(remote.url)
        self._sockets.renew()
        self._local.deadline = time.monotonic() + self.policy.deadline_s
        timer = threading.Timer(
            self.policy.deadline_s, self._sockets.expire, args=(threading.get_ident(),)
        )
        timer.daemon = True
        timer.start()
        try:  # a part cut by the deadline or a cancel stays, within its size, for a resume
            return self._fetch(remote, target, part, meta, known, on_bytes)
        finally:
            timer.cancel()
            self._local.deadline = float("inf")

    def _fetch(
        self,
        remote: RemoteFile,
        target: Path,
        part: Path,
        meta: Path,
        known: Validator | None,
        on_bytes: Callable[[int], None] | None,
    ) -> FetchResult:
        """``fetch``'s attempts, within this thread's deadline."""
        received, resumed = 0, False
        last = "no attempt made"
        for attempt in range(self.policy.retries + 1):
            self._check_bounds(remote.url)
            if attempt:
                self.wait(
                    min(self.policy.backoff_max_s, self.policy.backoff_s * 2 ** (attempt - 1))
                )
                self._check_bounds(remote.url)
            try:
                got, appended = self._attempt(remote, part, on_bytes, known)
                received += got
                resumed = appended  # the last attempt kept an earlier one's bytes
                self._verify_md5(remote, part)
                self._verify_kind(remote, part)
            except _NotModified:
                return FetchResult(remote, target, "cached", received)
            except _Retryable as exc:
                last = str(exc)
                continue
            except requests.RequestException as exc:
                last = f"{type(exc).__name__}: {_short(exc)}"
                continue
            except FetchError:
                self._check_bounds(remote.url)  # a cut socket: say why it was cut
                raise
            fresh = Validator.read(sidecar(part), remote.url)
            meta.unlink(missing_ok=True)  # never a validator beside a file it does not describe
            os.replace(part, target)
            if remote.mutable and fresh is not None and fresh.known:
                atomic_write_bytes(meta, fresh.dump(target.stat().st_size))
            sidecar(part).unlink(missing_ok=True)
            return FetchResult(remote, target, "resumed" if resumed else "downloaded", received)
        self._check_bounds(remote.url)
        raise FetchError(remote.url, f"failed after {self.policy.retries + 1} attempts: {last}")

    def _attempt(
        self,
        remote: RemoteFile,
        part: Path,
        on_bytes: Callable[[int], None] | None,
        known: Validator | None = None,
    ) -> tuple[int, bool]:
        """One GET; writes or appends to ``part``; (bytes received, whether it appended).

        A ``part`` is resumed with ``Range: bytes=N-`` and ``If-Range`` set to the validator
        of the answer that started it (``<part>.meta.json``); without one it is restarted.
        A part already whole (a 416 answer, ``_whole_size``) is kept as it is: (0, True).
        ``known``: the cached file's validator, sent as If-None-Match / If-Modified-Since when
        nothing is resumed (a 304 raises ``_NotModified``).
        """
        started = Validator.read(sidecar(part), remote.url)
        if_range = None if started is None else started.if_range
        offset = part.stat().st_size if part.is_file() else 0
        if offset and if_range is None:
            offset = 0  # nothing proves the remote file is still the one the part began
        if remote.size is not None and offset > remote.size:
            offset = 0
        headers: dict[str, str] = {}
        if offset and if_range is not None:  # (an offset is kept only with a validator)
            headers["Range"] = f"bytes={offset}-"
            headers["If-Range"] = if_range
        elif known is not None:
            if known.etag:
                headers["If-None-Match"] = known.etag
            if known.last_modified:
                headers["If-Modified-Since"] = known.last_modified
        timeout = (self.policy.connect_timeout_s, self.policy.read_timeout_s)
        try:
            response = self.session().get(remote.url, headers=headers, stream=True, timeout=timeout)
        except requests.RequestException as exc:  # urllib3 has retried connecting and waiting
            if _unresolved(exc):  # not retried: offline, or a wrong host name
                raise FetchError(
                    remote.url, f"host name not resolved (offline?): {_short(exc)}"
                ) from None
            raise FetchError(
                remote.url,
                f"no answer after {self.policy.retries} retries: {type(exc).__name__}: "
                f"{_short(exc)}",
            ) from None
        with response as r:
            if r.status_code == 304 and known is not None and not offset:
                raise _NotModified()
            if r.status_code == 416 and offset and started is not None:
                # If-Range matched (else the answer is the whole file), so the part is of the
                # current version; when it is already whole it is checked, then promoted
                whole = self._whole_size(remote.url, r, started)
                if whole == offset and remote.size in (None, offset):
                    return 0, True
                _discard(part)
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
            try:
                check_content_type(remote.file_kind, r.headers.get("Content-Type"), remote.url)
            except ContentError as exc:
                raise _Retryable(exc.reason) from None
            part.parent.mkdir(parents=True, exist_ok=True)  # when an answer came: none, none
            encoding = r.headers.get("Content-Encoding", "").strip().lower()
            if encoding not in ("", "identity"):
                _discard(part)
                raise FetchError(
                    remote.url,
                    f"refused: the answer is encoded ({encoding}), never asked for "
                    "(Accept-Encoding: identity)",
                )
            if r.status_code == 200 or not offset:
                offset, mode = 0, "wb"  # the server sent the whole file
                answer = Validator.of(remote.url, r.headers)
                if answer.known:
                    atomic_write_bytes(sidecar(part), answer.dump(None))
                else:
                    sidecar(part).unlink(missing_ok=True)
            else:
                start, total = _content_range(r.headers.get("Content-Range", ""), remote.url)
                if start != offset:
                    _discard(part)
                    raise _Retryable(f"Content-Range starts at {start}, asked for {offset}")
                etag = r.headers.get("ETag")
                if etag and started is not None and started.etag and etag != started.etag:
                    _discard(part)  # a server that ignored If-Range: never stitch two files
                    raise _Retryable(f"the resumed part has ETag {etag}, not {started.etag}")
                mode = "ab"
            length = _length(r.headers, remote.url)
            total = offset + length if length is not None else None
            if r.status_code == 206 and mode == "ab":
                total = _content_range(r.headers["Content-Range"], remote.url)[1] or total
            if remote.size is not None and total is not None and total != remote.size:
                raise _Retryable(f"server sends {total} bytes, the archive says {remote.size}")
            limit = self._limit(remote, total)
            if total is not None and total > limit:
                _discard(part)
                raise FetchError(remote.url, f"refused: {total} bytes, over {self._why(remote)}")
            got = 0
            with open(part, mode) as fh:
                for chunk in r.iter_content(self.policy.chunk_bytes):
                    if offset + got + len(chunk) > limit:
                        fh.close()
                        _discard(part)
                        raise FetchError(
                            remote.url, f"stopped: the body runs past {self._why(remote)}"
                        )
                    fh.write(chunk)
                    got += len(chunk)
                    if on_bytes is not None:
                        on_bytes(len(chunk))
                    if self._cancelled.is_set() or time.monotonic() >= self._deadline():
                        break  # the part so far is kept (within its size) for a resume
                fh.flush()
                os.fsync(fh.fileno())
            self._check_bounds(remote.url)
        size = part.stat().st_size
        expected = remote.size if remote.size is not None else total
        if expected is not None and size != expected:
            raise _Retryable(f"received {size} bytes of {expected}")
        return got, mode == "ab"

    def _limit(self, remote: RemoteFile, total: int | None) -> int:
        """The most bytes the file may have: the archive's size, else the answer's length,
        else its kind's limit (never more than the kind's limit)."""
        cap = self.policy.max_bytes.get(remote.file_kind, MAX_BYTES["data"])
        known = remote.size if remote.size is not None else total
        return cap if known is None else min(known, cap)

    def _why(self, remote: RemoteFile) -> str:
        cap = self.policy.max_bytes.get(remote.file_kind, MAX_BYTES["data"])
        if remote.size is not None and remote.size <= cap:
            return f"the {remote.size} bytes the archive gives it"
        return f"the {cap}-byte limit of a {remote.file_kind} file"

    def _verify_kind(self, remote: RemoteFile, part: Path) -> None:
        """Check the part is a file of its kind; a failure discards the part."""
        try:
            check_file(
                part, remote.file_kind, label=remote.label, where=remote.url, extent=remote.extent
            )
        except ContentError as exc:
            _discard(part)
            raise _Retryable(exc.reason) from None

    def _verify_md5(self, remote: RemoteFile, part: Path) -> None:
        """Compare the part file's MD5 with the archive's; a mismatch discards the part."""
        if remote.md5 is None:
            return
        digest = hashlib.md5(usedforsecurity=False)
        with open(part, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        if digest.hexdigest() != remote.md5.lower():
            _discard(part)
            raise _Retryable(f"MD5 {digest.hexdigest()} differs from the archive's {remote.md5}")


def _length(
    headers: requests.structures.CaseInsensitiveDict[str], url: str | None = None
) -> int | None:
    """The Content-Length of an answer's headers (None when absent); a malformed one is a
    FetchError naming ``url`` (None: read as absent)."""
    length = headers.get("Content-Length")
    if length is None:
        return None
    text = length.strip()
    if text.isascii() and text.isdigit() and len(text) <= 20:
        return int(text)
    if url is None:
        return None
    raise FetchError(url, f"malformed Content-Length header {length[:40]!r}")


def _content_range(header: str, url: str) -> tuple[int | None, int | None]:
    """(first byte, total size) of a ``Content-Range: bytes a-b/n`` header; a malformed one is
    a FetchError naming ``url``."""
    m = _CONTENT_RANGE.fullmatch(header.strip())
    if not m:
        raise FetchError(url, f"malformed Content-Range header {header[:60]!r}")
    return int(m[1]), None if m[3] == "*" else int(m[3])


def _unresolved(exc: BaseException) -> bool:
    """Whether a requests error is, at its root, a host name that did not resolve."""
    seen: BaseException | None = exc
    for _ in range(8):
        if seen is None or isinstance(seen, NameResolutionError):
            return seen is not None
        nxt = getattr(seen, "reason", None)
        if (
            not isinstance(nxt, BaseException)
            and seen.args
            and isinstance(seen.args[0], BaseException)
        ):
            nxt = seen.args[0]
        seen = nxt if isinstance(nxt, BaseException) and nxt is not seen else None
    return False


_OBJECT_REPR = re.compile(r"<[\w.]+ object at 0x[0-9a-f]+>: ")


def _short(exc: BaseException) -> str:
    """The innermost cause of a requests/urllib3 error first (a name that does not resolve, a
    refused connection), then the rest, within 200 characters."""
    inner = exc
    for _ in range(6):  # requests' ConnectionError -> urllib3 MaxRetryError -> its reason
        nxt = getattr(inner, "reason", None)
        if not isinstance(nxt, BaseException) and inner.args:
            nxt = inner.args[0]
        if not isinstance(nxt, BaseException) or nxt is inner:
            break
        inner = nxt
    text = str(exc) if inner is exc else f"{type(inner).__name__}: {inner} ({exc})"
    text = _OBJECT_REPR.sub("", text)
    return text if len(text) <= 200 else text[:197] + "..."
