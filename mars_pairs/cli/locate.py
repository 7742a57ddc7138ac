"""``mars-pairs locate LABEL...``: read labels and place each image on the map (one summary
per label, :func:`~mars_pairs.store.describe.describe`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from mars_pairs.errors import MarsPairsError


def register(sub: Any) -> None:
    """Add the ``locate`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("locate", help="read labels and place each image on the map")
    p.add_argument("labels", nargs="+", help="PDS3 .LBL or PDS4 .xml label(s)")
    p.add_argument("--places", help="PLACES table (best_interp.csv / localized_interp.csv)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """One summary per label (text, or ``--json`` lines); a bad label is one line on stderr
    and the status 2, the other labels still printed."""
    import numpy as np

    from mars_pairs.geometry.places import Places
    from mars_pairs.pds import read_observation
    from mars_pairs.store.describe import describe

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
        try:
            with np.errstate(all="raise", under="ignore"):  # a number flushed to 0 is harmless
                summary = describe(obs, pose)
            _require_finite(summary)
        except (FloatingPointError, ValueError) as exc:
            print(f"mars-pairs locate: {label}: {exc}", file=sys.stderr)
            status = 2
            continue
        if args.json:
            print(json.dumps(summary, allow_nan=False), flush=True)
        else:
            width = max(len(k) for k in summary)
            print("\n".join(f"{k:<{width}}  {v}" for k, v in summary.items()), end="\n\n")
    return status


def _require_finite(summary: dict[str, object]) -> None:
    """ValueError naming the first field of ``summary`` that is not a finite number."""
    for key, value in summary.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{key}: not a finite number ({value}); check the camera model")
