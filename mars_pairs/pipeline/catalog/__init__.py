"""The footprint catalogue: every image's visible footprint, without chips (``run_catalog``).

``entry`` is one label's row (the build's stages up to the view, then the outline), ``chunk``
what a worker runs for a chunk of labels, ``run`` the driver (the build's engines, resume,
the merge into catalog.parquet, failures.parquet, pairs.parquet, catalog.json, README.md).
"""

from __future__ import annotations

from typing import Any

__all__ = ["CatalogSummary", "run_catalog"]


def __getattr__(name: str) -> Any:
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from mars_pairs.pipeline.catalog import run

    return getattr(run, name)
