"""``mars-pairs inspect DATASET``: counts, failures and size of a built dataset
(:func:`~mars_pairs.store.inspect.inspect_dataset`)."""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: Any) -> None:
    """Add the ``inspect`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("inspect", help="counts, failures and size of a built dataset")
    p.add_argument("dataset", help="dataset folder, or its URL (s3://bucket/prefix)")
    p.add_argument("--json", action="store_true", help="the facts as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the dataset's report."""
    from mars_pairs.store.inspect import format_facts, inspect_facts

    facts = inspect_facts(args.dataset)
    print(json.dumps(facts, indent=2) if args.json else format_facts(facts))
    return 0
