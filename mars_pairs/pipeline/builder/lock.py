"""One writer per output folder: a build, ``--resume`` or ``--append`` holds the folder's lock
from before it reads or writes anything in it to its end; a second one is refused
(:class:`~mars_pairs.errors.FolderLockedError`, exit 2) naming the holder.

Locally the lock is ``fcntl.flock(LOCK_EX | LOCK_NB)`` on the file :data:`LOCK` in the output
folder (created with the folder). The kernel releases it when the holder's process ends,
however it ends (SIGKILL too), so a dead holder never blocks the next run. The file stays
empty and is never rewritten (a refused run changes no byte and no time stamp in the folder);
the holder is named from the kernel's lock table (``/proc/locks``: its pid, this host, its
start time from ``/proc/PID/stat``). It stays in the folder (the folder hygiene knows it:
``layout.written_by``), except that a run that created the folder and leaves nothing else in
it removes both.

On object storage the lock is the object :data:`LOCK` under the prefix, created by a
conditional put (``If-None-Match: *``, fsspec's ``pipe_file(mode="create")``): of two writers
exactly one creates it. It holds an owner token, the pid, host, start time and ``renewed``,
which the holder rewrites every :data:`RENEW_S` seconds (a daemon thread), and it is deleted
at the end. The stale rule: a lock object is stale when its ``renewed`` time is more than
:data:`STALE_S` seconds old (a holder that died without deleting it: killed, its machine lost)
or when its host is this host and its pid is no process; the next run then deletes it and
takes the lock. (Two runs that find the same stale lock at once: one of their conditional puts
wins.)
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mars_pairs.errors import FolderLockedError
from mars_pairs.pipeline.builder.layout import LOCK_FILE
from mars_pairs.store import fs

#: the lock's name in the output folder (a file locally, an object on object storage)
LOCK = LOCK_FILE
#: how often the holder of an object storage lock renews it, in seconds
RENEW_S = 60.0
#: an object storage lock not renewed for this many seconds is stale
STALE_S = 600.0


def _holder() -> dict[str, Any]:
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "renewed": time.time(),
        "token": uuid.uuid4().hex,
    }


def _describe(path: object, info: dict[str, Any] | None) -> str:
    if not info:
        who = "another build (its holder not yet recorded)"
    else:
        who = (
            f"another build: pid {info.get('pid')} on {info.get('host')}, started "
            f"{info.get('started')}"
        )
    return f"{path}: the output folder is locked by {who}; wait for it to end"


@contextlib.contextmanager
def folder_lock(out: fs.Location) -> Iterator[None]:
    """Hold the output folder ``out``'s lock for the ``with`` block (see the module
    docstring); FolderLockedError naming the holder when another run holds it."""
    if isinstance(out, Path):
        with _local_lock(out):
            yield
    else:
        with _object_lock(out):
            yield


@contextlib.contextmanager
def _local_lock(out: Path) -> Iterator[None]:
    import fcntl

    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    path = out / LOCK
    made = not path.exists()
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            raise FolderLockedError(_describe(out, _local_holder(os.fstat(fd).st_ino))) from None
        try:
            yield
        except Exception:
            # a run refused (a folder of someone else's files) touches nothing: the lock file
            # it made goes, while it still holds the lock (a run that starts meanwhile fails to
            # lock the old file, exits 2, and the next one makes a new file)
            if made:
                with contextlib.suppress(OSError):
                    path.unlink()
            raise
        finally:
            if created and sorted(os.listdir(out)) in ([LOCK], []):
                with contextlib.suppress(OSError):
                    path.unlink()  # a run that left nothing leaves no folder
                with contextlib.suppress(OSError):
                    out.rmdir()
    finally:
        os.close(fd)  # releases the lock


def _local_holder(inode: int) -> dict[str, Any] | None:
    """The pid, host and start time of the process holding a flock on the file of ``inode``
    (the kernel's ``/proc/locks``); None when it cannot be told (no /proc)."""
    try:
        with open("/proc/locks") as fh:
            table = fh.read().splitlines()
    except OSError:
        return None
    for line in table:
        fields = line.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5].rsplit(":", 1)[-1] == str(inode):
            pid = int(fields[4])
            return {"pid": pid, "host": socket.gethostname(), "started": _started(pid)}
    return None


def _started(pid: int) -> str:
    """When process ``pid`` started (UTC, ISO 8601), from /proc; '?' when it cannot be told."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/stat") as fh:
            boot = next(int(x.split()[1]) for x in fh if x.startswith("btime"))
    except (OSError, ValueError, IndexError, StopIteration):
        return "?"
    at = boot + ticks / os.sysconf("SC_CLK_TCK")
    return datetime.fromtimestamp(at, timezone.utc).isoformat(timespec="seconds")


def _read_json(data: bytes) -> dict[str, Any] | None:
    try:
        doc = json.loads(data)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def _stale(info: dict[str, Any] | None, now: float) -> bool:
    """The stale rule of an object storage lock (module docstring)."""
    if info is None:
        return True  # not a lock this code wrote whole
    renewed = info.get("renewed")
    if not isinstance(renewed, int | float) or now - renewed > STALE_S:
        return True
    if info.get("host") == socket.gethostname() and isinstance(info.get("pid"), int):
        try:
            os.kill(info["pid"], 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
    return False


@contextlib.contextmanager
def _object_lock(out: str) -> Iterator[None]:
    from mars_pairs.errors import StorageError

    url = str(fs.join(out, LOCK))
    filesystem, path = fs.filesystem(url)
    me = _holder()
    for _ in range(2):  # the second try after removing a stale lock
        try:
            filesystem.pipe_file(path, json.dumps(me).encode(), mode="create")
            break
        except FileExistsError:
            try:
                info = _read_json(fs.read_bytes(url))
            except FileNotFoundError:
                continue  # released meanwhile
            if not _stale(info, time.time()):
                raise FolderLockedError(_describe(out, info)) from None
            fs.remove(url)
        except Exception as exc:  # no bucket, no credentials, unreachable
            raise StorageError(url, f"cannot create the output folder's lock: {exc}") from exc
    else:
        raise FolderLockedError(_describe(out, None))
    stop = threading.Event()

    def renew() -> None:
        while not stop.wait(RENEW_S):
            with contextlib.suppress(Exception):
                current = _read_json(fs.read_bytes(url))
                if current is None or current.get("token") != me["token"]:
                    return  # taken over: not ours to renew
                fs.put_bytes(url, json.dumps({**me, "renewed": time.time()}).encode())

    renewer = threading.Thread(target=renew, name="mars-pairs-lock", daemon=True)
    renewer.start()
    try:
        yield
    finally:
        stop.set()
        renewer.join(timeout=5)
        with contextlib.suppress(Exception):
            current = _read_json(fs.read_bytes(url))
            if current is not None and current.get("token") == me["token"]:
                fs.remove(url)
