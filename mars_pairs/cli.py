"""The ``mars-pairs`` command line. Bad input exits with status 2 and one line on stderr."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from mars_pairs.errors import MarsPairsError


def _cmd_locate(args: argparse.Namespace) -> int:
    from mars_pairs.labels import read_observation
    from mars_pairs.locate import describe
    from mars_pairs.places import Places

    places = Places.from_csv(args.places) if args.places else None
    status = 0
    for label in args.labels:
        try:
            obs = read_observation(label)
            pose = places.locate(obs) if places is not None else None
        except MarsPairsError as exc:
            print(f"mars-pairs locate: {exc}", file=sys.stderr)
            status = 2
            continue
        summary = describe(obs, pose)
        if args.json:
            print(json.dumps(summary), flush=True)
        else:
            width = max(len(k) for k in summary)
            print("\n".join(f"{k:<{width}}  {v}" for k, v in summary.items()), end="\n\n")
    return status


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="mars-pairs",
        description="Paired aerial/ground ML datasets from Mars rover images and orbital maps.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("locate", help="read labels and place each image on the map")
    p.add_argument("labels", nargs="+", help="PDS3 .LBL or PDS4 .xml label(s)")
    p.add_argument("--places", help="PLACES table (best_interp.csv / localized_interp.csv)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=_cmd_locate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mars-pairs`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except MarsPairsError as exc:
        print(f"mars-pairs {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
