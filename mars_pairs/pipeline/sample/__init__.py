"""One observation -> one dataset sample, the stages in order (``build_sample``).

A stage per module: ``ground`` (the image, decoded and checked against its label), ``view``
(the camera anchored on the DEM, its viewshed and ray hits), ``chips`` (ortho, DEM and
viewshed chips, coverage, correspondence), ``dense`` (the optional per-pixel members),
``footprint`` (the view's footprint and statistics), ``record`` (the manifest row and
meta.json), ``encode`` (member bytes); ``context`` is what the samples of a worker share,
``stages`` the stage names and timings. Nothing here knows of the build that runs it
(``pipeline.builder``).

The public names below are resolved on first use, so importing one stage does not import
every other.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

#: public name -> the module that defines it
_HOMES = {
    "Sample": "build_sample",
    "build_sample": "build_sample",
    "SampleContext": "context",
    "Stages": "stages",
    "AnchoredView": "view",
    "View": "view",
    "anchor_view": "view",
    "label_view": "view",
    "view_stages": "build_sample",
    "GroundImage": "ground",
    "ground_image": "ground",
    "cut_chips": "chips",
    "dense_members": "dense",
    "manifest_row": "record",
    "sample_key": "key",
}

__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_HOMES[name]}"), name)
