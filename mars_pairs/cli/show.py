"""``mars-pairs show DATASET KEY``: a figure of one sample
(:func:`~mars_pairs.report.show_sample`; needs the viz extra)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import add_out, local_dataset


def register(sub: Any) -> None:
    """Add the ``show`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("show", help="a figure of one sample (needs the viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    p.add_argument("key", help="sample key or product id (see mars-pairs query)")
    add_out(p, "PNG path (default KEY.png in the current directory)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the figure; print its path."""
    from mars_pairs.report import show_sample

    print(show_sample(args.dataset, args.key, args.out))
    return 0
