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
the headers and 429/5xx statuses with exponential backoff; failures inside the body (truncated
bodies, stalls, wrong sizes, MD5 mismatches) are retried by this module's loop with the same
backoff. After the last attempt a ``FetchError`` names the URL and the reason.
"""

from __future__ import annotations

import hashlib
import json
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
        target.parent.mkdir(parents=True, exist_ok=True)
        part = target.with_name(target.name + ".part")
        for path in (part, sidecar(part), meta):
            if path.is_symlink():
                raise FetchError(remote.url, f"refused: {path} is a symlink")
        received, resumed = 0, False
        last = "no attempt made"
        for attempt in range(self.policy.retries + 1):
            if attempt:
                time.sleep(
                    min(self.policy.backoff_max_s, self.policy.backoff_s * 2 ** (attempt - 1))
                )
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
            fresh = Validator.read(sidecar(part), remote.url)
            meta.unlink(missing_ok=True)  # never a validator beside a file it does not describe
            os.replace(part, target)
            if remote.mutable and fresh is not None and fresh.known:
                atomic_write_bytes(meta, fresh.dump(target.stat().st_size))
            sidecar(part).unlink(missing_ok=True)
            return FetchResult(remote, target, "resumed" if resumed else "downloaded", received)
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
            if r.status_code == 200 or not offset:
                offset, mode = 0, "wb"  # the server sent the whole file
                answer = Validator.of(remote.url, r.headers)
                if answer.known:
                    atomic_write_bytes(sidecar(part), answer.dump(None))
                else:
                    sidecar(part).unlink(missing_ok=True)
            else:
                start, total = _content_range(r.headers.get("Content-Range", ""))
                if start != offset:
                    _discard(part)
                    raise _Retryable(f"Content-Range starts at {start}, asked for {offset}")
                etag = r.headers.get("ETag")
                if etag and started is not None and started.etag and etag != started.etag:
                    _discard(part)  # a server that ignored If-Range: never stitch two files
                    raise _Retryable(f"the resumed part has ETag {etag}, not {started.etag}")
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
        return got, mode == "ab"

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


def _length(headers: requests.structures.CaseInsensitiveDict[str]) -> int | None:
    """The Content-Length of an answer's headers (None when absent or not a number)."""
    length = headers.get("Content-Length")
    return int(length) if length is not None and length.isdigit() else None


def _content_range(header: str) -> tuple[int | None, int | None]:
    """(first byte, total size) of a ``Content-Range: bytes a-b/n`` header."""
    m = _CONTENT_RANGE.match(header.strip())
    if not m:
        return None, None
    return int(m[1]), None if m[3] == "*" else int(m[3])


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
