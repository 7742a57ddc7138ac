"""A real HTTP server on 127.0.0.1 serving a folder, with Range support and injected faults.

werkzeug's threaded WSGI server and ``send_file(conditional=True)`` (HEAD, Range -> 206 with
Content-Range, 416). Faults are queued per path and used one per request:

    "404", "500"     that status instead of the file
    "slow"           sleep ``slow_s`` before answering (longer than the client's timeout)
    "truncate"       send the headers of the full answer, half its body, then drop the connection
    "stall"          send half the body, then wait ``slow_s`` before the rest (kill a client then)
    "corrupt"        the same number of bytes with one changed (an MD5 mismatch)
    "longer"         the file with 100 bytes appended (a wrong size)
    "html"           200 with ``Content-Type: text/html`` and an HTML error page (a proxy's)
    "html-as-file"   that HTML page with the Content-Type the file itself would have
    "short"          200 with the first half of the file and a Content-Length matching that
                     half (a cut body that looks complete); ignores Range and validators;
                     "short:N" sends the first N bytes instead
    "416-bare"       416 without a Content-Range header (the size left unsaid)

``replace(rel, data)`` puts new content at a path between requests, moving its modification
time on (so its ETag and Last-Modified change, as an archive's re-release would).

Every request is logged with its method, path, Range, If-Range, If-None-Match and
If-Modified-Since headers, status and body bytes sent, so tests measure what a client moved.
"""

from __future__ import annotations

import mimetypes
import os
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from werkzeug.exceptions import NotFound, RequestedRangeNotSatisfiable
from werkzeug.security import safe_join
from werkzeug.serving import WSGIRequestHandler, make_server
from werkzeug.utils import send_file
from werkzeug.wrappers import Request, Response


@dataclass
class LogEntry:
    method: str
    path: str
    range: str | None
    status: int = 0
    sent: int = 0
    if_range: str | None = None
    if_none_match: str | None = None
    if_modified_since: str | None = None


class _Quiet(WSGIRequestHandler):
    def log(self, *args, **kwargs) -> None:
        pass


class _Dropped(Exception):
    """Raised inside a body to make the server drop the connection (a truncated body)."""


class ArchiveServer:
    """Serve ``root`` on 127.0.0.1 (a free port); ``with ArchiveServer(root) as srv: srv.url``."""

    def __init__(self, root: Path, slow_s: float = 1.0) -> None:
        self.root = Path(root)
        self.slow_s = slow_s
        self.faults: dict[str, list[str]] = {}
        self.log: list[LogEntry] = []
        self._lock = threading.Lock()
        self._variants = self.root.parent / (self.root.name + ".variants")
        self._server = make_server("127.0.0.1", 0, self._app, threaded=True, request_handler=_Quiet)
        self.url = f"http://127.0.0.1:{self._server.server_port}"
        self._thread = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )

    # -- lifecycle -------------------------------------------------------------------------
    def __enter__(self) -> ArchiveServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=5)

    # -- control and measurement -----------------------------------------------------------
    def fault(self, rel: str, *kinds: str) -> None:
        """Queue faults for the next requests of ``rel`` (archive-relative path)."""
        with self._lock:
            self.faults.setdefault(rel.lstrip("/"), []).extend(kinds)

    def requests_for(self, rel: str, method: str = "GET") -> list[LogEntry]:
        """The logged requests of one path."""
        rel = "/" + rel.lstrip("/")
        with self._lock:
            return [e for e in self.log if e.path == rel and e.method == method]

    def bytes_sent(self, rel: str | None = None) -> int:
        """Body bytes sent (for one path, or all)."""
        with self._lock:
            rows = [e for e in self.log if rel is None or e.path == "/" + rel.lstrip("/")]
            return sum(e.sent for e in rows)

    def replace(self, rel: str, data: bytes) -> None:
        """New content at ``rel``, its modification time moved 10 s past the old one."""
        path = self.root / rel.lstrip("/")
        old = path.stat().st_mtime if path.exists() else time.time()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        later = max(old + 10, time.time())
        os.utime(path, (later, later))

    def reset_log(self) -> None:
        with self._lock:
            self.log.clear()

    # -- the WSGI app ----------------------------------------------------------------------
    def _app(self, environ: dict, start_response):  # type: ignore[no-untyped-def]
        req = Request(environ)
        h = req.headers
        entry = LogEntry(req.method, req.path, h.get("Range"), if_range=h.get("If-Range"),
                         if_none_match=h.get("If-None-Match"),
                         if_modified_since=h.get("If-Modified-Since"))  # fmt: skip
        with self._lock:
            self.log.append(entry)
            queue = self.faults.get(req.path.lstrip("/"))
            fault = queue.pop(0) if queue else None
        limit = None
        if fault == "slow":
            time.sleep(self.slow_s)
        if fault in ("404", "500", "416-bare"):
            status = {"404": 404, "500": 500, "416-bare": 416}[fault]
            resp: Response = NotFound() if fault == "404" else Response("injected", status=status)
        else:
            path = safe_join(str(self.root), req.path.lstrip("/"))
            if path is None or not Path(path).is_file():
                resp = NotFound()
            elif fault in ("html", "html-as-file") or (fault or "").startswith("short"):
                resp = self._bad_200(Path(path), fault)
            else:
                served = (
                    self._variant(Path(path), fault) if fault in ("corrupt", "longer") else path
                )
                try:
                    resp = send_file(served, environ, conditional=True, etag=True, max_age=None)
                except RequestedRangeNotSatisfiable as exc:  # with Content-Range: bytes */N
                    resp = exc.get_response(environ)
                if fault in ("truncate", "stall"):
                    limit = max(1, (resp.content_length or 2) // 2)

        def recording_start(status: str, headers, exc_info=None):  # type: ignore[no-untyped-def]
            entry.status = int(status.split()[0])
            return start_response(status, headers, exc_info)

        stall = self.slow_s if fault == "stall" else None
        return self._counted(resp(environ, recording_start), entry, limit, stall)

    def _counted(
        self, body: Iterable[bytes], entry: LogEntry, limit: int | None, stall: float | None
    ) -> Iterator[bytes]:
        try:
            for chunk in body:
                if stall is not None and limit is not None and entry.sent + len(chunk) >= limit:
                    head, chunk = chunk[: limit - entry.sent], chunk[limit - entry.sent :]
                    entry.sent += len(head)
                    yield head
                    time.sleep(stall)
                    limit = None
                if limit is not None and entry.sent + len(chunk) >= limit:
                    chunk = chunk[: limit - entry.sent]
                    entry.sent += len(chunk)
                    yield chunk
                    raise _Dropped("injected truncation")
                entry.sent += len(chunk)
                yield chunk
        finally:
            close = getattr(body, "close", None)
            if close is not None:
                close()

    @staticmethod
    def _bad_200(path: Path, fault: str) -> Response:
        """A 200 that is not the file: an HTML error page, or the first half of the file."""
        own = mimetypes.guess_type(path.name)[0] or "application/octet-stream"  # as send_file
        if fault.startswith("short"):
            data = path.read_bytes()
            cut = int(fault.split(":")[1]) if ":" in fault else len(data) // 2
            return Response(data[:cut], status=200, mimetype=own)
        page = (
            "<!DOCTYPE html>\n<html><head><title>Service Unavailable</title></head>\n"
            "<body><h1>The archive is down for maintenance</h1></body></html>\n"
        )
        return Response(page, status=200, mimetype="text/html" if fault == "html" else own)

    def _variant(self, path: Path, fault: str) -> str:
        """A corrupted or lengthened copy of ``path`` (kept beside the archive, not in it)."""
        self._variants.mkdir(parents=True, exist_ok=True)
        data = bytearray(path.read_bytes())
        if fault == "corrupt":
            data[len(data) // 2] ^= 0xFF
        else:
            data += b"\0" * 100
        out = self._variants / f"{fault}-{path.name}"
        out.write_bytes(bytes(data))
        return str(out)


@pytest.fixture()
def served(tmp_path: Path) -> Iterator[tuple[ArchiveServer, Path]]:
    """(server, archive root): an empty archive folder served on 127.0.0.1."""
    root = tmp_path / "archive"
    root.mkdir()
    with ArchiveServer(root, slow_s=1.0) as srv:
        yield srv, root
