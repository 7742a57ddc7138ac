"""``mars-pairs show``: the figure files of one sample, read through :class:`MarsPairsDataset`
and drawn by :mod:`mars_pairs.viz.sample`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mars_pairs.errors import MarsPairsError
from mars_pairs.report.meta import camera_centres
from mars_pairs.store.members import OPTIONAL_FIELDS
from mars_pairs.store.query import Manifest
from mars_pairs.viz.common import DPI, pyplot
from mars_pairs.viz.sample import dense_figure, has_dense


def show_sample(root: str | Path, key: str, out: str | Path | None = None, dpi: int = DPI) -> Path:
    """The figure of the sample named ``key`` (its key or product id, any case) drawn by
    :meth:`MarsPairsDataset.plot` and written to ``out`` (PNG of ``SHOW_SIZE`` inches at
    ``dpi``; default ``<key>.png`` in the current directory, the sample's own key). A sample
    with dense members also gets their figure, ``<stem>_dense<suffix>`` beside ``out``."""
    from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset

    root = Path(root)
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    Manifest.open(root).require()  # a damaged or column-less manifest: one error naming it
    plt = pyplot()
    with MarsPairsDataset(root, fields=ALL_FIELDS + _dense_fields_of(root)) as ds:
        sample = ds[ds.index_of(key)]
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
