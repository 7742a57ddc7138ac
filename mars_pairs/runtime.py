"""Process-wide settings, applied explicitly at process start, never on import.

Two things live here, each listed once:

- :data:`PROCESS_DEFAULTS`: environment variables this package's processes run with, unless
  the user set them. ``OMP_WAIT_POLICY=PASSIVE``: numba's OpenMP threading layer otherwise
  busy-waits at the end of every parallel loop, and on a machine shared with other CPU-bound
  jobs the spinning thread takes the core the straggling one needs (a 2-thread kernel then
  runs slower than a 1-thread one; timings in ``benchmarks/README.md``). OpenMP reads it once,
  when its library loads: numba loads it lazily, at the first call of a parallel kernel in the
  process (``numba.np.ufunc.parallel._launch_threads``), so :func:`configure_process` must run
  before that call; importing numba or ``mars_pairs.kernels`` does not load it.
- :data:`BUILD_SETTING_PREFIXES` / :data:`BUILD_SETTING_NAMES`: the driver's environment
  variables a build's worker processes take (:func:`build_settings` in the driver,
  :func:`take_build_settings` in the worker). A fork server's workers inherit the server's
  environment from when it started; GDAL, cloud-storage, proxy, OpenMP and numba options set
  in the driver since (a notebook) must reach them. Nothing else of the driver's environment does.

Who calls :func:`configure_process`: the ``mars-pairs`` command line before any command, a
local build worker and a Dask build worker when they start. A library user who runs the
kernels (``compute_viewshed``, an in-process ``run_build``) calls it first::

    from mars_pairs.runtime import configure_process
    configure_process()
"""

from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping
from types import MappingProxyType

from mars_pairs.errors import ArgumentError

#: Environment defaults of every mars-pairs process; a value already set wins.
PROCESS_DEFAULTS: Mapping[str, str] = MappingProxyType({"OMP_WAIT_POLICY": "PASSIVE"})

#: Variable-name prefixes a build worker takes from the driver: GDAL and PROJ options
#: (``GDAL_HTTP_*``, ``CPL_VSIL_*``, ``VSI_CACHE``...), the credentials and endpoints of GDAL's
#: cloud file systems (``/vsis3``, ``/vsigs``, ``/vsiaz``, ``/vsioss``, ``/vsiswift``), OpenMP
#: options (read when a worker's first parallel kernel loads OpenMP) and numba's (numba
#: rereads them when it compiles and when it starts its threads).
BUILD_SETTING_PREFIXES: tuple[str, ...] = (
    "GDAL_",
    "CPL_",
    "VSI_",
    "PROJ_",
    "AWS_",
    "GS_",
    "GOOGLE_",
    "AZURE_",
    "OSS_",
    "SWIFT_",
    "OMP_",
    "NUMBA_",
)

#: Exact variable names a build worker takes from the driver: proxies and TLS certificates
#: (used by GDAL's curl for ``/vsicurl`` and the cloud file systems).
BUILD_SETTING_NAMES: frozenset[str] = frozenset(
    {
        "HTTP_PROXY",
        "HTTPS_PROXY",
        "NO_PROXY",
        "http_proxy",
        "https_proxy",
        "no_proxy",
        "CURL_CA_BUNDLE",
        "SSL_CERT_FILE",
        "SSL_CERT_DIR",
    }
)


def is_build_setting(name: str) -> bool:
    """Whether environment variable ``name`` is one a build worker takes from the driver."""
    return name in BUILD_SETTING_NAMES or name.startswith(BUILD_SETTING_PREFIXES)


def configure_process(environ: MutableMapping[str, str] | None = None) -> None:
    """Set :data:`PROCESS_DEFAULTS` in ``environ`` (default ``os.environ``) where not set.

    Call at process start, before the first parallel numba kernel runs; idempotent."""
    target = os.environ if environ is None else environ
    for name, value in PROCESS_DEFAULTS.items():
        target.setdefault(name, value)


def build_settings(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The build settings of ``environ`` (default ``os.environ``): the variables a build's
    worker processes take from the driver (:func:`is_build_setting`)."""
    source = os.environ if environ is None else environ
    return {name: value for name, value in source.items() if is_build_setting(name)}


def take_build_settings(
    settings: Mapping[str, str], environ: MutableMapping[str, str] | None = None
) -> None:
    """Make the build settings of ``environ`` (default ``os.environ``) exactly ``settings``
    (the driver's :func:`build_settings`): each is set, and a build setting ``settings`` lacks
    is removed (the driver unset it). Other variables are left as they are."""
    target = os.environ if environ is None else environ
    for name in settings:
        if not is_build_setting(name):
            raise ArgumentError(f"{name!r} is not a build setting (mars_pairs.runtime)")
    for name in [name for name in target if is_build_setting(name) and name not in settings]:
        del target[name]
    target.update(settings)
