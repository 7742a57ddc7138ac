"""A dataset build: many labels -> shards, a manifest and dataset.json (``run_build``).

``label_list`` streams the labels in one total order; ``plan`` checks the inputs and cuts the
labels into chunks, finding those a killed build finished; ``engine`` is the one contract the
engines implement (``InProcess`` here, ``local_pool.LocalPool``, ``dask_engine.DaskEngine``),
``worker`` what a worker process runs for one chunk; what the output folder keeps is
``layout`` (its file names), ``fingerprints`` (the inputs' identity), ``stamp`` (the build
stamp a resume must match) and ``hygiene`` (what may be cleared or resumed); ``commit``
what a built chunk commits (a pure selection, then the writes); ``finish`` the merge into
manifest.parquet and dataset.json; ``append`` what ``--append`` adds to a finished dataset (a
new release's labels as new chunks, merged at the end); ``run`` the driver that ties them. The
samples themselves are ``pipeline.sample``'s.

The public names below are resolved on first use (the Dask engine needs the ``dask`` extra).
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

#: public name -> the module that defines it
_HOMES = {
    "run_build": "run",
    "BuildSummary": "finish",
    "BuildPlan": "plan",
    "plan_build": "plan",
    "AppendPlan": "append",
    "plan_append": "append",
    "iter_matches": "label_list",
    "Engine": "engine",
    "ChunkTask": "engine",
    "ChunkResult": "engine",
    "InProcess": "engine",
    "LocalPool": "local_pool",
    "DaskEngine": "dask_engine",
}

__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_HOMES[name]}"), name)
