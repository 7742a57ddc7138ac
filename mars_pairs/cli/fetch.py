"""``mars-pairs fetch products|places|orbital|all --config CONFIG``: the command lives with
the fetch package (:mod:`mars_pairs.fetch.cli`); this module registers it."""

from __future__ import annotations

from typing import Any


def register(sub: Any) -> None:
    """Add the ``fetch`` subparser (and its subcommands) to the top-level subparsers ``sub``."""
    from mars_pairs.fetch.cli import add_fetch_parser

    add_fetch_parser(sub)
