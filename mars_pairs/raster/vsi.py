"""Remote rasters through GDAL's VSI HTTP reader: URL -> ``/vsicurl/`` path and its options.

``gdal_path("https://host/dem.tif")`` is ``/vsicurl/https://host/dem.tif``: GDAL then reads
the header and the blocks a window needs with HTTP range requests, never the whole file (a
COG or tiled GeoTIFF moves a small fraction of itself; a striped one whole strips).

The options (``VSI_OPTIONS``) stop GDAL listing the remote folder on open and set its HTTP
retries and timeouts. They are GDAL configuration options, read from the environment at each
request, so ``use_remote_defaults()`` sets the ones not already set in ``os.environ`` (build
workers inherit them); ``remote_env()`` applies them for one block of code.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

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


def is_remote(path: object) -> bool:
    """True for http(s) URLs and GDAL ``/vsicurl/`` paths."""
    text = str(path)
    return text.startswith(_SCHEMES) or text.startswith("/vsicurl/")


def gdal_path(path: object) -> str:
    """The path GDAL opens: ``/vsicurl/<url>`` for an http(s) URL, else the path as text."""
    text = str(path)
    if text.startswith(_SCHEMES):
        return "/vsicurl/" + text
    return text


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
