"""``mars-pairs show DATASET [KEY | --index N | --random]``: a figure of one sample
(:func:`~mars_pairs.report.show_sample`; needs the viz extra)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import add_out, local_dataset


def register(sub: Any) -> None:
    """Add the ``show`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("show", help="a figure of one sample (needs the viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    pick = p.add_mutually_exclusive_group()
    pick.add_argument("key", nargs="?", help="sample key or product id (default: the first)")
    pick.add_argument("--index", type=int, help="the sample at this row (manifest order)")
    pick.add_argument("--random", action="store_true", help="a sample drawn at random")
    p.add_argument("--seed", type=int, help="with --random: the same draw every time")
    p.add_argument("--dpi", type=int, default=90, help="PNG resolution (default 90)")
    add_out(p, "PNG path (default KEY.png in the current directory)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the figure; print its path."""
    from mars_pairs.report import show_sample

    print(
        show_sample(
            args.dataset,
            args.key,
            args.out,
            args.dpi,
            index=args.index,
            seed=args.seed,
            pick_random=args.random,
        )
    )
    return 0
