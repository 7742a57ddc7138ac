"""``mars-pairs inspect``: what a built dataset holds."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs
from mars_pairs.store.dataset_info import read_dataset_info
from mars_pairs.store.query import Manifest


def _counts(title: str, values: Sequence[object]) -> list[str]:
    lines = [f"{title}:"]
    lines += [f"  {value!s:<24} {n:>8}" for value, n in sorted(Counter(values).items(), key=str)]
    return lines


def split_warnings(dataset: str | Path) -> list[str]:
    """The split warnings a build recorded in ``dataset.json`` (``splits.warnings``: a
    configured split left empty); none for a dataset built before they were recorded or
    without a readable dataset.json."""
    try:
        return read_dataset_info(dataset, required=False).split_warnings
    except DatasetError:
        return []


def inspect_dataset(dataset: str | Path) -> str:
    """A text report: counts by mission, sol, instrument and split; failures; size.
    ``dataset``: a local folder or an fsspec URL (``store.fs``)."""
    root = fs.dataset_root(dataset)
    columns = ["mission", "sol", "instrument", "split"]
    manifest = Manifest.open(root).require(columns).to_table(columns=columns)
    lines = [f"dataset: {root}", f"samples: {manifest.num_rows}"]
    for name in ("mission", "instrument", "split", "sol"):
        lines += _counts(name, manifest.column(name).to_pylist())
    failures_path = fs.join(root, "failures.parquet")
    if fs.is_file(failures_path):
        try:
            failures = fs.read_parquet(failures_path, columns=["stage", "error_type"])
        except (pa.ArrowException, OSError, KeyError) as exc:
            raise DatasetError(failures_path, None, f"unreadable: {exc}") from None
        reasons = [
            f"{s} ({e})"
            for s, e in zip(
                failures.column("stage").to_pylist(),
                failures.column("error_type").to_pylist(),
                strict=False,
            )
        ]
        lines.append(f"failures: {failures.num_rows}")
        lines += _counts("failures by reason", reasons)[1:] if reasons else []
    lines += [f"warning: {text}" for text in split_warnings(root)]
    lines.append(f"size on disk: {fs.total_size(root) / 1e6:.1f} MB")
    return "\n".join(lines)
