"""``mars-pairs synth --out FOLDER``: generate the synthetic mission (terrain, labels, images;
:func:`~mars_pairs.synth.generate_mission`)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from mars_pairs.cli.arguments import add_out, count, required_out_path


def register(sub: Any) -> None:
    """Add the ``synth`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("synth", help="generate the synthetic mission (terrain, labels, images)")
    add_out(p, "output folder", required=True, positional=True)
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--mission", choices=("m2020", "msl", "both"), default="m2020")
    p.add_argument("--stops", type=count(1), help="rover stops (default: the size's: 3, 8, 90)")
    p.add_argument("--images-per-stop", type=count(1), help="default: the size's (4, 4, 3)")
    p.add_argument("--size", choices=("small", "default", "demo"), default="small")
    p.add_argument(
        "--terrain-labels",
        action="store_true",
        help="also write the true terrain classes and AI4Mars-layout masks",
    )
    p.add_argument(
        "--workers",
        type=count(1),
        default=1,
        help="processes rendering the images (default 1: this one); the same bytes for any",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Generate the mission; print what was written (JSON)."""
    from mars_pairs.synth import generate_mission

    result = generate_mission(
        required_out_path(args),
        seed=args.seed,
        mission=args.mission,
        stops=args.stops,
        images_per_stop=args.images_per_stop,
        size=args.size,
        terrain_labels=args.terrain_labels,
        workers=args.workers,
    )
    print(json.dumps(result, indent=2, default=str))
    return 0
