"""``mars-pairs export-qgis DATASET --out FILE.gpkg``: a GeoPackage of positions, footprints
and camera wedges, optionally the viewshed and chip GeoTIFFs
(:func:`~mars_pairs.export.export_geopackage`)."""

from __future__ import annotations

import argparse
from typing import Any

from mars_pairs.cli.arguments import add_out, local_dataset, out_path


def register(sub: Any) -> None:
    """Add the ``export-qgis`` subparser to the top-level subparsers ``sub``."""
    p = sub.add_parser("export-qgis", help="a GeoPackage of positions, footprints and wedges")
    p.add_argument("dataset", type=local_dataset, help="dataset or footprint catalogue folder")
    add_out(p, "output .gpkg (default DATASET-qgis.gpkg beside the folder)", positional=True)
    p.add_argument("--viewsheds", action="store_true", help="also write viewshed GeoTIFFs")
    p.add_argument(
        "--chips",
        action="store_true",
        help="also write every sample's ortho, DEM and viewshed chips as GeoTIFFs (NAME_chips/)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the GeoPackage (and the GeoTIFFs asked for); print its path."""
    from mars_pairs.export import export_geopackage

    out = out_path(args)
    print(
        export_geopackage(args.dataset, out, with_viewsheds=args.viewsheds, with_chips=args.chips)
    )
    return 0
