"""Where the files the tool writes about a dataset go: beside its folder, never in it.

A dataset folder holds only what its build wrote (a rebuild refuses a folder holding anything
else: ``pipeline.builder.hygiene``), so a report, an overview picture or a GeoPackage written
into it would block the next build of the same config. Their default path is beside the folder
(``<folder>-report.html`` next to ``<folder>``), and a path inside the folder is refused.
"""

from __future__ import annotations

from pathlib import Path

from mars_pairs.errors import MarsPairsError


def beside(root: str | Path, suffix: str) -> Path:
    """The default path of an output about dataset folder ``root``: ``<root>-<suffix>`` in
    the folder that holds ``root`` (``root`` resolved, so ``.`` names its real folder)."""
    folder = Path(root).resolve()
    return folder.with_name(f"{folder.name}-{suffix}")


def outside(root: str | Path, out: str | Path, what: str) -> Path:
    """``out`` unless it lies inside dataset folder ``root``: then MarsPairsError naming both
    and the default (``what``: the output's suffix, e.g. ``report.html``). A folder that is no
    dataset (no manifest.parquet, no dataset.json) is left to the command to refuse."""
    out = Path(out)
    folder = Path(root).resolve()
    target = out.resolve()
    built = (folder / "manifest.parquet").exists() or (folder / "dataset.json").exists()
    if built and (target == folder or folder in target.parents):
        raise MarsPairsError(
            f"{out}: inside the dataset folder {root}, whose next build would refuse a file it "
            f"did not write; write it beside the folder (the default: {beside(root, what)})"
        )
    return out
