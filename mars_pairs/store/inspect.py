"""``mars-pairs inspect``: what a built dataset holds."""

from __future__ import annotations

import textwrap
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mars_pairs.errors import DatasetError
from mars_pairs.store import fs
from mars_pairs.store.dataset_info import read_dataset_info
from mars_pairs.store.query import Manifest


def _counts(title: str, counts: dict[str, int]) -> list[str]:
    return [f"{title}:", *(f"  {value!s:<24} {n:>8}" for value, n in counts.items())]


def split_warnings(dataset: str | Path) -> list[str]:
    """The split warnings a build recorded in ``dataset.json`` (``splits.warnings``: a
    configured split left empty); none for a dataset built before they were recorded or
    without a readable dataset.json."""
    try:
        return read_dataset_info(dataset, required=False).split_warnings
    except DatasetError:
        return []


#: Sol ranges listed in full on one line of the text report; more are summarised.
MAX_SOL_RANGES = 12


def sol_ranges(sols: Sequence[int]) -> list[tuple[int, int]]:
    """The runs of consecutive sols among ``sols`` (sorted numerically, each once), as
    (first, last) pairs."""
    runs: list[tuple[int, int]] = []
    for sol in sorted(set(sols)):
        if runs and sol == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], sol)
        else:
            runs.append((sol, sol))
    return runs


def _span(run: tuple[int, int]) -> str:
    return str(run[0]) if run[0] == run[1] else f"{run[0]}-{run[1]}"


def _view_coverage(table: pa.Table) -> dict[str, Any]:
    """How much of its chip each sample's view covers: the share of the chip box (dataset CRS)
    inside the footprint (the visible area's hull), median overall and per instrument, and
    the count of views that miss their chip."""
    import shapely

    feet = shapely.from_wkb(table.column("footprint").to_pylist())
    chips = shapely.from_wkb(table.column("chip_box").to_pylist())
    known = ~(shapely.is_missing(feet) | shapely.is_missing(chips))
    share = np.full(len(feet), np.nan)
    if known.any():
        inter = shapely.area(shapely.intersection(feet[known], chips[known]))
        share[known] = inter / np.maximum(shapely.area(chips[known]), 1e-12)
    instruments = np.array(table.column("instrument").to_pylist(), dtype=object)

    def median(mask: np.ndarray) -> float | None:
        values = share[mask & np.isfinite(share)]
        return round(float(np.median(values)), 4) if values.size else None

    return {
        "median": median(np.ones(len(share), bool)),
        "by_instrument": {str(i): median(instruments == i) for i in sorted(set(instruments))},
        "missing_the_chip": int(np.sum(np.isfinite(share) & (share <= 0.0))),
        "unknown": int(np.sum(~np.isfinite(share))),
    }


def inspect_facts(dataset: str | Path) -> dict[str, Any]:
    """What a built dataset holds: counts by mission, instrument and split (with each split's
    share), sols (numerically, as runs), view coverage, failures, warnings, size.
    ``dataset``: a local folder or an fsspec URL (``store.fs``)."""
    root = fs.dataset_root(dataset)
    columns = ["mission", "sol", "instrument", "split"]
    manifest = Manifest.open(root).require(columns)
    wanted = [*columns, *(c for c in ("footprint", "chip_box") if c in manifest.column_names)]
    table = manifest.to_table(columns=wanted)
    n = table.num_rows
    facts: dict[str, Any] = {"dataset": str(root), "samples": n}
    for name in ("mission", "instrument"):
        facts[f"by_{name}"] = dict(
            sorted(Counter(map(str, table.column(name).to_pylist())).items())
        )
    splits = Counter(map(str, table.column("split").to_pylist()))
    facts["by_split"] = {
        s: {"samples": c, "share": round(c / n, 4)} for s, c in sorted(splits.items())
    }
    sols = [int(v) for v in table.column("sol").to_pylist() if v is not None]
    facts["sols"] = {
        "distinct": len(set(sols)),
        "first": min(sols) if sols else None,
        "last": max(sols) if sols else None,
        "ranges": [_span(r) for r in sol_ranges(sols)],
        "by_sol": {str(k): v for k, v in sorted(Counter(sols).items())},
    }
    if "footprint" in table.column_names and "chip_box" in table.column_names and n:
        facts["view_coverage"] = _view_coverage(table)
    failures_path = fs.join(root, "failures.parquet")
    if fs.is_file(failures_path):
        try:
            failures = fs.read_parquet(failures_path, columns=["stage", "error_type"])
        except (pa.ArrowException, OSError, KeyError) as exc:
            raise DatasetError(failures_path, None, f"unreadable: {exc}") from None
        reasons = Counter(
            f"{s} ({e})"
            for s, e in zip(
                failures.column("stage").to_pylist(),
                failures.column("error_type").to_pylist(),
                strict=False,
            )
        )
        facts["failures"] = failures.num_rows
        facts["failures_by_reason"] = dict(sorted(reasons.items()))
    facts["warnings"] = split_warnings(root)
    facts["size_bytes"] = fs.total_size(root)
    return facts


def format_facts(facts: dict[str, Any]) -> str:
    """The text report of :func:`inspect_facts`."""
    lines = [f"dataset: {facts['dataset']}", f"samples: {facts['samples']}"]
    for name in ("mission", "instrument"):
        lines += _counts(name, facts[f"by_{name}"])
    lines.append("split:")
    lines += [
        f"  {s:<24} {v['samples']:>8}  {100 * v['share']:5.1f} %"
        for s, v in facts["by_split"].items()
    ]
    sols = facts["sols"]
    if sols["distinct"]:
        ranges = sols["ranges"]
        shown = ", ".join(ranges[:MAX_SOL_RANGES])
        if len(ranges) > MAX_SOL_RANGES:
            shown += f", ... ({len(ranges) - MAX_SOL_RANGES} more runs; --json lists them)"
        lines.append(
            f"sols: {sols['distinct']} from {sols['first']} to {sols['last']}, "
            f"{len(ranges)} runs of consecutive sols:"
        )
        lines += textwrap.wrap(shown, 96, initial_indent="  ", subsequent_indent="  ")
    cover = facts.get("view_coverage")
    if cover and cover["median"] is not None:
        per = ", ".join(
            f"{i} {100 * m:.1f} %" for i, m in cover["by_instrument"].items() if m is not None
        )
        lines.append(
            f"view coverage (share of the chip inside the footprint): median "
            f"{100 * cover['median']:.1f} % ({per}); {cover['missing_the_chip']} views miss "
            "their chip"
        )
    if "failures" in facts:
        lines.append(f"failures: {facts['failures']}")
        lines += [f"  {r!s:<24} {c:>8}" for r, c in facts["failures_by_reason"].items()]
    lines += [f"warning: {text}" for text in facts["warnings"]]
    lines.append(f"size on disk: {facts['size_bytes'] / 1e6:.1f} MB")
    return "\n".join(lines)


def inspect_dataset(dataset: str | Path) -> str:
    """The text report of ``dataset`` (:func:`inspect_facts`, :func:`format_facts`)."""
    return format_facts(inspect_facts(dataset))
