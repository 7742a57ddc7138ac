"""``mars-pairs viewshed``: one image's view (frustum or the study's band), or a raw observer's
viewshed, as a QGIS-ready GeoTIFF."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

from mars_pairs.cli.arguments import band
from mars_pairs.errors import UsageError

if TYPE_CHECKING:
    from mars_pairs.raster.terrain import Terrain


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


def cmd_viewshed(args: argparse.Namespace) -> int:
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
