"""``mars-pairs viewshed``: one image's view (frustum or the study's band), or a raw observer's
viewshed, as a QGIS-ready GeoTIFF."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

import numpy as np

from mars_pairs.cli.arguments import band, bounded, finite
from mars_pairs.errors import UsageError
from mars_pairs.geometry.body import MAX_RADIUS_M

if TYPE_CHECKING:
    from mars_pairs.raster.terrain import Terrain


def register(sub: Any) -> None:
    """Add the ``viewshed`` subparser to the top-level subparsers ``sub``."""
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
    p.set_defaults(func=run)


def label_viewshed(args: argparse.Namespace, terrain: Terrain) -> int:
    """``viewshed --label``: the image's view (frustum or the study's band) as a GeoTIFF."""

    from mars_pairs.geometry.places import Places
    from mars_pairs.pds import read_observation
    from mars_pairs.pipeline.sample.view import label_view
    from mars_pairs.raster.viewshed_tiff import NODATA, write_viewshed_geotiff

    obs = read_observation(args.label)
    pose = Places.from_csv(args.places).locate(obs)
    view = label_view(obs, pose, terrain, args.radius, args.height, args.mask)
    rows, cols = np.indices(view.mask.shape)
    x, y = view.window.colrow_to_xy(cols, rows)
    points = np.stack([x, y, view.window.data.astype(np.float64)], axis=-1).reshape(-1, 3)
    centre = view.camera.map_to_local(view.camera.center_map)
    local = view.camera.map_to_local(points) - centre
    far = (np.hypot(local[:, 0], local[:, 1]) > args.radius).reshape(view.mask.shape)
    codes = np.where(far | ~np.isfinite(view.window.data), NODATA, view.mask).astype(np.uint8)
    write_viewshed_geotiff(args.out, codes, view.window.transform, view.window.crs)
    cx, cy, cz = view.camera.center_map
    print(
        f"{args.out}: {int((codes == 1).sum())} cells in view ({args.mask} mask) of "
        f"{codes.size}; camera centre x={cx:.3f} y={cy:.3f} z={cz:.3f} m "
        f"({view.height:.3f} m above the DEM at the rover; DEM - PLACES {view.dem_offset_m:+.3f} m)"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    """Compute the viewshed asked for and write it as a GeoTIFF (``--out``)."""
    from mars_pairs.raster.terrain import Terrain
    from mars_pairs.raster.viewshed_tiff import (
        ViewshedRequest,
        compute_request,
        write_viewshed_geotiff,
    )

    with Terrain.open(args.dem) as terrain:
        if args.label:
            if not args.places:
                raise UsageError("--label needs --places")
            return label_viewshed(args, terrain)
        else:
            if args.x is None or args.y is None or args.height is None:
                raise UsageError("without --label, give --x, --y and --height")
            az = band(args.az_min, args.az_max, "--az-min/--az-max")
            el = band(args.el_min, args.el_max, "--el-min/--el-max")
            terrain.require_inside(args.x, args.y, "observer")
            req = ViewshedRequest(
                args.x, args.y, args.height, args.radius, az, el, height_is_absolute=args.absolute
            )
        codes, window = compute_request(terrain, req)
    write_viewshed_geotiff(args.out, codes, window.transform, window.crs)
    visible = int((codes == 1).sum())
    print(
        f"{args.out}: {visible} visible cells of {codes.size}; observer x={req.x:.3f} "
        f"y={req.y:.3f} height={req.height:.3f} m; az band {req.az_band}; "
        f"el band {req.el_band}"
    )
    return 0
