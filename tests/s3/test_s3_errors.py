"""Object storage that fails (an unreachable endpoint, a missing bucket) gives a
``StorageError`` naming the URL, never "not a mars-pairs dataset"; the commands that read
only local folders refuse a URL naming the ones that read object storage."""

from __future__ import annotations

import re
import socket
import time

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import StorageError
from mars_pairs.store import fs
from mars_pairs.store.query import Manifest

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_an_unreachable_endpoint_is_a_storage_error_naming_the_url(
    s3_env: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    s3fs = pytest.importorskip("s3fs")
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{_closed_port()}")
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")
    url = "s3://some-bucket/a-dataset"
    where = re.escape("s3://some-bucket/a-dataset/manifest.parquet: ")
    # fsspec keeps file system instances (keyed by arguments, not the environment): a fresh
    # one for the closed endpoint, and none of it left for the next test
    s3fs.S3FileSystem.clear_instance_cache()
    start = time.monotonic()
    try:
        with pytest.raises(StorageError, match=where):
            Manifest.open(url)
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
    assert time.monotonic() - start < 60  # bounded: the retries end


def test_writing_to_a_missing_bucket_names_the_url(s3_env: str) -> None:
    url = "s3://no-such-bucket-here/p/manifest.parquet"
    with pytest.raises(StorageError, match=r"no-such-bucket-here/p/manifest\.parquet.*bucket"):
        fs.put_bytes(url, b"x")


def test_an_absent_dataset_on_a_reachable_server_is_still_not_a_dataset(s3_prefix: str) -> None:
    assert not fs.is_file(fs.join(s3_prefix, "manifest.parquet"))
    assert not fs.exists(fs.join(s3_prefix, "manifest.parquet"))


@pytest.mark.parametrize("command", ["query", "show", "report", "overview", "export-qgis"])
def test_local_only_commands_refuse_a_url(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    argv = [command, "s3://bucket/prefix", *(["some-key"] if command == "show" else [])]
    try:  # query reads a catalogue on object storage: it refuses a URL once it knows why
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code  # type: ignore[assignment]
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "s3://bucket/prefix: this command reads a dataset folder on this machine" in err
    assert "s3:/bucket" not in err  # the URL is not mangled into a path


def test_a_storage_error_crosses_processes_whole() -> None:
    """A Dask worker's StorageError reaches the driver with its URL and reason (pickled)."""
    import pickle

    err = pickle.loads(pickle.dumps(StorageError("s3://b/p/x.tar", "NoCredentialsError: none")))
    assert isinstance(err, StorageError)
    assert (err.url, err.reason) == ("s3://b/p/x.tar", "NoCredentialsError: none")
    assert str(err) == "s3://b/p/x.tar: NoCredentialsError: none"
