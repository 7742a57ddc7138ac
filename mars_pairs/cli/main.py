"""The ``mars-pairs`` command line: the top-level parser and the error-to-exit-code contract.

Each command is its own module (``mars_pairs/cli/<command>.py``) with ``register(sub)``,
which adds its subparser and sets ``func=run``, and ``run(args) -> int``; this module only
calls ``register``. Bad input (a :class:`~mars_pairs.errors.MarsPairsError`, a missing or
unwritable path) exits with status 2 and one line on stderr, ``mars-pairs COMMAND: ...``;
Ctrl-C exits 130 with one line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import mars_pairs.cli.build as build
import mars_pairs.cli.catalog as catalog
import mars_pairs.cli.export_qgis as export_qgis
import mars_pairs.cli.fetch as fetch
import mars_pairs.cli.inspect as inspect
import mars_pairs.cli.locate as locate
import mars_pairs.cli.overview as overview
import mars_pairs.cli.query as query
import mars_pairs.cli.report as report
import mars_pairs.cli.show as show
import mars_pairs.cli.synth as synth
import mars_pairs.cli.terrain_map as terrain_map
import mars_pairs.cli.verify as verify
import mars_pairs.cli.viewshed as viewshed
from mars_pairs.cli.arguments import OneLineParser, VersionAction
from mars_pairs.errors import MarsPairsError
from mars_pairs.runtime import configure_process


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command."""
    parser = OneLineParser(
        prog="mars-pairs",
        description="Paired aerial/ground ML datasets from Mars rover images and orbital maps.",
    )
    parser.add_argument(
        "--version", action=VersionAction, help="the package's and key libraries' versions"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    locate.register(sub)
    viewshed.register(sub)
    build.register(sub)
    catalog.register(sub)
    inspect.register(sub)
    verify.register(sub)
    query.register(sub)
    show.register(sub)
    overview.register(sub)
    report.register(sub)
    export_qgis.register(sub)
    fetch.register(sub)
    synth.register(sub)
    terrain_map.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mars-pairs`` console script."""
    configure_process()
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (MarsPairsError, OSError) as exc:  # a missing or unwritable path too
        print(f"mars-pairs {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line, no traceback (a build's workers are gone)
        print(f"mars-pairs {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
