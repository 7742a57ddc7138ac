"""A raw HTTP/1.1 server on 127.0.0.1 that misbehaves on purpose, for the fetch's bounds.

Written on ``socketserver`` (not a WSGI server) because the faults live below what a web
framework lets a handler do: headers sent one byte a second, a body with no length that never
ends, a Content-Length of 10**15, headers that do not parse. Every path names its fault:

    /slow-body      Content-Length 4096, then the body at one byte a second
    /slow-headers   the status line and headers at one byte a second
    /retry-after    503 with ``Retry-After: 100000``
    /bad-length     200 with ``Content-Length: abc``
    /endless        200, no Content-Length, ``Connection: close``, an endless body
    /huge           200 with ``Content-Length: 10**15`` and an endless body
    /gzip           200, ``Content-Encoding: gzip``, a small gzip of a large run of zeros
    /ok             200, 16 bytes

A sending thread stops when the client goes away. ``requests`` counts the requests by path.
"""

from __future__ import annotations

import contextlib
import gzip
import socketserver
import threading
import time
from collections import Counter
from collections.abc import Iterator

import pytest

GZIP_BOMB = gzip.compress(b"\0" * (64 << 20), compresslevel=9)  # 64 MiB of zeros in ~64 KB


class _Handler(socketserver.BaseRequestHandler):
    server: _Server

    def handle(self) -> None:
        sock = self.request
        sock.settimeout(30)
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk:
                return
            data += chunk
        path = data.split(b" ", 2)[1].decode()
        with self.server.lock:
            self.server.requests[path] += 1
        with contextlib.suppress(OSError):  # the client went away
            self.serve(sock, path)

    def serve(self, sock, path: str) -> None:
        stop = self.server.stop
        if path == "/slow-body":
            sock.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 4096\r\n\r\n")
            while not stop.is_set():
                sock.sendall(b"x")
                stop.wait(1.0)
        elif path == "/slow-headers":
            for byte in b"HTTP/1.1 200 OK\r\nX-Slow: " + b"y" * 10_000:
                if stop.is_set():
                    return
                sock.sendall(bytes([byte]))
                stop.wait(1.0)
        elif path == "/retry-after":
            sock.sendall(
                b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 100000\r\n"
                b"Content-Length: 0\r\n\r\n"
            )
        elif path == "/bad-length":
            sock.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: abc\r\n\r\n0123456789")
        elif path in ("/endless", "/huge"):
            head = b"HTTP/1.1 200 OK\r\nConnection: close\r\n"
            if path == "/huge":
                head += b"Content-Length: 1000000000000000\r\n"
            sock.sendall(head + b"\r\n")
            block = b"x" * 65536
            for _ in range(16384):  # at most 1 GiB, should the client never stop
                if stop.is_set():
                    return
                sock.sendall(block)
        elif path == "/gzip":
            sock.sendall(
                b"HTTP/1.1 200 OK\r\nContent-Encoding: gzip\r\nContent-Length: "
                + str(len(GZIP_BOMB)).encode()
                + b"\r\n\r\n"
                + GZIP_BOMB
            )
        else:
            sock.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 16\r\n\r\n" + b"0123456789abcdef")


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.lock = threading.Lock()
        self.requests: Counter[str] = Counter()
        self.stop = threading.Event()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}"


@pytest.fixture
def hostile_server() -> Iterator[_Server]:
    """The hostile server, started on a free port of 127.0.0.1 and stopped after the test."""
    server = _Server()
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.stop.set()
        server.shutdown()
        server.server_close()
        time.sleep(0)
