"""PLACES localization tables (best_interp.csv, localized_interp.csv) and the rover Pose."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.attitude import rpy_to_quaternion
from mars_pairs.geometry.frames import (
    M2020_PLACES_CRS,
    MARS_RADIUS_M,
    MSL_PLACES_CRS,
    TangentFrame,
    lonlat_to_map,
)
from mars_pairs.geometry.labelled import LabelledImage

MISSING = -9999.0

#: Columns every PLACES table has, read by name whatever the header's case. Two generations:
#: the current tables (Curiosity ``msl_places/data_localizations/localized_interp.csv``, 26
#: lower-case columns; Perseverance ``best_interp.csv``, 28, adding areoid and radius) carry
#: the quaternion columns; the PDS3-era Curiosity table (``MSLPLC_1XXX/DATA/LOCALIZATIONS/
#: localized_interp.csv``) has 22 upper-case columns, the 26 without the four quaternion
#: columns: FRAME, SITE, DRIVE, POSE, LANDING_X/Y/Z, NORTHING, EASTING, PLANETOCENTRIC_LATITUDE,
#: PLANETODETIC_LATITUDE, LONGITUDE, ELEVATION, MAP_PIXEL_LINE/SAMPLE, DEM_PIXEL_LINE/SAMPLE,
#: ROLL, PITCH, YAW, SCLK, SOL (26 - 4 = 22; pose kept, the archive README naming it
#: "FRAME ... YAW, SCLK, SOL"). ``pose`` is optional (tables of this shape without it, e.g.
#: ../shared/real-gale/rover_positions.csv, are looked up by site and drive).
REQUIRED_COLUMNS = (
    "frame",
    "site",
    "drive",
    "northing",
    "easting",
    "planetocentric_latitude",
    "longitude",
    "elevation",
)
#: The attitude: the quaternion columns (s, v1, v2, v3) or, without them, roll/pitch/yaw degrees.
QUATERNION_COLUMNS = ("quat_s", "quat_v1", "quat_v2", "quat_v3")
RPY_COLUMNS = ("roll", "pitch", "yaw")

#: ``Pose.match``: which PLACES row (or fallback) gave the position.
MATCH_POSE = "site-drive-pose"  # the row of the label's site, drive and pose
MATCH_SITE_DRIVE = "site-drive"  # the (site, drive) row for any pose, or the label has none
MATCH_EARLIER = "earlier-pose"  # the label's pose is absent: the highest pose below it
MATCH_LATER = "later-pose"  # no pose at or below the label's: the lowest above it
MATCH_LABEL = "label-offset"  # no ROVER row: the label's offset from the PLACES SITE origin


@dataclass(frozen=True)
class Pose:
    """Where the rover stood and how it was oriented when an image was taken.

    ``easting``/``northing``: rover frame origin in the table's CRS (``crs``), map units.
    ``latitude``/``longitude``: planetocentric degrees (Mars sphere). ``elevation_m``: metres
    above the areoid. ``quaternion``: (s, v1, v2, v3), ROVER_NAV_FRAME -> SITE_FRAME
    (site <- rover). ``source``: "places" (a localized ROVER row) or "label" (the label's
    telemetry offset from the PLACES SITE origin); ``attitude_source`` likewise.
    ``pose``: the PLACES row's pose number (-1: the table's row for every pose of the
    (site, drive)); None without a pose column or a row. ``match``: how the row was chosen,
    one of the ``MATCH_*`` values of this module.
    """

    site: int
    drive: int
    easting: float
    northing: float
    crs: str
    latitude: float
    longitude: float
    elevation_m: float
    quaternion: np.ndarray | None
    source: str
    attitude_source: str | None
    #: the SITE_FRAME origin (planetocentric lon, lat degrees) the quaternion refers to, when
    #: the table has the SITE row; None: the quaternion is taken as relative to NED at the rover
    site_lonlat: tuple[float, float] | None = None
    pose: int | None = None
    match: str = MATCH_SITE_DRIVE


def _valid(*values: float) -> bool:
    return all(v is not None and math.isfinite(v) and v != MISSING for v in values)


def infer_places_crs(easting: float, longitude_deg: float) -> str:
    """The table's equirectangular CRS, recovered from one row: cos(lat_ts) = x / (R lon).

    acos is ill-conditioned at lat_ts = 0: a longitude rounded to 7 decimals (1e-9 relative)
    reads as lat_ts ~0.002 deg, so lat_ts below 0.01 deg (an easting change under 2e-8 of
    itself) is taken as 0, Curiosity's CRS.
    """
    if abs(longitude_deg) < 1e-6:
        raise PlacesError("cannot infer the PLACES CRS from a row at longitude 0")
    ratio = easting / (MARS_RADIUS_M * math.radians(longitude_deg))
    lat_ts = math.degrees(math.acos(max(-1.0, min(1.0, ratio))))
    if abs(lat_ts - 18.4663) < 1e-3:
        return M2020_PLACES_CRS
    if abs(lat_ts) < 0.01:
        return MSL_PLACES_CRS
    return M2020_PLACES_CRS.replace("+lat_ts=18.4663", f"+lat_ts={lat_ts:.4f}")


class Places:
    """A PLACES localization table: SITE origins and localized ROVER positions.

    Columns are read by name, case-insensitively (``REQUIRED_COLUMNS``, then the attitude: the
    quaternion columns, else roll/pitch/yaw). ROVER rows are keyed by (site, drive, pose); a
    table without a pose column keys them by (site, drive).

    >>> places = Places.from_csv("best_interp.csv")
    >>> pose = places.locate(observation)
    """

    def __init__(self, table: pa.Table, path: Path | None = None, crs: str | None = None) -> None:
        self.path = path
        names = [str(n).strip().lower() for n in table.column_names]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise PlacesError(f"{path}: column(s) {', '.join(twice)} appear twice (any case)")
        missing = [c for c in REQUIRED_COLUMNS if c not in names]
        if missing:
            raise PlacesError(f"{path}: missing column(s) {', '.join(missing)}")
        self._cols = {n: table.column(i).to_pylist() for i, n in enumerate(names)}
        self.attitude_columns = self._attitude_columns()
        self.has_pose = "pose" in self._cols
        frames = [str(f).strip().upper() for f in self._cols["frame"]]
        #: (site, drive) -> {pose (-1 without a pose column): row}
        self._rover: dict[tuple[int, int], dict[int, int]] = {}
        self._site: dict[int, int] = {}
        self._conflicts: dict[tuple[int, int, int], str] = {}
        for i, kind in enumerate(frames):
            if kind not in ("ROVER", "SITE"):
                continue
            site, drive = self._index(i, "site"), self._index(i, "drive")
            if kind == "SITE":
                self._site[site] = i
                continue
            pose = self._index(i, "pose") if self.has_pose else -1
            rows = self._rover.setdefault((site, drive), {})
            if pose in rows:
                self._note_duplicate(site, drive, pose, rows[pose], i)
            else:
                rows[pose] = i
        self.crs = crs or self._infer_crs()

    def _attitude_columns(self) -> tuple[str, ...]:
        """The quaternion columns when the table has them all, else roll/pitch/yaw."""
        for group in (QUATERNION_COLUMNS, RPY_COLUMNS):
            if all(c in self._cols for c in group):
                return group
        lacking = [c for c in (*QUATERNION_COLUMNS, *RPY_COLUMNS) if c not in self._cols]
        raise PlacesError(
            f"{self.path}: missing column(s) {', '.join(lacking)}: no attitude "
            f"(quaternion {', '.join(QUATERNION_COLUMNS)} or {', '.join(RPY_COLUMNS)} degrees)"
        )

    def _where(self, row: int, column: str) -> str:
        # line numbers of the CSV file: the header is line 1
        return f"{self.path}: line {row + 2}: {column}"

    def _index(self, row: int, column: str) -> int:
        """A site, drive or pose number: an integer in [-1, 2**31); else PlacesError."""
        v = self._cols[column][row]
        try:
            number = float(v)
        except (TypeError, ValueError):
            number = math.nan
        if not (math.isfinite(number) and number == int(number) and -1 <= number < 2**31):
            raise PlacesError(f"{self._where(row, column)}: expected an integer, got {v!r}")
        return int(number)

    def _note_duplicate(self, site: int, drive: int, pose: int, first: int, again: int) -> None:
        """Two ROVER rows for one (site, drive, pose): kept if they agree within 1 cm, else the
        position is refused (``locate`` raises) rather than one of them chosen silently. Rows
        of one (site, drive) with different poses are distinct states, not duplicates."""
        key = (site, drive, pose)
        try:
            a = [self._value(c, first) for c in ("easting", "northing", "elevation")]
            b = [self._value(c, again) for c in ("easting", "northing", "elevation")]
        except PlacesError as exc:
            self._conflicts[key] = str(exc)
            return
        gap = math.dist(a, b) if _valid(*a, *b) else math.inf
        if not gap <= 0.01:
            which = f"site {site} drive {drive}" + (f" pose {pose}" if self.has_pose else "")
            self._conflicts[key] = (
                f"{self.path}: lines {first + 2} and {again + 2}: conflicting ROVER rows for "
                f"{which} ({gap:.3f} m apart)"
            )

    @classmethod
    def from_csv(cls, path: str | Path, crs: str | None = None) -> Places:
        """Read a PLACES CSV by header name; ``crs`` overrides the inferred table CRS."""
        path = Path(path)
        if not path.is_file():  # a FIFO or a device would block or never end
            raise PlacesError(f"{path}: cannot read PLACES table: not a regular file")
        try:
            table = pacsv.read_csv(path)
        except (OSError, pa.ArrowInvalid) as exc:
            raise PlacesError(f"{path}: cannot read PLACES table: {exc}") from None
        return cls(table, path=path, crs=crs)

    def __len__(self) -> int:
        return len(self._cols["frame"])

    def _infer_crs(self) -> str:
        for i in range(len(self)):
            try:
                e, lon = self._value("easting", i), self._value("longitude", i)
            except PlacesError:
                continue
            if _valid(e, lon) and abs(lon) > 1e-3:
                return infer_places_crs(e, lon)
        raise PlacesError(f"{self.path}: no row with a valid easting and longitude")

    def _value(self, column: str, row: int) -> float:
        """A numeric cell: NaN when empty; PlacesError naming line and column for text."""
        v = self._cols[column][row]
        if v is None:
            return math.nan
        try:
            return float(v)
        except (TypeError, ValueError):
            raise PlacesError(f"{self._where(row, column)}: expected a number, got {v!r}") from None

    def _quaternion(self, row: int) -> np.ndarray | None:
        """The row's attitude (s, v1, v2, v3), ROVER_NAV_FRAME -> SITE_FRAME; None if unknown.

        From the quaternion columns, or from roll, pitch, yaw (degrees) by
        ``attitude.rpy_to_quaternion`` in a table without them."""
        values = [self._value(c, row) for c in self.attitude_columns]
        if not _valid(*values):
            return None
        if self.attitude_columns == RPY_COLUMNS:
            return rpy_to_quaternion(*values)
        if abs(np.linalg.norm(values) - 1.0) > 1e-3:
            return None
        return np.asarray(values)

    def site_origin(self, site: int) -> tuple[float, float, float] | None:
        """(longitude deg, planetocentric latitude deg, elevation m) of a SITE origin."""
        row = self._site.get(site)
        if row is None:
            return None
        lon, lat, elev = (
            self._value("longitude", row),
            self._value("planetocentric_latitude", row),
            self._value("elevation", row),
        )
        return (lon, lat, elev) if _valid(lon, lat, elev) else None

    def poses(self, site: int, drive: int) -> list[int]:
        """The pose numbers of the ROVER rows for (site, drive), ascending ([-1]: one row for
        every pose, or a table without a pose column; []: no row)."""
        return sorted(self._rover.get((site, drive), {}))

    def _choose(self, site: int, drive: int, want: int | None) -> tuple[int, str] | None:
        """The pose row to use for an image taken at pose ``want`` (None: the label has none).

        The pose index counts updates of the rover's state within one drive (the rover does
        not drive between them): the row of the image's own pose is exact; else the latest
        localized state before the image (the highest pose below it), as no drive has moved
        the rover since; else a row for every pose (-1); else the next state after it (the
        lowest pose above). Without a label pose: the row for every pose, else the lowest.
        """
        poses = self.poses(site, drive)
        if not poses:
            return None
        specific = [p for p in poses if p >= 0]
        if want is None or not specific:
            return (-1 if -1 in poses else poses[0]), MATCH_SITE_DRIVE
        if want in specific:
            return want, MATCH_POSE
        below = [p for p in specific if p < want]
        if below:
            return below[-1], MATCH_EARLIER
        if -1 in poses:
            return -1, MATCH_SITE_DRIVE
        return specific[0], MATCH_LATER

    def rover_pose(self, site: int, drive: int, pose: int | None = None) -> Pose | None:
        """The localized ROVER row for (site, drive) at the image's ``pose`` as a Pose (the row
        chosen as in ``_choose``; ``Pose.pose`` and ``Pose.match`` say which), or None when
        absent; PlacesError when the table's rows for it conflict or hold text for numbers."""
        chosen = self._choose(site, drive, pose)
        if chosen is None:
            return None
        row_pose, match = chosen
        if (site, drive, row_pose) in self._conflicts:
            raise PlacesError(self._conflicts[(site, drive, row_pose)])
        row = self._rover[(site, drive)][row_pose]
        e, n = self._value("easting", row), self._value("northing", row)
        lat, lon = self._value("planetocentric_latitude", row), self._value("longitude", row)
        elev = self._value("elevation", row)
        if not _valid(e, n, lat, lon, elev):
            return None
        q = self._quaternion(row)
        return Pose(
            site=site,
            drive=drive,
            easting=e,
            northing=n,
            crs=self.crs,
            latitude=lat,
            longitude=lon,
            elevation_m=elev,
            quaternion=q,
            source="places",
            attitude_source="places" if q is not None else None,
            pose=row_pose if self.has_pose else None,
            match=match,
        )

    def locate(self, obs: LabelledImage) -> Pose:
        """The rover Pose for an observation, by the fallback in DESIGN.md.

        1. the ROVER row for the label's (site, drive), at its pose as in ``rover_pose`` ->
           source "places";
        2. else the label's telemetry offset (SITE_FRAME, NED metres) from the PLACES SITE
           origin -> source "label", match "label-offset";
        3. else PlacesError. Attitude: the row's quaternion when known, else the label's.
        """
        site, drive = obs.rmc.site, obs.rmc.drive
        pose = self.rover_pose(site, drive, obs.rmc.pose)
        origin = self.site_origin(site)
        site_lonlat = None if origin is None else (origin[0], origin[1])
        if pose is not None:
            pose = replace(pose, site_lonlat=site_lonlat)
            if pose.quaternion is None and obs.rover_quaternion is not None:
                q = np.asarray(obs.rover_quaternion, dtype=np.float64)
                pose = replace(pose, quaternion=q, attitude_source="label")
            return pose
        if origin is None or obs.rover_offset_m is None:
            why = "no SITE origin" if origin is None else "the label has no rover offset"
            raise PlacesError(
                f"{self.path}: no ROVER row for site {site} drive {drive} and {why} "
                f"(label {obs.label_path})"
            )
        lon0, lat0, elev0 = origin
        lon, lat, h = TangentFrame(lon0, lat0, elev0).ned_to_lonlat(obs.rover_offset_m)
        x, y = lonlat_to_map(lon, lat, self.crs)
        label_q = obs.rover_quaternion
        return Pose(
            site=site,
            drive=drive,
            easting=float(x),
            northing=float(y),
            crs=self.crs,
            latitude=float(lat),
            longitude=float(lon),
            elevation_m=float(h),
            quaternion=None if label_q is None else np.asarray(label_q, dtype=np.float64),
            source="label",
            attitude_source=None if label_q is None else "label",
            site_lonlat=site_lonlat,
            match=MATCH_LABEL,
        )
