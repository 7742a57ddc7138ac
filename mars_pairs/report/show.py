"""``mars-pairs show``: the figure files of one sample, read through :class:`MarsPairsDataset`
and drawn by :mod:`mars_pairs.viz.sample`."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

from mars_pairs.errors import ArgumentError, MarsPairsError
from mars_pairs.report.meta import camera_centres
from mars_pairs.store.members import OPTIONAL_FIELDS
from mars_pairs.store.query import Manifest
from mars_pairs.viz.common import DPI, pyplot
from mars_pairs.viz.sample import dense_figure, has_dense


def show_sample(
    root: str | Path,
    key: str | None = None,
    out: str | Path | None = None,
    dpi: int = DPI,
    *,
    index: int | None = None,
    seed: int | None = None,
    pick_random: bool = False,
) -> Path:
    """The figure of one sample drawn by :meth:`MarsPairsDataset.plot` and written to ``out``
    (PNG at ``dpi``; default ``<key>.png`` in the current directory, the sample's own key).

    The sample: the one named by ``key`` (its key or product id, any case), else the one at
    ``index`` (manifest order, negative from the end), else with ``pick_random`` one drawn
    at random (``seed``: the same draw each time), else the first. A sample with dense
    members also gets their figure, ``<stem>_dense<suffix>`` beside ``out``."""
    from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset

    root = Path(root)
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    if isinstance(dpi, bool) or not isinstance(dpi, int) or not 10 <= dpi <= 1200:
        raise ArgumentError(f"dpi: expected an integer from 10 to 1200, got {dpi!r}")
    Manifest.open(root).require()  # a damaged or column-less manifest: one error naming it
    plt = pyplot()
    fields = ALL_FIELDS + _dense_fields_of(root)
    with MarsPairsDataset(root, fields=fields, pad=False) as ds:
        if len(ds) == 0:
            raise MarsPairsError(f"{root}: the dataset has no samples to show")
        if key is not None:
            i = ds.index_of(key)
        elif index is not None:
            i = int(index)
        elif pick_random:
            i = random.Random(seed).randrange(len(ds))
        else:
            i = 0
        sample = ds[i]
        out = Path(out) if out is not None else Path(f"{sample['meta']['key']}.png")
        own_key = sample["meta"]["key"]
        centre = camera_centres(root, [own_key])[own_key]
        if centre is not None:
            sample["meta"] = {**sample["meta"], "camera_center_map": centre}
        fig = ds.plot(sample)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi)
    finally:
        plt.close(fig)
    if has_dense(sample):
        _save_dense(sample, out, dpi)
    return out


def _dense_fields_of(root: Path) -> tuple[str, ...]:
    """The optional dense fields whose members the dataset's manifest locates."""
    names = set(Manifest.open(root).column_names)
    return tuple(f for f in OPTIONAL_FIELDS if f"{f}_offset" in names)


def _save_dense(sample: dict[str, Any], out: Path, dpi: int) -> Path:
    """The dense members' figure beside ``out``: ``<stem>_dense<suffix>``."""
    plt = pyplot()
    path = out.with_name(f"{out.stem}_dense{out.suffix}")
    fig = dense_figure(sample)
    try:
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
    return path
