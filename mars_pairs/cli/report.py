"""``mars-pairs report DATASET``: one self-contained HTML page of a dataset
(:func:`~mars_pairs.report.write_report`; needs the viz extra)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import add_out, count, local_dataset


def register(sub: Any) -> None:
    """Add the ``report`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("report", help="one self-contained HTML page of a dataset (viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset or footprint catalogue folder")
    add_out(p, "HTML path (default DATASET-report.html beside the folder)")
    p.add_argument("--samples", type=count(0), default=12, help="gallery samples (default 12)")
    p.add_argument("--dpi", type=count(20), default=90, help="figures' dots per inch (default 90)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the page; print its path."""
    from mars_pairs.report import write_report

    print(write_report(args.dataset, args.out, samples=args.samples, dpi=args.dpi))
    return 0
