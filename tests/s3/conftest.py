"""An S3-compatible server on 127.0.0.1 for the object-storage tests (moto's server mode),
started once for the session and stopped at its end; the tests skip with a message when
moto or s3fs is not installed (``pip install -e '.[dev]'`` installs them)."""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Iterator

import pytest

BUCKET = "mars-pairs-test"


@pytest.fixture(scope="session")
def s3_server() -> Iterator[str]:
    """The endpoint URL (``http://127.0.0.1:PORT``) of a moto S3 server holding ``BUCKET``."""
    pytest.importorskip("s3fs", reason="s3fs is not installed (pip install -e '.[dev]')")
    server_mod = pytest.importorskip(
        "moto.server", reason="moto[server] is not installed (pip install -e '.[dev]')"
    )
    import boto3

    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # a line per request otherwise
    server = server_mod.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        endpoint = f"http://{host}:{port}"
        client = boto3.client(
            "s3",
            endpoint_url=endpoint,
            aws_access_key_id="testing",
            aws_secret_access_key="testing",
            region_name="us-east-1",
        )
        client.create_bucket(Bucket=BUCKET)
        yield endpoint
    finally:
        server.stop()


@pytest.fixture(scope="module")
def s3_env(s3_server: str) -> Iterator[str]:
    """The environment a reader of the test server needs (credentials, endpoint), for one
    test module; yields the endpoint URL."""
    with pytest.MonkeyPatch.context() as mp:
        for key in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3"):
            mp.delenv(key, raising=False)
        mp.setenv("AWS_ACCESS_KEY_ID", "testing")
        mp.setenv("AWS_SECRET_ACCESS_KEY", "testing")
        mp.setenv("AWS_DEFAULT_REGION", "us-east-1")
        mp.setenv("AWS_ENDPOINT_URL", s3_server)
        yield s3_server


@pytest.fixture(scope="module")
def s3_prefix_factory(s3_env: str) -> Iterator[Callable[[], str]]:
    """Makes fresh ``s3://BUCKET/<unique>`` prefixes on the test server (its environment
    set for the module)."""
    yield lambda: f"s3://{BUCKET}/{uuid.uuid4().hex[:12]}"


@pytest.fixture
def s3_prefix(s3_env: str) -> str:
    """A fresh ``s3://BUCKET/<unique>`` prefix on the test server (its environment set)."""
    return f"s3://{BUCKET}/{uuid.uuid4().hex[:12]}"
