"""Figures of a built dataset drawn from arrays, manifest rows and dataset.json: all
footprints on the map (``overview``), one sample (``sample_figure``, ``dense_figure``, what
``MarsPairsDataset.plot`` returns), the report's map, histograms and gallery card
(``report_figures``). viz never imports torch: the files written from a dataset's samples
(``mars-pairs show``, ``mars-pairs report``) are :mod:`mars_pairs.report`'s."""

from mars_pairs.viz.overview import overview, overview_figure
from mars_pairs.viz.sample import dense_figure, sample_figure

__all__ = ["dense_figure", "overview", "overview_figure", "sample_figure"]
