"""Which raster CRSs mars-pairs accepts: projected, on the Mars sphere."""

from __future__ import annotations

from pyproj import CRS

from mars_pairs.errors import TerrainError
from mars_pairs.geometry.body import MARS_RADIUS_M


def check_map_crs(crs: CRS, path: str, what: str) -> None:
    """Refuse CRSs whose coordinates cannot be placed exactly on the Mars sphere.

    mars-pairs computes on the Mars sphere (R = 3 396 190 m, the PLACES CRS). A geographic
    (lon/lat) raster has no metric grid for the kernels, and a CRS on another ellipsoid (e.g.
    the IAU Mars ellipsoid with planetographic latitudes) would go through PROJ's "ballpark"
    datum transform (12 km off at Jezero): both are refused with the fix in the message.
    Any projected CRS on the sphere works: true north and true metres come from its local
    Jacobian.
    """
    if crs.is_geographic:
        raise TerrainError(
            f"{path}: {what} CRS is geographic (longitude/latitude degrees); warp it to a "
            "projected Mars CRS first, e.g. "
            "gdalwarp -t_srs '+proj=eqc +lat_ts=0 +R=3396190 +units=m'"
        )
    if not crs.is_projected:
        raise TerrainError(f"{path}: {what} CRS is not a projected map CRS: {crs.name}")
    ell = crs.ellipsoid
    a = ell.semi_major_metre if ell is not None else float("nan")
    b = ell.semi_minor_metre if ell is not None else float("nan")
    if not (abs(a - MARS_RADIUS_M) < 1.0 and abs(b - MARS_RADIUS_M) < 1.0):
        name = ell.name if ell is not None else "unknown"
        raise TerrainError(
            f"{path}: {what} CRS is on the {name} ellipsoid (a={a:.0f} m, b={b:.0f} m), not the "
            f"Mars sphere R={MARS_RADIUS_M:.0f} m; no exact transform to the PLACES sphere "
            "exists here: reproject the raster onto a sphere CRS (+R=3396190)"
        )
