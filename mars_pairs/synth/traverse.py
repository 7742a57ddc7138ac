"""A synthetic rover traverse over the synthetic DEM, and its PLACES table.

Frames and units:
- map: the mission's equirectangular CRS (x easting, y northing, metres; z elevation above
  the areoid, metres, up). Easting/northing <-> lon/lat use the exact eqc relations
  (x = R lon cos(lat_ts), y = R lat) through ``mars_pairs.geometry.frames``.
- SITE_FRAME: NED tangent frame at the site origin (``TangentFrame``); ``landing_x/y/z`` of a
  ROVER row are the rover's NED offset from its site origin, metres.
- Attitude: rotation ROVER_NAV_FRAME (x forward, y right, z down) -> local NED at the rover,
  the convention ``MapCamera`` uses; the tangent planes of rover and site origin differ by
  under 0.01 degree over a kilometre. Roll/pitch/yaw: ZYX Euler angles of that rotation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from affine import Affine
from numpy.typing import NDArray

from mars_pairs.geometry.body import MARS_EQUATORIAL_RADIUS_M, MARS_POLAR_RADIUS_M
from mars_pairs.geometry.frames import (
    MARS_RADIUS_M,
    TangentFrame,
    local_map_jacobian,
    map_to_lonlat,
    matrix_to_quaternion,
    site_to_local_ned,
)

F64 = NDArray[np.float64]

PLACES_COLUMNS = (
    "frame", "site", "drive", "pose", "landing_x", "landing_y", "landing_z", "northing",
    "easting", "planetocentric_latitude", "planetodetic_latitude", "longitude", "elevation",
    "map_pixel_line", "map_pixel_sample", "dem_pixel_line", "dem_pixel_sample", "roll",
    "pitch", "yaw", "quat_s", "quat_v1", "quat_v2", "quat_v3", "areoid", "radius", "sclk",
    "sol",
)  # fmt: skip
SOL_SECONDS = 88775.244


@dataclass
class RoverState:
    """One ROVER row: where the rover stood (map, lon/lat, site offset) and its attitude."""

    site: int
    drive: int
    sol: int
    sclk: int
    x: float  # easting, map metres
    y: float  # northing, map metres
    z: float  # elevation above the areoid, metres
    lon: float  # planetocentric degrees
    lat: float
    heading_deg: float  # travel direction, clockwise from north
    rotation: F64  # ROVER_NAV_FRAME -> SITE_FRAME (NED level at the site origin), 3 x 3
    quaternion: F64  # (s, v1, v2, v3) of ``rotation``
    landing: F64 = field(default_factory=lambda: np.zeros(3))  # NED from the site origin
    stop: int = -1  # index of the imaging stop, -1 for a row passed while driving


@dataclass
class SiteOrigin:
    """One SITE row: a site origin on the ground (map, lon/lat, elevation)."""

    site: int
    sol: int
    sclk: int
    x: float
    y: float
    z: float
    lon: float
    lat: float


class DemSampler:
    """Bilinear DEM elevation at map x, y (cell centres are the grid nodes)."""

    def __init__(self, dem: F64, transform: Affine) -> None:
        self.dem = dem
        self.transform = transform

    def colrow(self, x: F64, y: F64) -> tuple[F64, F64]:
        """Map x, y -> fractional (col, row), cell centres at integers."""
        col, row = ~self.transform * (np.asarray(x, float), np.asarray(y, float))
        return np.asarray(col) - 0.5, np.asarray(row) - 0.5

    def __call__(self, x: F64, y: F64) -> F64:
        col, row = self.colrow(x, y)
        n0, n1 = self.dem.shape
        j = np.clip(np.floor(col).astype(int), 0, n1 - 2)
        i = np.clip(np.floor(row).astype(int), 0, n0 - 2)
        tx, ty = col - j, row - i
        d = self.dem
        top = d[i, j] * (1 - tx) + d[i, j + 1] * tx
        bot = d[i + 1, j] * (1 - tx) + d[i + 1, j + 1] * tx
        return np.asarray(top * (1 - ty) + bot * ty)


def smooth_path(
    rng: np.random.Generator, bounds: tuple[float, float, float, float], length_m: float
) -> F64:
    """A smooth random path (N, 2) of map x, y at 1 m steps inside ``bounds`` (l, b, r, t).

    The heading follows a smoothed random walk and turns back toward the centre near the
    bounds, so the path never leaves them.
    """
    left, bottom, right, top = bounds
    cx, cy = 0.5 * (left + right), 0.5 * (bottom + top)
    half = 0.5 * min(right - left, top - bottom)
    p = np.array([cx, cy]) + rng.uniform(-0.5, 0.5, 2) * half
    heading = rng.uniform(0, 2 * np.pi)  # clockwise from north (map y)
    turn = 0.0
    steps = int(length_m) + 1
    out = np.empty((steps, 2))
    for k in range(steps):
        out[k] = p
        turn = 0.97 * turn + rng.normal(0.0, 0.004)
        to_c = np.array([cx, cy]) - p
        frac = max(abs(to_c[0]), abs(to_c[1])) / half
        if frac > 0.7:
            want = math.atan2(to_c[0], to_c[1])
            err = (want - heading + np.pi) % (2 * np.pi) - np.pi
            turn += 0.02 * (frac - 0.7) / 0.3 * np.sign(err)
        heading += turn
        p = p + np.array([math.sin(heading), math.cos(heading)])
        p = np.clip(p, [left, bottom], [right, top])
    return out


def directed_path(
    rng: np.random.Generator, bounds: tuple[float, float, float, float], length_m: float
) -> F64:
    """A smooth path (N, 2) of map x, y at 1 m steps inside ``bounds`` (l, b, r, t) that
    heads across them, as a rover drives toward a distant goal: from near the south-west
    corner toward the north-east one, the heading a smoothed random walk pulled toward the
    goal (the path is about 1.1-1.3 times the straight distance it makes good).
    """
    left, bottom, right, top = bounds
    span = np.array([right - left, top - bottom])
    start = np.array([left, bottom]) + rng.uniform(0.02, 0.08, 2) * span
    corner = np.array([right, top]) - rng.uniform(0.02, 0.08, 2) * span
    way = corner - start
    reach = min(float(np.hypot(*way)), length_m / 1.15)
    goal = start + way / np.hypot(*way) * reach
    heading = math.atan2(way[0], way[1]) + rng.normal(0.0, 0.2)  # clockwise from north
    turn = 0.0
    steps = int(length_m) + 1
    out = np.empty((steps, 2))
    p = start.copy()
    for k in range(steps):
        out[k] = p
        to_g = goal - p
        want = math.atan2(to_g[0], to_g[1])
        err = (want - heading + np.pi) % (2 * np.pi) - np.pi
        turn = 0.97 * turn + rng.normal(0.0, 0.003)
        heading += turn + 0.01 * err
        p = p + np.array([math.sin(heading), math.cos(heading)])
        p = np.clip(p, [left, bottom], [right, top])
    return out


def rover_attitude(
    sampler: DemSampler, x: float, y: float, heading_deg: float, crs: str
) -> tuple[F64, float, float]:
    """Rotation ROVER_NAV_FRAME -> local NED for a rover at map (x, y) heading ``heading_deg``.

    The rover's z axis is the downward normal of a plane fitted to the DEM under its wheels
    (3 m x 3 m); x is the heading projected onto that plane. Returns (R, lon, lat).
    """
    lon, lat = (float(v) for v in map_to_lonlat(x, y, crs))
    jac = local_map_jacobian(lon, lat, crs)
    # local (north, east) offsets -> map offsets -> DEM samples
    g = np.linspace(-1.5, 1.5, 5)
    gn, ge = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    dxy = np.stack([gn, ge], axis=-1) @ jac[:2, :2].T
    zs = sampler(x + dxy[:, 0], y + dxy[:, 1])
    design = np.stack([np.ones_like(gn), gn, ge], axis=-1)
    coef, *_ = np.linalg.lstsq(design, zs, rcond=None)
    slope_n, slope_e = coef[1], coef[2]  # metres up per metre north / east
    z_axis = np.array([slope_n, slope_e, 1.0])
    z_axis /= np.linalg.norm(z_axis)
    hd = math.radians(heading_deg)
    h = np.array([math.cos(hd), math.sin(hd), 0.0])
    x_axis = h - (h @ z_axis) * z_axis
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    return np.stack([x_axis, y_axis, z_axis], axis=1), lon, lat


def euler_zyx_deg(rot: F64) -> tuple[float, float, float]:
    """(roll, pitch, yaw) degrees of a rotation R = Rz(yaw) Ry(pitch) Rx(roll)."""
    yaw = math.degrees(math.atan2(rot[1, 0], rot[0, 0]))
    pitch = math.degrees(-math.asin(max(-1.0, min(1.0, rot[2, 0]))))
    roll = math.degrees(math.atan2(rot[2, 1], rot[2, 2]))
    return roll, pitch, yaw % 360.0


@dataclass
class Traverse:
    """SITE origins, ROVER rows (stops and in-between drive steps) of a synthetic traverse."""

    sites: list[SiteOrigin]
    rovers: list[RoverState]

    @property
    def stops(self) -> list[RoverState]:
        """The imaging stops, in order."""
        return [r for r in self.rovers if r.stop >= 0]


def make_traverse(
    rng: np.random.Generator,
    sampler: DemSampler,
    crs: str,
    bounds: tuple[float, float, float, float],
    stops: int,
    first_site: int,
    first_sol: int,
    sclk0: int,
    spacing_m: tuple[float, float] = (15.0, 35.0),
    directed: bool = False,
) -> Traverse:
    """A traverse of ``stops`` imaging stops along a smooth path inside ``bounds``.

    Stops are ``spacing_m`` (low, high) metres apart along the path; the path wanders about
    the bounds (``smooth_path``) or, ``directed``, heads across them (``directed_path``).
    A new site starts every 2..4 stops at the rover's position (drive 0); the drive counter
    then grows along the path, with ROVER rows every ~8 m between stops.
    """
    spacing = rng.uniform(*spacing_m, max(stops - 1, 0))
    cum = np.concatenate([[0.0], np.cumsum(spacing)])
    path = (directed_path if directed else smooth_path)(rng, bounds, cum[-1] + 2.0)
    seg = np.diff(path, axis=0)
    heading_path = np.degrees(np.arctan2(seg[:, 0], seg[:, 1])) % 360.0

    def state_at(s: float) -> tuple[float, float, float]:
        k = min(int(s), len(seg) - 1)
        t = s - k
        xy = path[k] * (1 - t) + path[k + 1] * t
        return float(xy[0]), float(xy[1]), float(heading_path[k])

    sites: list[SiteOrigin] = []
    rovers: list[RoverState] = []
    site, drive, sol = first_site - 1, 0, first_sol
    next_site_at = 0
    sclk = sclk0 + int(sol * SOL_SECONDS) + 40000
    for k in range(stops):
        if k > 0:
            sol += int(rng.integers(0, 3))
            sclk = max(sclk + 600, sclk0 + int(sol * SOL_SECONDS) + int(rng.integers(36000, 60000)))
        new_site = k == next_site_at
        if new_site:
            site += 1
            drive = 0
            next_site_at = k + int(rng.integers(2, 5))
        elif k > 0:
            # intermediate rows while driving from the previous stop
            n_mid = max(1, int(spacing[k - 1] // 8.0))
            step = int(rng.integers(6, 40)) * 2
            for m in range(1, n_mid):
                s = cum[k - 1] + spacing[k - 1] * m / n_mid
                drive += step
                x, y, hd = state_at(s)
                rovers.append(_rover(sampler, crs, site, drive, sol, sclk - 300 + m, x, y, hd, -1))
            drive += step
        x, y, hd = state_at(cum[k])
        hd = (hd + float(rng.normal(0.0, 8.0))) % 360.0  # rovers often turn at a stop
        r = _rover(sampler, crs, site, drive, sol, sclk, x, y, hd, k)
        if new_site:
            sites.append(SiteOrigin(site, sol, sclk, r.x, r.y, r.z, r.lon, r.lat))
        rovers.append(r)
    origins = {s.site: TangentFrame(s.lon, s.lat, s.z) for s in sites}
    for r in rovers:
        o = origins[r.site]
        r.landing = o.lonlat_to_ned(r.lon, r.lat, r.z)
        # the attitude was built level at the rover; labels give it relative to SITE_FRAME
        r.rotation = site_to_local_ned(o.lon_deg, o.lat_deg, r.lon, r.lat).T @ r.rotation
        r.quaternion = matrix_to_quaternion(r.rotation)
    return Traverse(sites, rovers)


def _rover(
    sampler: DemSampler,
    crs: str,
    site: int,
    drive: int,
    sol: int,
    sclk: int,
    x: float,
    y: float,
    heading: float,
    stop: int,
) -> RoverState:
    z = float(sampler(np.array(x), np.array(y)))
    rot, lon, lat = rover_attitude(sampler, x, y, heading, crs)
    q = matrix_to_quaternion(rot)
    return RoverState(site, drive, sol, sclk, x, y, z, lon, lat, heading, rot, q, stop=stop)


def _planetodetic(lat_deg: float) -> float:
    return math.degrees(
        math.atan(
            math.tan(math.radians(lat_deg)) * (MARS_EQUATORIAL_RADIUS_M / MARS_POLAR_RADIUS_M) ** 2
        )
    )


def write_places_csv(
    path: Path, traverse: Traverse, dem_transform: Affine, ortho_transform: Affine
) -> None:
    """Write the PLACES table (SITE rows, each followed by its ROVER rows) with real columns."""
    inv_dem, inv_map = ~dem_transform, ~ortho_transform
    lines = [",".join(PLACES_COLUMNS)]

    def common(x: float, y: float, z: float, lon: float, lat: float) -> list[str]:
        ms, ml = inv_map * (x, y)
        ds, dl = inv_dem * (x, y)
        return [
            f"{y:.4f}", f"{x:.4f}", f"{lat:.10f}", f"{_planetodetic(lat):.10f}", f"{lon:.10f}",
            f"{z:.4f}", f"{ml:.2f}", f"{ms:.2f}", f"{dl:.2f}", f"{ds:.2f}",
        ]  # fmt: skip

    for s in traverse.sites:
        lines.append(",".join([
            "SITE", str(s.site), "-1", "-1", "0.0000", "0.0000", "0.0000",
            *common(s.x, s.y, s.z, s.lon, s.lat),
            "0.000", "0.000", "0.000", "1.000000000", "0.000000000", "0.000000000",
            "0.000000000", f"{MARS_RADIUS_M:.3f}", f"{MARS_RADIUS_M + s.z:.3f}", str(s.sclk),
            str(s.sol),
        ]))  # fmt: skip
        for r in traverse.rovers:
            if r.site != s.site:
                continue
            roll, pitch, yaw = euler_zyx_deg(r.rotation)
            lines.append(",".join([
                "ROVER", str(r.site), str(r.drive), "-1",
                *(f"{v:.4f}" for v in r.landing),
                *common(r.x, r.y, r.z, r.lon, r.lat),
                f"{roll:.3f}", f"{pitch:.3f}", f"{yaw:.3f}",
                *(f"{v:.9f}" for v in r.quaternion),
                f"{MARS_RADIUS_M:.3f}", f"{MARS_RADIUS_M + r.z:.3f}", str(r.sclk), str(r.sol),
            ]))  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
