"""Where a dataset lives: a local folder (a ``Path``) or an fsspec URL (``s3://bucket/prefix``).

A dataset root is either a local ``Path`` (every local code path is the plain ``os`` one) or
the text of an fsspec URL (``s3://bucket/prefix``, ``gs://...``, ``memory://...``: any
protocol whose fsspec implementation is installed; ``s3fs`` for S3). :func:`dataset_root`
makes one from what a user gives; :func:`join` names a file in it. The functions here take
either and do the one obvious thing for each.

Object storage has no rename and no partial objects: an object appears only when its upload
completes, whole. So a file is written to object storage by writing it to a local temporary
file (the system temporary folder, ``TMPDIR``; removed after) and uploading it in one piece
(:func:`upload`, :func:`put_bytes`): a writer killed mid-upload leaves nothing under the
final name. Where a local build renames a staged file into place, an object is copied on the
server (:func:`replace`: the destination appears whole, then the source is deleted).

Credentials and endpoints come from the environment as the fsspec implementation reads them
(s3fs/botocore: ``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL`` or
``AWS_ENDPOINT_URL_S3``, ``AWS_PROFILE``, ...). Listings are never cached (another process,
a build worker, may have written since).
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, TypeGuard, overload

#: A dataset root or a file in one: a local path, or the text of an fsspec URL.
Location = Path | str

_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]*://")
#: What ``Path`` makes of a URL: its ``//`` collapsed (``s3:/bucket/prefix``); a scheme of one
#: letter is a Windows drive (``C:/``), not a URL
_COLLAPSED_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]+:/(?!/)")


def collapsed_url(value: str | os.PathLike[str]) -> str | None:
    """The URL ``value`` was made from when it is a local path that reads as one whose ``//``
    was collapsed (``Path("s3://b/p")`` is ``s3:/b/p``), else None: a dataset written there
    would go to a folder ``s3:`` of the working directory."""
    text = os.fspath(value)
    if not isinstance(text, str) or not _COLLAPSED_URL.match(text):
        return None
    scheme, rest = text.split(":/", 1)
    return f"{scheme}://{rest}"


def collapsed_url_problem(value: str | os.PathLike[str]) -> str | None:
    """The one-line refusal of ``value`` when it is a collapsed URL (``collapsed_url``), else
    None."""
    url = collapsed_url(value)
    if url is None:
        return None
    return (
        f"{os.fspath(value)!s}: a URL made into a local path (its // collapsed); pass the URL "
        f"as text ({url}), not as a Path"
    )


def is_url(value: object) -> TypeGuard[str]:
    """Whether ``value`` is the text of a URL (``scheme://...``) other than ``file://``."""
    return isinstance(value, str) and bool(_URL.match(value)) and not value.startswith("file://")


def dataset_root(value: str | os.PathLike[str]) -> Location:
    """A dataset root from what a user gives: a URL (its trailing ``/`` removed) as text,
    ``file://PATH`` and anything else as a local ``Path``; ConfigError for a URL that was made
    into a ``Path`` (``collapsed_url``), which would otherwise name a local folder ``s3:``."""
    if is_url(value):
        return str(value).rstrip("/")
    problem = collapsed_url_problem(value)
    if problem is not None:
        from mars_pairs.errors import ConfigError

        raise ConfigError(problem)
    text = os.fspath(value)
    if isinstance(text, str) and text.startswith("file://"):
        text = text.removeprefix("file://")
    return Path(text)


@overload
def join(root: Path, rel: str) -> Path: ...
@overload
def join(root: str, rel: str) -> Location: ...
def join(root: Location, rel: str) -> Location:
    """The file ``rel`` (relative, ``/``-separated) of the dataset root ``root``."""
    if is_url(root):
        return f"{root.rstrip('/')}/{rel}"
    return Path(root) / rel


def filesystem(url: str) -> tuple[Any, Any]:
    """The fsspec file system of ``url`` (listings not cached) and the path in it.
    ConfigError naming the URL when the protocol is unknown or its package is missing."""
    import fsspec.core

    from mars_pairs.errors import ConfigError

    try:
        found: tuple[Any, Any] = fsspec.core.url_to_fs(url, use_listings_cache=False)
    except (ImportError, ValueError) as exc:
        scheme = url.split("://", 1)[0]
        hint = " (pip install 'mars-pairs[s3]')" if scheme in ("s3", "s3a") else ""
        raise ConfigError(f"{url}: no file system for {scheme}://{hint}: {exc}") from None
    return found


@contextmanager
def _remote(url: str, *, writing: bool = False) -> Iterator[None]:
    """Re-raise what the file system raises for ``url`` as ``StorageError`` naming it (an
    unreachable endpoint, missing credentials, a refused request): not as a missing file. A
    FileNotFoundError stays one when reading (the file is absent); when writing it means
    the bucket or container is missing."""
    from mars_pairs.errors import MarsPairsError, StorageError

    try:
        yield
    except FileNotFoundError as exc:
        if writing:
            raise StorageError(url, f"cannot write: {exc} (does the bucket exist?)") from exc
        raise
    except MarsPairsError:
        raise
    except Exception as exc:
        hint = ""
        if "Credentials" in type(exc).__name__:
            hint = (
                " (the process that reads or writes it needs AWS credentials in its"
                " environment: on an external Dask cluster, the workers')"
            )
        raise StorageError(url, f"{type(exc).__name__}: {exc}{hint}") from exc


def exists(path: Location) -> bool:
    """Whether the file ``path`` exists."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path):
            try:
                fs.info(p)
            except FileNotFoundError:
                return False
        return True
    return Path(path).exists()


def is_file(path: Location) -> bool:
    """Whether ``path`` is a file (an object, for object storage)."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path):
            try:
                info = fs.info(p)
            except FileNotFoundError:
                return False
        return bool(info.get("type") == "file")
    return Path(path).is_file()


def size(path: Location) -> int:
    """The size of the file ``path`` in bytes (FileNotFoundError when absent)."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path):
            return int(fs.size(p))
    return Path(path).stat().st_size


def read_bytes(path: Location) -> bytes:
    """The bytes of the file ``path`` (FileNotFoundError when absent)."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path):
            return bytes(fs.cat_file(p))
    return Path(path).read_bytes()


def read_range(path: Location, offset: int, length: int) -> bytes:
    """``length`` bytes of ``path`` at ``offset`` (fewer at its end): one range request."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path):
            return bytes(fs.cat_file(p, start=offset, end=offset + length))
    with open(Path(path), "rb") as fh:
        fh.seek(offset)
        return fh.read(length)


def read_ranges(requests: list[tuple[str, int, int]]) -> list[bytes]:
    """The bytes of each ``(url, offset, length)`` of ``requests`` (fewer at a file's end), in
    order, as one concurrent batch of range requests (fsspec ``cat_ranges``): one round trip
    where a loop of :func:`read_range` makes one a request. URLs of one file system."""
    if not requests:
        return []
    filesystem_, _ = filesystem(requests[0][0])
    paths = [filesystem(url)[1] for url, _, _ in requests]
    starts = [offset for _, offset, _ in requests]
    ends = [offset + length for _, offset, length in requests]
    with _remote(requests[0][0]):
        got = filesystem_.cat_ranges(paths, starts, ends, on_error="raise")
    return [bytes(b) for b in got]


def open_input(path: Location) -> Any:
    """``path`` opened for binary reading (seekable; remote reads are range requests)."""
    if is_url(path):
        fs, p = filesystem(path)
        return fs.open(p, "rb", cache_type="readahead", block_size=1 << 20)
    return open(Path(path), "rb")


def upload(local: Path, path: Location) -> None:
    """Upload the local file ``local`` to ``path`` whole: the object appears only when the
    upload completes (a multipart upload is completed, or aborted, by fsspec); a local
    ``path`` is a copy through a temporary name and a rename."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path, writing=True):
            fs.put_file(str(local), p)
        return
    from mars_pairs.store.atomic import atomic_path

    with atomic_path(Path(path)) as tmp:
        shutil.copyfile(local, tmp)


def put_bytes(path: Location, data: bytes) -> None:
    """Write ``data`` to ``path`` all or nothing (locally: a temporary name and a rename)."""
    from mars_pairs.store.atomic import atomic_write_bytes

    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path, writing=True):
            fs.pipe_file(p, data)
        return
    atomic_write_bytes(Path(path), data)


def replace(src: Location, dst: Location) -> None:
    """Move ``src`` to ``dst``: a rename locally; on object storage a server-side copy (the
    object ``dst`` appears whole) and then the removal of ``src``."""
    if is_url(src):
        fs, s = filesystem(src)
        _, d = filesystem(str(dst))
        with _remote(str(dst), writing=True):
            fs.copy(s, d)
            fs.rm_file(s)
        return
    os.replace(src, dst)


def remove(path: Location) -> None:
    """Remove the file ``path``, if there."""
    if is_url(path):
        fs, p = filesystem(path)
        with _remote(path), suppress(FileNotFoundError):
            fs.rm_file(p)
        return
    Path(path).unlink(missing_ok=True)


def list_files(root: Location) -> list[str]:
    """Every file under ``root``, relative to it (``/``-separated), sorted; [] when absent."""
    if is_url(root):
        fs, p = filesystem(root)
        base = p.rstrip("/") + "/"
        with _remote(root):
            try:
                found = fs.find(p)
            except FileNotFoundError:
                return []
        return sorted(f[len(base) :] for f in found if f.startswith(base))
    folder = Path(root)
    if not folder.is_dir():
        return []
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def list_names(root: Location) -> list[str]:
    """The files directly in ``root`` (not in its subfolders), by name, sorted; [] when
    absent. One listing of the folder itself, whatever its subfolders hold."""
    if is_url(root):
        fs, p = filesystem(root)
        base = p.rstrip("/") + "/"
        with _remote(root):
            try:
                found = fs.ls(p, detail=True)
            except FileNotFoundError:
                return []
        names = (str(f["name"]).rstrip("/") for f in found if f.get("type") == "file")
        return sorted(
            n[len(base) :] for n in names if n.startswith(base) and "/" not in n[len(base) :]
        )
    folder = Path(root)
    if not folder.is_dir():
        return []
    with os.scandir(folder) as entries:
        return sorted(e.name for e in entries if e.is_file())


def total_size(root: Location) -> int:
    """The bytes of every file under ``root`` (one listing on object storage)."""
    if is_url(root):
        fs, p = filesystem(root)
        with _remote(root):
            try:
                return int(fs.du(p, total=True))
            except FileNotFoundError:
                return 0
    return sum(p.stat().st_size for p in Path(root).rglob("*") if p.is_file())


#: the name of a staging folder: the prefix, the pid of the process that made it, a suffix
STAGING_PREFIX = "mars-pairs-upload-"


@contextmanager
def local_staging() -> Iterator[Path]:
    """A fresh local folder (in the system temporary folder) for files on their way to
    object storage, named ``mars-pairs-upload-<pid>-...``; removed with its content when the
    block ends (a killed process's: by :func:`remove_stale_staging`)."""
    with tempfile.TemporaryDirectory(prefix=f"{STAGING_PREFIX}{os.getpid()}-") as tmp:
        yield Path(tmp)


def remove_stale_staging() -> list[Path]:
    """Remove the staging folders (:func:`local_staging`) in the system temporary folder
    whose process is gone (a build killed mid-upload: SIGKILL, a lost bucket); the ones of
    running processes stay. Returns the folders removed."""
    removed = []
    root = Path(tempfile.gettempdir())
    for path in sorted(root.glob(f"{STAGING_PREFIX}*")):
        pid_text = path.name[len(STAGING_PREFIX) :].split("-", 1)[0]
        if not pid_text.isdigit() or path.is_symlink() or not path.is_dir():
            continue
        try:
            os.kill(int(pid_text), 0)
            continue  # alive (or not ours to signal: alive)
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


@contextmanager
def written_file(path: Location) -> Iterator[Path]:
    """A local file for the caller to write ``path`` through, all or nothing: its temporary
    name (``store.atomic.atomic_path``: synced and renamed to ``path`` when the block ends
    cleanly, removed when it raises), or on object storage a file of a local staging folder
    uploaded whole when the block ends cleanly."""
    from mars_pairs.store.atomic import atomic_path

    if is_url(path):
        with local_staging() as tmp:
            local = tmp / path.rsplit("/", 1)[-1]
            yield local
            upload(local, path)
        return
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(Path(path)) as tmp:
        yield tmp


def write_parquet(table: Any, path: Location, row_group_size: int = 4096) -> None:
    """Write ``table`` as the Parquet file ``path`` all or nothing (the bytes of
    ``store.atomic.write_parquet_atomic``; on object storage written locally, then
    uploaded whole)."""
    from mars_pairs.store.atomic import write_parquet_atomic

    if is_url(path):
        with local_staging() as tmp:
            local = tmp / path.rsplit("/", 1)[-1]
            write_parquet_atomic(table, local, row_group_size)
            upload(local, path)
        return
    write_parquet_atomic(table, Path(path), row_group_size)


def parquet_source(path: Location) -> tuple[Any, Any]:
    """``(source, filesystem)`` for pyarrow's readers (``pq.read_table(source,
    filesystem=...)``, ``pyarrow.dataset.dataset``): the path and None locally, the path in
    the fsspec file system and that file system otherwise."""
    if is_url(path):
        fs, p = filesystem(path)
        return p, fs
    return Path(path), None


def read_parquet(path: Location, columns: list[str] | None = None) -> Any:
    """The Parquet table at ``path`` (``columns`` only, when given)."""
    import pyarrow.parquet as pq

    source, fs = parquet_source(path)
    return pq.read_table(source, columns=columns, filesystem=fs)


def read_parquet_file(path: Location) -> Any:
    """The whole Parquet file at ``path`` as a table, read by its own reader in this thread
    (not the datasets layer of :func:`read_parquet`, whose set-up costs more than a chunk
    part's read and whose allocations outlive it); the same table."""
    import pyarrow.parquet as pq

    if is_url(path):
        with open_input(path) as fh, pq.ParquetFile(fh) as file:
            return file.read(use_threads=False)
    with pq.ParquetFile(Path(path)) as file:
        return file.read(use_threads=False)


def parquet_schema(path: Location) -> Any:
    """The Arrow schema of the Parquet file at ``path`` (its footer only)."""
    import pyarrow.parquet as pq

    if is_url(path):
        with open_input(path) as fh:
            return pq.read_schema(fh)
    return pq.read_schema(Path(path))


def parquet_metadata(path: Location) -> Any:
    """The Parquet footer (``FileMetaData``) of the file at ``path``."""
    import pyarrow.parquet as pq

    if is_url(path):
        with open_input(path) as fh:
            return pq.read_metadata(fh)
    return pq.read_metadata(Path(path))
