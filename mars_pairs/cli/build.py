"""``mars-pairs build --config CONFIG``: build a dataset (:func:`~mars_pairs.pipeline.builder.
run.run_build`), generating the config's synthetic mission first when its files are absent."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from typing import TYPE_CHECKING, Any

from mars_pairs.cli.arguments import count
from mars_pairs.errors import ConfigError, UsageError

if TYPE_CHECKING:
    from mars_pairs.pipeline.builder.engine import Engine
    from mars_pairs.pipeline.config import BuildConfig


def register(sub: Any) -> None:
    """Add the ``build`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("build", help="build a dataset from a config")
    p.add_argument("--config", required=True, help="build configuration (YAML)")
    p.add_argument("--out", help="dataset folder or URL (s3://bucket/prefix; overrides output.dir)")
    p.add_argument("--workers", type=count(1), default=1, help="worker processes (default 1)")
    p.add_argument("--resume", action="store_true", help="keep finished shards of a killed build")
    p.add_argument(
        "--append",
        action="store_true",
        help="add the labels the finished dataset in the folder does not hold yet (a new "
        "release) as new shards; existing shards are kept; a killed append reruns with "
        "--append",
    )
    p.add_argument("--limit", type=count(1), help="build at most N observations")
    p.add_argument("--strict", action="store_true", help="stop at the first failure")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="check the config and inputs, list and chunk the labels, print the plan (labels, "
        "chunks, chunks done with --resume, samples to build); write nothing",
    )
    p.add_argument(
        "--engine",
        choices=("local", "dask"),
        default="local",
        help="local: this machine's process pool; dask: a Dask cluster (default local)",
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="with --engine dask: a running cluster's scheduler (default: a local cluster "
        "of --workers processes); its workers write the shards into --out, which they must "
        "reach at the same path",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build (or with ``--dry-run`` plan) the dataset; print the summary and split warnings."""
    from dataclasses import replace
    from pathlib import Path

    from mars_pairs.errors import BuildError
    from mars_pairs.pipeline.builder.run import run_build
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.store.fs import dataset_root
    from mars_pairs.store.inspect import split_warnings
    from mars_pairs.store.splits import EmptySplitWarning

    config = load_config(args.config)
    if args.out:
        out = dataset_root(args.out)
        if isinstance(out, Path):
            try:
                out = out.resolve()
            except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop (Python 3.11)
                raise ConfigError(f"--out: {args.out}: cannot resolve the path ({exc})") from None
        config = replace(config, output=replace(config.output, dir=out))
    if args.dry_run and args.append:  # the new labels and chunks; writes nothing
        from mars_pairs.pipeline.builder.append import plan_append

        print(plan_append(config).format())
        return 0
    if args.dry_run:  # lists, chunks and checks; writes nothing (nor a synthetic mission)
        from mars_pairs.pipeline.builder.plan import plan_build

        plan = plan_build(config, resume=args.resume, limit=args.limit, generate=True)
        print(plan.format())
        return 0
    mission_seconds = _ensure_synthetic(config, workers=args.workers)
    engine = _engine(args)
    started = time.perf_counter()
    try:
        with warnings.catch_warnings():  # printed below, from dataset.json, with the summary
            warnings.simplefilter("ignore", EmptySplitWarning)
            summary = run_build(
                config,
                engine=engine,
                workers=args.workers,
                resume=args.resume,
                limit=args.limit,
                strict=args.strict,
                progress=not args.quiet,
                append=args.append,
            )
    except BuildError as exc:
        print(f"mars-pairs build: --strict: {exc}", file=sys.stderr)
        return 2
    print(summary.format())
    print(phase_line(mission_seconds, summary.seconds, time.perf_counter() - started))
    for text in split_warnings(summary.out_dir):
        print(f"warning: {text}")
    return 0


def _engine(args: argparse.Namespace) -> Engine | None:
    """The build engine the options name: None (the local pool) or a DaskEngine."""
    if args.engine == "local":
        if args.scheduler:
            raise UsageError("--scheduler needs --engine dask")
        return None
    from mars_pairs.pipeline.builder.dask_engine import DaskEngine

    return DaskEngine(scheduler=args.scheduler, workers=args.workers)


def phase_line(mission_seconds: float | None, build_seconds: float, total_seconds: float) -> str:
    """The build's line of each phase's own time: the mission's generation (when this run
    generated it: ``mission_seconds``), the build (``BuildSummary.seconds``) and its finish
    (the rest of ``total_seconds``, the build's whole call: the dataset's card, index and
    record)."""
    mission = "" if mission_seconds is None else f"mission generation {mission_seconds:.1f} s, "
    finish = max(0.0, total_seconds - build_seconds)
    return f"phases: {mission}build {build_seconds:.1f} s, finish {finish:.1f} s"


def _ensure_synthetic(config: BuildConfig, workers: int = 1) -> float | None:
    """Generate the config's synthetic mission when its files are absent (the demo), its
    images rendered by ``workers`` processes; the seconds it took (with the wait for the
    kernels' compile), None when the mission was there."""
    from mars_pairs.pipeline.builder.label_list import iter_matches

    spec = config.inputs.synthetic
    inputs = config.inputs
    if spec is None:
        return None
    from pathlib import Path

    dem_there = not isinstance(inputs.dem, Path) or inputs.dem.exists()  # (a str: remote)
    if dem_there and inputs.places.exists() and next(iter_matches(inputs.labels), None):
        return None
    import subprocess

    from mars_pairs.synth import generate_mission

    t0 = time.perf_counter()
    # numba compiles the kernels once (``python -m mars_pairs.warmup``, which the Makefile runs
    # at install; then they load from its cache): in a process of its own, on the other core,
    # while the mission is generated; the render and build workers then load them
    print(
        "loading the kernels in the background (compiled once: `python -m mars_pairs.warmup`, "
        "which make demo runs at install; else here, ~40 s of CPU) ..."
    )
    warm = subprocess.Popen(  # it prints its own time (s): the loading's, not the mission's
        [
            sys.executable,
            "-c",
            "import time; t = time.perf_counter(); "
            "from mars_pairs.warmup import warm_all as w; w(); "
            "print(round(time.perf_counter() - t))",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    print(f"generating the synthetic {spec.mission} mission in {spec.root} ...", flush=True)
    try:
        generate_mission(
            spec.root,
            seed=spec.seed,
            mission=spec.mission,
            stops=spec.stops,
            images_per_stop=spec.images_per_stop,
            size=spec.size,
            log=lambda line: print(f"  {line}", flush=True),
            # terrain labels read from inside the mission: its AI4Mars-layout truth
            terrain_labels=inputs.terrain_labels is not None
            and inputs.terrain_labels.root.is_relative_to(spec.root),
            workers=workers,
        )
    except BaseException:
        warm.kill()
        warm.wait()
        raise
    print(f"mission generated ({time.perf_counter() - t0:.0f} s)", flush=True)
    t1 = time.perf_counter()
    own, err = warm.communicate()
    waited = time.perf_counter() - t1
    if warm.returncode:  # the workers compile what is missing themselves
        print(f"compiling the kernels failed ({err.strip()[-300:]}); the workers will retry")
    else:
        print(
            f"kernels ready ({own.strip() or '?'} s, beside the mission; {waited:.0f} s "
            "waited after it); building ...",
            flush=True,
        )
    return time.perf_counter() - t0
