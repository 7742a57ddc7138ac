"""``mars-pairs verify DATASET``: check every member's tar header, size and checksum
(:func:`~mars_pairs.store.verify.verify_dataset`); damage exits 2, listed on stderr."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(sub: Any) -> None:
    """Add the ``verify`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("verify", help="check every member's tar header, size and checksum")
    p.add_argument("dataset", help="dataset folder, or its URL (s3://bucket/prefix)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the report: on stdout (0) when intact, on stderr (2) when damaged."""
    from mars_pairs.store.verify import verify_dataset

    report = verify_dataset(args.dataset)
    if report.damage:
        print(report.format(), file=sys.stderr)
        return 2
    print(report.format())
    return 0
