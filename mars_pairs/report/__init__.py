"""Files written about a built dataset that read its samples through :mod:`mars_pairs.torch`:
the HTML page of ``mars-pairs report`` (:func:`write_report`) and the figure of one sample
of ``mars-pairs show`` (:func:`show_sample`).

The layers, each importing only those below it:

- :mod:`mars_pairs.viz` draws figures from arrays, manifest rows and dataset.json (the
  overview, a sample's figure, the report's map, histograms and gallery card); it never
  imports torch.
- :mod:`mars_pairs.torch` reads samples; ``MarsPairsDataset.plot`` draws with ``viz``.
- :mod:`mars_pairs.report` (here) opens a dataset with ``torch`` and writes ``viz``'s
  figures to files; the CLI calls it.

torch and matplotlib are imported inside the functions (the ``torch`` and ``viz`` extras).
"""

from mars_pairs.report.page import report_html, write_report
from mars_pairs.report.show import show_sample

__all__ = ["report_html", "show_sample", "write_report"]
