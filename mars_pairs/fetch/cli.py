"""``mars-pairs fetch products|places|orbital|all --config CONFIG``: the command line.

Bad input (a config error, an unreadable index) exits 2 with one line naming the file or URL
(``cli/main.py``); products that fail to download are listed one line each and in
``<cache>/fetch_failures.parquet``, and the command exits 1.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any


def add_fetch_parser(sub: Any) -> None:
    """Register ``fetch`` and its subcommands on the top-level subparsers."""
    p = sub.add_parser("fetch", help="download products, PLACES and orbital windows (PDS, USGS)")
    fsub = p.add_subparsers(dest="fetch_command", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument("--config", required=True, help="build config with a fetch: section")
        q.add_argument("--cache", help="cache root (overrides fetch.cache)")
        q.add_argument("--workers", type=int, help="parallel downloads (overrides fetch.workers)")
        q.add_argument("--quiet", action="store_true", help="no progress bar")

    def filters(q: argparse.ArgumentParser) -> None:
        q.add_argument("--sol", nargs=2, type=int, metavar=("FIRST", "LAST"))
        q.add_argument("--instrument", action="append", help="e.g. MAST_LEFT, MCZ_RIGHT")
        q.add_argument("--product-type", action="append", help="e.g. DRCL, DRCX, RAD")
        q.add_argument("--site", action="append", type=int)
        q.add_argument("--drive", action="append", type=int)

    q = fsub.add_parser("products", help="labels and images chosen from the archive's index")
    common(q)
    filters(q)
    q.add_argument("--dry-run", action="store_true", help="print product count and bytes only")
    q.set_defaults(func=_cmd_products)

    q = fsub.add_parser("places", help="the PLACES localization table")
    common(q)
    q.add_argument("--dry-run", action="store_true", help="print the URL and cache path only")
    q.set_defaults(func=_cmd_places)

    margin_help = "ground metres past the build's reach (overrides fetch.orbital.margin_m)"
    windows_help = "print the planned windows and whether fetch.orbital.max_cells accepts them"
    q = fsub.add_parser("orbital", help="DEM/ortho windows around the rover positions, as COGs")
    common(q)
    filters(q)
    q.add_argument("--margin", type=float, help=margin_help)
    q.add_argument("--dry-run", action="store_true", help=windows_help)
    q.set_defaults(func=_cmd_orbital)

    q = fsub.add_parser("all", help="places, products, then orbital windows")
    common(q)
    filters(q)
    q.add_argument("--margin", type=float, help=margin_help)
    q.add_argument("--dry-run", action="store_true", help="product counts and planned windows")
    q.set_defaults(func=_cmd_all)


def _config(args: argparse.Namespace) -> Any:
    from pathlib import Path

    from mars_pairs.fetch.config import load_fetch_config

    cfg = load_fetch_config(args.config)
    if args.cache:
        cfg = replace(cfg, cache=Path(args.cache).resolve())
    if args.workers:
        cfg = replace(cfg, policy=replace(cfg.policy, workers=args.workers))
    return cfg


def _filters(args: argparse.Namespace, cfg: Any) -> Any:
    base = cfg.products.filters if cfg.products is not None else None
    if base is None:
        from mars_pairs.fetch.products import ProductFilter

        base = ProductFilter()
    changes: dict[str, Any] = {}
    if args.sol:
        changes["sols"] = (args.sol[0], args.sol[1])
    if args.instrument:
        changes["instruments"] = tuple(s.upper() for s in args.instrument)
    if args.product_type:
        changes["product_types"] = tuple(s.upper() for s in args.product_type)
    if args.site:
        changes["sites"] = tuple(args.site)
    if args.drive:
        changes["drives"] = tuple(args.drive)
    return replace(base, **changes)


def _cmd_products(args: argparse.Namespace) -> int:
    from mars_pairs.fetch.run import fetch_products

    cfg = _config(args)
    report = fetch_products(
        cfg, filters=_filters(args, cfg), dry_run=args.dry_run, progress=not args.quiet
    )
    print(report.format(args.dry_run))
    return 1 if report.failures else 0


def _cmd_places(args: argparse.Namespace) -> int:
    from mars_pairs.fetch.cache import Cache, archive_path, join_url
    from mars_pairs.fetch.run import fetch_places

    cfg = _config(args)
    if getattr(args, "dry_run", False) and cfg.places is not None:
        rel = archive_path(cfg.places.path, where="fetch.places.path")
        target = Cache(cfg.cache).path(rel)
        state = "cached" if target.is_file() else "not yet in the cache"
        print(f"dry run: {join_url(cfg.places.archive, rel)} -> {target} ({state})")
        return 0
    print(fetch_places(cfg))
    return 0


def _cmd_orbital(args: argparse.Namespace) -> int:
    """Plan the windows; print them; on a dry run stop (exit 1 if a limit refuses one)."""
    from mars_pairs.fetch.run import cut_orbital, plan_orbital

    cfg = _config(args)
    dry = getattr(args, "dry_run", False)
    margin = getattr(args, "margin", None)
    plan = plan_orbital(cfg, filters=_filters(args, cfg), margin_m=margin, dry_run=dry)
    for line in plan.format():
        print(("dry run: " if dry else "") + line)
    if dry:
        return 0 if all(p.accepted for p in plan.plans) else 1
    for res in cut_orbital(cfg, plan):
        state = "cached" if res.cached else "cut"
        print(f"{res.path}: {res.shape[1]} x {res.shape[0]} cells from {res.source} ({state})")
    for p in plan.plans:
        print(f"{cfg.cache / 'orbital' / (p.kind + '.vrt')}: mosaic of the {p.kind} windows")
    return 0


def _cmd_all(args: argparse.Namespace) -> int:
    """Every step whose section the config has (orbital windows need the PLACES table)."""
    cfg = _config(args)
    steps = [
        (cfg.places is not None, _cmd_places),
        (cfg.products is not None, _cmd_products),
        (cfg.orbital is not None and cfg.places is not None, _cmd_orbital),
    ]
    return max([step(args) for wanted, step in steps if wanted], default=0)
