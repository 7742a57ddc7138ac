"""Pictures of a built dataset: one sample (``show_sample``), all footprints (``overview``)."""

from mars_pairs.viz.overview import overview, overview_figure
from mars_pairs.viz.sample import show_sample

__all__ = ["overview", "overview_figure", "show_sample"]
