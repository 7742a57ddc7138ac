"""A Dask worker preload for long-lived clusters: ``dask worker --preload
mars_pairs.pipeline.builder.dask_preload ...``.

When the worker process starts (before any build reaches it) it applies the process settings
(``mars_pairs.runtime.configure_process``), imports the build's modules and loads the compiled
kernels, so the first chunk of every build finds a warm worker, as the local pool's fork
server gives its workers. Without it a worker does the same work when a build registers its
plugin (``dask_engine``), inside that build's time. Opening a build's rasters stays per build.
"""

from __future__ import annotations

from typing import Any


def dask_setup(worker: Any) -> None:
    """Dask's preload hook: settings, modules and kernels of a build worker."""
    from mars_pairs.runtime import configure_process

    configure_process()
    from mars_pairs.kernels.warm import warm_kernels
    from mars_pairs.pipeline.builder import dask_engine, engine  # noqa: F401

    warm_kernels()
