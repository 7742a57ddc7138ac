"""``mars-pairs catalog``: every image's visible footprint, no chips, into a catalogue folder
(``pipeline.catalog.run_catalog``)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import count
from mars_pairs.errors import UsageError


def register(sub: Any) -> None:
    """Add the ``catalog`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    p = sub.add_parser(
        "catalog",
        help="every image's visible footprint and the pairs that saw the same ground (no chips)",
    )
    p.add_argument("--config", required=True, help="build configuration (YAML): its inputs")
    p.add_argument("--out", required=True,
                   help="catalogue folder, or a URL (s3://bucket/prefix: made locally, then "
                   "uploaded, catalog.json last)")  # fmt: skip
    p.add_argument("--workers", type=count(1), default=1, help="worker processes (default 1)")
    p.add_argument("--resume", action="store_true", help="keep the chunks of a killed run")
    p.add_argument("--append", action="store_true",
                   help="add the labels the catalogue does not hold yet (a new release); the "
                   "existing rows are kept, pairs recomputed over all; a killed append reruns "
                   "with --append")  # fmt: skip
    p.add_argument("--no-pairs", action="store_true", help="do not write pairs.parquet")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--engine", choices=("local", "dask"), default="local",
                   help="local: this machine's process pool; dask: a Dask cluster")  # fmt: skip
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="with --engine dask: a running cluster's scheduler")  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``mars-pairs catalog``; one summary line."""
    from pathlib import Path

    from mars_pairs.pipeline.catalog.run import run_catalog
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.store.fs import is_url

    config = load_config(args.config)
    engine = None
    if args.engine == "dask":
        from mars_pairs.pipeline.builder.dask_engine import DaskEngine

        engine = DaskEngine(scheduler=args.scheduler, workers=args.workers)
    elif args.scheduler:
        raise UsageError("--scheduler needs --engine dask")
    summary = run_catalog(
        config,
        args.out if is_url(args.out) else Path(args.out),
        workers=args.workers,
        resume=args.resume,
        engine=engine,
        progress=not args.quiet,
        pairs=not args.no_pairs,
        append=args.append,
    )
    print(
        f"{summary.out_dir}: {summary.images} images, {summary.failures} failures, "
        f"{summary.pairs} pairs; {summary.chunks_built} chunks built, "
        f"{summary.chunks_resumed} kept; {summary.seconds:.1f} s"
    )
    for reason, n in sorted(summary.failures_by_reason.items()):
        print(f"  failed: {reason}: {n}")
    return 0
