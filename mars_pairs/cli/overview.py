"""``mars-pairs overview DATASET``: all footprints over the orthoimage (a catalogue folder: its
footprints and pairs)
(:func:`~mars_pairs.viz.overview`; needs the viz extra)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import add_out, count, local_dataset


def register(sub: Any) -> None:
    """Add the ``overview`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("overview", help="all footprints over the orthoimage (needs the viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset or footprint catalogue folder")
    add_out(p, "PNG path (default DATASET-overview.png beside the folder)")
    p.add_argument(
        "--color-by",
        "--colour-by",
        dest="color_by",
        choices=("sol", "split", "instrument"),
        default="sol",
        help="colour the footprints by sol, by split (a dataset) or by instrument (a "
        "catalogue); default sol",
    )
    p.add_argument("--dpi", type=count(20), default=90, help="dots per inch (default 90)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the PNG; print its path."""
    from mars_pairs.viz import overview

    print(overview(args.dataset, args.out, colour_by=args.color_by, dpi=args.dpi))
    return 0
