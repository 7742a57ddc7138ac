"""The ``mars-pairs`` command line. Bad input exits with status 2 and one line on stderr."""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from mars_pairs.cli.arguments import VersionAction, bounded, count, finite
from mars_pairs.cli.catalog import register as register_catalog
from mars_pairs.cli.summary import split_warnings
from mars_pairs.cli.viewshed import cmd_viewshed
from mars_pairs.errors import MarsPairsError, UsageError
from mars_pairs.pipeline.builder.label_list import iter_matches
from mars_pairs.pipeline.config import MAX_RADIUS_M
from mars_pairs.runtime import configure_process
from mars_pairs.store.splits import EmptySplitWarning

if TYPE_CHECKING:
    from mars_pairs.pipeline.builder.engine import Engine
    from mars_pairs.pipeline.config import BuildConfig


def _cmd_locate(args: argparse.Namespace) -> int:
    from mars_pairs.cli.locate import describe
    from mars_pairs.geometry.places import Places
    from mars_pairs.pds import read_observation

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


def _cmd_build(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from mars_pairs.errors import BuildError
    from mars_pairs.pipeline.builder.run import run_build
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.store.fs import dataset_root

    config = load_config(args.config)
    if args.out:
        out = dataset_root(args.out)
        out = out.resolve() if isinstance(out, Path) else out
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
    _ensure_synthetic(config)
    engine = _engine(args)
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


def _ensure_synthetic(config: BuildConfig) -> None:
    """Generate the config's synthetic mission when its files are absent (the demo)."""
    spec = config.inputs.synthetic
    inputs = config.inputs
    if spec is None:
        return
    from pathlib import Path

    dem_there = not isinstance(inputs.dem, Path) or inputs.dem.exists()  # (a str: remote)
    if dem_there and inputs.places.exists() and next(iter_matches(inputs.labels), None):
        return
    import subprocess
    import time

    from mars_pairs.synth import generate_mission

    t0 = time.perf_counter()
    # numba compiles the build's kernels once (then loads them from its cache): in a process
    # of its own, on the other core, while the mission is generated; the workers then load it
    print("compiling the build's kernels in the background (first run: ~20 s of CPU) ...")
    warm = subprocess.Popen(
        [sys.executable, "-c", "from mars_pairs.kernels.warm import warm_kernels as w; w()"],
        stdout=subprocess.DEVNULL,
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
        )
    except BaseException:
        warm.kill()
        warm.wait()
        raise
    print(f"mission generated ({time.perf_counter() - t0:.0f} s)", flush=True)
    _, err = warm.communicate()
    if warm.returncode:  # the workers compile what is missing themselves
        print(f"compiling the kernels failed ({err.strip()[-300:]}); the workers will retry")
    else:
        print(f"kernels compiled ({time.perf_counter() - t0:.0f} s); building ...", flush=True)


def _cmd_inspect(args: argparse.Namespace) -> int:
    from mars_pairs.cli.summary import inspect_dataset

    print(inspect_dataset(args.dataset))
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from mars_pairs.cli.verify import verify_dataset

    report = verify_dataset(args.dataset)
    if report.damage:
        print(report.format(), file=sys.stderr)
        return 2
    print(report.format())
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    from mars_pairs.synth import generate_mission

    result = generate_mission(
        args.out,
        seed=args.seed,
        mission=args.mission,
        stops=args.stops,
        images_per_stop=args.images_per_stop,
        size=args.size,
    )
    print(json.dumps(result, indent=2, default=str))
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from mars_pairs.report import show_sample

    print(show_sample(args.dataset, args.key, args.out))
    return 0


def _cmd_overview(args: argparse.Namespace) -> int:
    from mars_pairs.viz import overview

    print(overview(args.dataset, args.out, colour_by=args.colour_by))
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from mars_pairs.report import write_report

    print(write_report(args.dataset, args.out, samples=args.samples))
    return 0


def _cmd_export_qgis(args: argparse.Namespace) -> int:
    from mars_pairs.cli.qgis import export_geopackage

    print(
        export_geopackage(
            args.dataset, args.out, with_viewsheds=args.viewsheds, with_chips=args.chips
        )
    )
    return 0


def _cmd_query(args: argparse.Namespace) -> int:
    from mars_pairs.cli.query import check_query_splits, filter_arguments, run_query

    if args.saw is not None or args.overlaps is not None:
        from mars_pairs.cli.query import footprint_query

        return footprint_query(args.dataset, args.saw, args.overlaps, args.format, args.out)
    filters = filter_arguments(
        bbox=args.bbox,
        bbox_map=args.bbox_map,
        near=args.near,
        polygon=args.polygon,
        mission=args.mission,
        instrument=args.instrument,
        split=args.split,
        sol=args.sol,
    )
    check_query_splits(args.dataset, filters.get("split"))
    return run_query(args.dataset, filters, args.format, args.out)


def _add_build_arguments(p: argparse.ArgumentParser) -> None:
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


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="mars-pairs",
        description="Paired aerial/ground ML datasets from Mars rover images and orbital maps.",
    )
    parser.add_argument(
        "--version", action=VersionAction, help="the package's and key libraries' versions"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    register_catalog(sub)

    p = sub.add_parser("locate", help="read labels and place each image on the map")
    p.add_argument("labels", nargs="+", help="PDS3 .LBL or PDS4 .xml label(s)")
    p.add_argument("--places", help="PLACES table (best_interp.csv / localized_interp.csv)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=_cmd_locate)

    p = sub.add_parser("viewshed", help="one image's (or a raw observer's) viewshed GeoTIFF")
    p.add_argument("--dem", required=True, help="DEM raster (any GDAL path, projected CRS)")
    p.add_argument("--out", required=True, help="output GeoTIFF")
    p.add_argument("--label", help="PDS label of the image (with --places)")
    p.add_argument("--places", help="PLACES table")
    p.add_argument(
        "--radius",
        type=bounded(0.0, MAX_RADIUS_M, open_low=True),
        default=5000.0,
        help="metres (default 5000)",
    )
    p.add_argument(
        "--height",
        type=finite,
        help="observer height above the terrain, metres (label default: camera's)",
    )
    p.add_argument("--absolute", action="store_true", help="--height is an absolute elevation")
    p.add_argument(
        "--mask",
        choices=("frustum", "band"),
        default="frustum",
        help="with --label: frustum = what the image saw (default); band = the study's az/el band",
    )
    p.add_argument("--x", type=finite, help="observer x, DEM CRS map units")
    p.add_argument("--y", type=finite, help="observer y, DEM CRS map units")
    for name in ("az-min", "az-max"):
        p.add_argument(f"--{name}", type=finite, help="degrees clockwise from north")
    for name in ("el-min", "el-max"):
        p.add_argument(f"--{name}", type=bounded(-90, 90), help="degrees up from the horizon")
    p.set_defaults(func=cmd_viewshed)

    p = sub.add_parser("build", help="build a dataset from a config")
    _add_build_arguments(p)
    p.set_defaults(func=_cmd_build)

    p = sub.add_parser("inspect", help="counts, failures and size of a built dataset")
    p.add_argument("dataset", help="dataset folder, or its URL (s3://bucket/prefix)")
    p.set_defaults(func=_cmd_inspect)

    p = sub.add_parser("verify", help="check every member's tar header, size and checksum")
    p.add_argument("dataset", help="dataset folder, or its URL (s3://bucket/prefix)")
    p.set_defaults(func=_cmd_verify)

    p = sub.add_parser(
        "query",
        help="filter a dataset's manifest by place and attributes",
        description="Rows of a dataset's manifest matching every filter given: at most one "
        "place filter (--bbox, --bbox-map, --near, --polygon) and any of --split, --mission, "
        "--instrument, --sol. No filter: every row.",
    )
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--bbox",
        nargs=4,
        type=finite,
        metavar=("W", "S", "E", "N"),
        help="longitude/latitude box, degrees",
    )
    where.add_argument(
        "--bbox-map",
        nargs=4,
        type=finite,
        metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
        help="box in the dataset CRS, map units",
    )
    where.add_argument(
        "--near",
        nargs=3,
        type=finite,
        metavar=("LAT", "LON", "RADIUS_M"),
        help="within a great-circle radius (metres) of a point",
    )
    where.add_argument("--polygon", help="WKT polygon in the dataset CRS")
    where.add_argument(
        "--saw",
        nargs=2,
        type=finite,
        metavar=("LON", "LAT"),
        help="the images whose footprint holds the point (a catalogue: its visible footprint; "
        "a dataset: the manifest's), nearest first, with the range",
    )
    where.add_argument(
        "--overlaps",
        metavar="KEY",
        help="the images that saw the same ground as KEY (pairs.parquet), by IoU",
    )
    p.add_argument("--mission", action="append", help="m2020 or msl (repeat for several)")
    p.add_argument(
        "--instrument", action="append", help="e.g. MAST_LEFT, NAV_LEFT (repeat for several)"
    )
    p.add_argument(
        "--split", action="append", help="train, val, test, buffer... (repeat for several)"
    )
    p.add_argument("--sol", nargs=2, type=int, metavar=("FIRST", "LAST"), help="inclusive")
    p.add_argument("--format", choices=("table", "csv", "parquet", "geojson"), default="table")
    p.add_argument("--out", help="output file (parquet needs one; others default to stdout)")
    p.set_defaults(func=_cmd_query)

    p = sub.add_parser("show", help="a figure of one sample (needs the viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    p.add_argument("key", help="sample key or product id (see mars-pairs query)")
    p.add_argument("--out", help="PNG path (default KEY.png in the current directory)")
    p.set_defaults(func=_cmd_show)

    p = sub.add_parser("overview", help="all footprints over the orthoimage (needs the viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    p.add_argument("--out", default="overview.png", help="PNG path")
    p.add_argument("--colour-by", choices=("sol", "split"), default="sol")
    p.set_defaults(func=_cmd_overview)

    p = sub.add_parser("report", help="one self-contained HTML page of a dataset (viz extra)")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    p.add_argument("--out", help="HTML path (default DATASET/report.html)")
    p.add_argument("--samples", type=count(0), default=12, help="gallery samples (default 12)")
    p.set_defaults(func=_cmd_report)

    p = sub.add_parser("export-qgis", help="a GeoPackage of positions, footprints and wedges")
    p.add_argument("dataset", type=local_dataset, help="dataset folder")
    p.add_argument("out", help="output .gpkg")
    p.add_argument("--viewsheds", action="store_true", help="also write viewshed GeoTIFFs")
    p.add_argument(
        "--chips",
        action="store_true",
        help="also write every sample's ortho, DEM and viewshed chips as GeoTIFFs (NAME_chips/)",
    )
    p.set_defaults(func=_cmd_export_qgis)

    from mars_pairs.fetch.cli import add_fetch_parser

    add_fetch_parser(sub)

    p = sub.add_parser("synth", help="generate the synthetic mission (terrain, labels, images)")
    p.add_argument("out", help="output folder")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--mission", choices=("m2020", "msl", "both"), default="m2020")
    p.add_argument("--stops", type=count(1), help="rover stops (default: the size's: 3, 8, 90)")
    p.add_argument("--images-per-stop", type=count(1), help="default: the size's (4, 4, 3)")
    p.add_argument("--size", choices=("small", "default", "demo"), default="small")
    p.set_defaults(func=_cmd_synth)
    return parser


def local_dataset(value: str) -> str:
    """An argument naming a dataset folder on this machine: a URL is refused, naming the
    commands that read object storage."""
    from mars_pairs.store.fs import is_url

    if is_url(value):
        raise argparse.ArgumentTypeError(
            f"{value}: this command reads a dataset folder on this machine; `inspect`, "
            "`verify` and the Python datasets (MarsPairsDataset, Manifest) read object "
            "storage: copy the dataset here first (e.g. `aws s3 sync`)"
        )
    return value


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
