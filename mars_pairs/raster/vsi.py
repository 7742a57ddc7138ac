"""Remote rasters through GDAL's VSI readers: URL -> ``/vsicurl/`` or ``/vsis3/`` path, options.

``gdal_path("https://host/dem.tif")`` is ``/vsicurl/https://host/dem.tif``: GDAL then reads
the header and the blocks a window needs with HTTP range requests, never the whole file (a
COG or tiled GeoTIFF moves a small fraction of itself; a striped one whole strips).

The options (``VSI_OPTIONS``) stop GDAL listing the remote folder on open and set its HTTP
retries and timeouts. They are GDAL configuration options, read from the environment at each
request, so ``use_remote_defaults()`` sets the ones not already set in ``os.environ`` (build
workers inherit them); ``remote_env()`` applies them for one block of code.

``gdal_path("s3://bucket/dem.tif")`` is ``/vsis3/bucket/dem.tif``. GDAL reads S3 with the
credentials and endpoint the environment gives boto3 and s3fs (``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``, ``AWS_REGION``, ``AWS_PROFILE``, and an
S3-compatible server's ``AWS_ENDPOINT_URL_S3`` or ``AWS_ENDPOINT_URL``), handed to GDAL
explicitly for each open (``open_raster``: a rasterio ``AWSSession`` in a ``rasterio.Env``,
with GDAL's ``AWS_S3_ENDPOINT``, ``AWS_HTTPS`` and ``AWS_VIRTUAL_HOSTING`` for an endpoint:
``s3_options``); the process environment is never changed. A dataset opened keeps them for
its reads.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any
from urllib.parse import urlsplit

VSI_OPTIONS = {
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",  # no directory listing per open
    # GeoTIFF/VRT, and the PDS maps: VICAR/PDS .img with detached PDS4 .xml / PDS3 .lbl labels
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": (
        ".tif,.TIF,.tiff,.TIFF,.vrt,.VRT,.ovr,.OVR,.msk,.img,.IMG,.xml,.XML,.lbl,.LBL"
    ),
    "GDAL_HTTP_MAX_RETRY": "4",
    "GDAL_HTTP_RETRY_DELAY": "0.5",
    "GDAL_HTTP_TIMEOUT": "60",
    "GDAL_HTTP_MULTIRANGE": "YES",
    "VSI_CACHE": "TRUE",
}
_SCHEMES = ("http://", "https://")
_S3 = ("s3://", "/vsis3/")


def is_remote(path: object) -> bool:
    """True for http(s) and s3 URLs and GDAL ``/vsicurl/`` and ``/vsis3/`` paths."""
    text = str(path)
    return text.startswith((*_SCHEMES, *_S3)) or text.startswith("/vsicurl/")


def gdal_path(path: object) -> str:
    """The path GDAL opens: ``/vsicurl/<url>`` for an http(s) URL, ``/vsis3/<bucket>/<key>``
    for ``s3://<bucket>/<key>``, else the path as text."""
    text = str(path)
    if text.startswith(_SCHEMES):
        return "/vsicurl/" + text
    if text.startswith("s3://"):
        return "/vsis3/" + text.removeprefix("s3://")
    return text


def s3_options(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """GDAL's options for an S3-compatible endpoint given in ``environ`` (the process
    environment by default) as ``AWS_ENDPOINT_URL_S3`` or ``AWS_ENDPOINT_URL``
    (``http://127.0.0.1:9000``): ``AWS_S3_ENDPOINT`` (host:port), ``AWS_HTTPS`` (NO for
    http) and ``AWS_VIRTUAL_HOSTING`` FALSE (path-style requests); {} without one."""
    env = os.environ if environ is None else environ
    endpoint = env.get("AWS_ENDPOINT_URL_S3") or env.get("AWS_ENDPOINT_URL")
    if not endpoint:
        return {}
    url = urlsplit(endpoint if "://" in endpoint else "https://" + endpoint)
    return {
        "AWS_S3_ENDPOINT": url.netloc + url.path.rstrip("/"),
        "AWS_HTTPS": "NO" if url.scheme == "http" else "YES",
        "AWS_VIRTUAL_HOSTING": "FALSE",
    }


def _aws_session(environ: Mapping[str, str]) -> Any:
    """A rasterio AWSSession with the credentials of ``environ`` (None without boto3: GDAL
    then reads the credentials from the environment itself)."""
    try:
        import boto3  # noqa: F401 - rasterio's AWSSession needs it
        from rasterio.session import AWSSession
    except ImportError:
        return None
    key = environ.get("AWS_ACCESS_KEY_ID")
    return AWSSession(
        aws_access_key_id=key,
        aws_secret_access_key=environ.get("AWS_SECRET_ACCESS_KEY") if key else None,
        aws_session_token=environ.get("AWS_SESSION_TOKEN") if key else None,
        region_name=environ.get("AWS_REGION") or environ.get("AWS_DEFAULT_REGION"),
        profile_name=None if key else environ.get("AWS_PROFILE"),
        aws_unsigned=environ.get("AWS_NO_SIGN_REQUEST", "").upper() == "YES",
    )


@contextmanager
def gdal_env(path: object) -> Iterator[None]:
    """The GDAL options to open ``path`` with, for one block: for a ``/vsis3/`` path the
    environment's AWS credentials (``_aws_session``) and endpoint (``s3_options``); nothing
    for other paths."""
    if not str(path).startswith("/vsis3/"):
        yield
        return
    import rasterio

    env = dict(os.environ)
    options = s3_options(env)
    with rasterio.Env(session=_aws_session(env), **options):
        yield


def open_raster(path: object) -> Any:
    """``rasterio.open(path)`` with the GDAL options ``path`` needs (``gdal_env``)."""
    import rasterio

    with gdal_env(path):
        return rasterio.open(path)


def url_of(path: object) -> str:
    """The http(s) URL behind a ``/vsicurl/`` path (or the text itself)."""
    text = str(path)
    return text.removeprefix("/vsicurl/")


def use_remote_defaults() -> None:
    """Set the VSI options that the environment does not set already (inherited by workers)."""
    for key, value in VSI_OPTIONS.items():
        os.environ.setdefault(key, value)


@contextmanager
def remote_env(**overrides: str) -> Iterator[None]:
    """A rasterio.Env with the VSI options (and ``overrides``) for one block."""
    import rasterio

    options = {**VSI_OPTIONS, **{k: v for k, v in os.environ.items() if k in VSI_OPTIONS}}
    options.update(overrides)
    with rasterio.Env(**options):
        yield


def gdal_reason(exc: BaseException) -> str:
    """The reason GDAL gave for a rasterio read error: rasterio's own message for a failed
    read is "Read failed. See previous exception for details.", GDAL's (the block that
    failed, and why) is the exception it chains."""
    return str(exc.__cause__ or exc)
