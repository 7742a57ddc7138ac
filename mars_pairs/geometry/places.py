"""PLACES localization tables (best_interp.csv, localized_interp.csv) and the rover Pose."""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.attitude import rpy_to_quaternion
from mars_pairs.geometry.body import MARS_ELEVATION_M
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


#: The most bytes a compressed PLACES table may expand to (the largest real table, Curiosity's
#: ``localized_interp.csv``, is 77 MB): a decompression bomb stops here, naming the file.
MAX_PLACES_BYTES = 4 << 30
#: Rows read at a time: the table is streamed, only the columns used are kept, as float64.
_BLOCK_BYTES = 4 << 20
_FRAME_OTHER, _FRAME_ROVER, _FRAME_SITE = 0, 1, 2


class _Bounded(io.RawIOBase):
    """A decompressing reader that refuses to expand past ``limit`` bytes."""

    def __init__(self, raw: Any, path: Path, limit: int) -> None:
        self._raw, self._path, self._limit, self._read = raw, path, limit, 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        data = self._raw.read(len(buffer))
        self._read += len(data)
        if self._read > self._limit:
            raise PlacesError(
                f"{self._path}: cannot read PLACES table: it expands past {self._limit} bytes "
                "(a decompression bomb?)"
            )
        buffer[: len(data)] = data
        return len(data)


@contextmanager
def _source(path: Path, limit: int) -> Iterator[Any]:
    """What the CSV reader reads: the file's path, or its decompressed bytes (gzip, bz2, xz),
    bounded by ``limit``."""
    openers: dict[str, Callable[..., Any]] = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}
    opener = openers.get(path.suffix.lower())
    if opener is None:
        yield str(path)
        return
    with opener(path, "rb") as raw:
        yield io.BufferedReader(_Bounded(raw, path, limit), 1 << 20)


@dataclass
class _Table:
    """The PLACES columns a ``Places`` uses, as float64 arrays by lower-case name (NaN: empty or
    not a number), the row frames (``_FRAME_*``), and the text of cells that are not numbers
    (column, row) -> text, kept so that only a row in use is refused for them."""

    columns: dict[str, np.ndarray]
    frames: np.ndarray
    text: dict[tuple[str, int], str]

    def __len__(self) -> int:
        return len(self.frames)


def _numbers(
    column: pa.ChunkedArray | pa.Array, name: str, first: int, text: dict[tuple[str, int], str]
) -> np.ndarray:
    """A string column as float64 (empty: NaN); cells that are not numbers become NaN, their
    text recorded in ``text`` under (name, row) (rows counted from ``first``)."""
    trimmed = pc.utf8_trim_whitespace(column)
    try:
        values = pc.cast(trimmed, pa.float64())
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        out = np.empty(len(trimmed), dtype=np.float64)
        for i, cell in enumerate(trimmed.to_pylist()):
            try:
                out[i] = math.nan if cell in (None, "") else float(cell)
            except ValueError:
                out[i] = math.nan
                text[(name, first + i)] = cell
        return out
    out = values.to_numpy(zero_copy_only=False)
    return np.asarray(out, dtype=np.float64)


def _frames(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    kind = pc.utf8_upper(pc.utf8_trim_whitespace(column))
    rover = pc.fill_null(pc.equal(kind, "ROVER"), False).to_numpy(zero_copy_only=False)
    site = pc.fill_null(pc.equal(kind, "SITE"), False).to_numpy(zero_copy_only=False)
    out = np.zeros(len(kind), dtype=np.int8)
    out[rover] = _FRAME_ROVER
    out[site] = _FRAME_SITE
    return out


def read_places_table(path: Path, limit: int = MAX_PLACES_BYTES) -> _Table:
    """Stream the PLACES CSV at ``path`` (maybe gzip/bz2/xz compressed, expanding to at most
    ``limit`` bytes): only the columns ``Places`` uses are kept, as float64 arrays, so memory
    is ~8 bytes a used cell, whatever the table's width. Column names are matched
    case-insensitively; PlacesError naming the file for a column given twice, a missing
    column, text that is not UTF-8 or a file that is not CSV."""
    used = set(REQUIRED_COLUMNS) | {"pose", *QUATERNION_COLUMNS, *RPY_COLUMNS}
    try:
        with _source(path, limit) as src:
            header = pacsv.open_csv(src, read_options=pacsv.ReadOptions(block_size=1 << 16))
            header = header.schema.names
        names = [str(n).strip().lower() for n in header]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise PlacesError(f"{path}: column(s) {', '.join(twice)} appear twice (any case)")
        missing = [c for c in REQUIRED_COLUMNS if c not in names]
        if missing:
            raise PlacesError(f"{path}: missing column(s) {', '.join(missing)}")
        wanted = [h for h, n in zip(header, names, strict=True) if n in used]
        parts: dict[str, list[np.ndarray]] = {}
        frames: list[np.ndarray] = []
        text: dict[tuple[str, int], str] = {}
        with _source(path, limit) as src:
            reader = pacsv.open_csv(
                src,
                read_options=pacsv.ReadOptions(block_size=_BLOCK_BYTES),
                convert_options=pacsv.ConvertOptions(
                    include_columns=wanted,
                    column_types={h: pa.string() for h in wanted},  # checked UTF-8
                    strings_can_be_null=False,
                ),
            )
            keep = {str(h).strip().lower(): i for i, h in enumerate(reader.schema.names)}
            parts = {n: [] for n in keep if n != "frame"}
            rows = 0
            for batch in reader:
                for name, i in keep.items():
                    col = batch.column(i)
                    if name == "frame":
                        frames.append(_frames(col))
                    else:
                        parts[name].append(_numbers(col, name, rows, text))
                rows += batch.num_rows
    except PlacesError:
        raise
    except (OSError, EOFError, pa.ArrowInvalid, pa.ArrowNotImplementedError, ValueError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "UTF8" in why or "utf-8" in why.lower():
            why = f"not UTF-8 text ({why})"
        raise PlacesError(f"{path}: cannot read PLACES table: {why}") from None
    empty = np.empty(0, dtype=np.float64)
    columns = {n: (np.concatenate(v) if v else empty) for n, v in parts.items()}
    frame = np.concatenate(frames) if frames else np.empty(0, dtype=np.int8)
    return _Table(columns, frame, text)


def _key(site: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """One int64 per (site, drive), both in [-1, 2**31): (site + 1) * 2**32 + drive + 1."""
    return (site.astype(np.int64) + 1) * (1 << 32) + (drive.astype(np.int64) + 1)


class Places:
    """A PLACES localization table: SITE origins and localized ROVER positions.

    Columns are read by name, case-insensitively (``REQUIRED_COLUMNS``, then the attitude: the
    quaternion columns, else roll/pitch/yaw). ROVER rows are keyed by (site, drive, pose); a
    table without a pose column keys them by (site, drive). The table is held as float64
    arrays of the used columns and a sorted key index (no Python object per row), so a table
    of 3 million rows fits in a few hundred MB.

    >>> places = Places.from_csv("best_interp.csv")
    >>> pose = places.locate(observation)
    """

    def __init__(self, table: _Table, path: Path | None = None, crs: str | None = None) -> None:
        self.path = path
        self._cols = table.columns
        self._text = table.text
        self._n = len(table)
        self.attitude_columns = self._attitude_columns()
        self.has_pose = "pose" in self._cols
        frames = table.frames
        keyed = np.flatnonzero(frames != _FRAME_OTHER)
        rover_rows = keyed[frames[keyed] == _FRAME_ROVER]
        for column in ("site", "drive", "pose") if self.has_pose else ("site", "drive"):
            self._check_index(column, rover_rows if column == "pose" else keyed)
        site_rows = np.flatnonzero(frames == _FRAME_SITE)
        sites = self._cols["site"][site_rows].astype(np.int64)
        #: site -> its SITE row (the last one of the site, as the table is read in order)
        self._site: dict[int, int] = dict(zip(sites.tolist(), site_rows.tolist(), strict=True))
        rover = np.flatnonzero(frames == _FRAME_ROVER)
        key = _key(self._cols["site"][rover], self._cols["drive"][rover])
        pose = (
            self._cols["pose"][rover].astype(np.int64)
            if self.has_pose
            else np.full(len(rover), -1, dtype=np.int64)
        )
        order = np.lexsort((pose, key))  # stable: equal keys keep the table's order
        #: ROVER rows sorted by (site, drive), then pose: their keys, poses and table rows
        self._rkey, self._rpose, self._rrow = key[order], pose[order], rover[order]
        self._conflicts: dict[tuple[int, int, int], str] = {}
        same = np.flatnonzero(
            (self._rkey[1:] == self._rkey[:-1]) & (self._rpose[1:] == self._rpose[:-1])
        )
        for k in same:  # row k + 1 repeats the (site, drive, pose) of row k: check with the first
            first = int(k)
            while (
                first > 0
                and self._rkey[first - 1] == self._rkey[k]
                and (self._rpose[first - 1] == self._rpose[k])
            ):
                first -= 1
            site, drive = divmod(int(self._rkey[k]), 1 << 32)
            self._note_duplicate(
                site - 1,
                drive - 1,
                int(self._rpose[k]),
                int(self._rrow[first]),
                int(self._rrow[k + 1]),
            )
        self.crs = crs or self._infer_crs()

    @classmethod
    def from_table(
        cls, table: pa.Table, path: Path | None = None, crs: str | None = None
    ) -> Places:
        """A ``Places`` of an Arrow table (any column types; names case-insensitive)."""
        names = [str(n).strip().lower() for n in table.column_names]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise PlacesError(f"{path}: column(s) {', '.join(twice)} appear twice (any case)")
        missing = [c for c in REQUIRED_COLUMNS if c not in names]
        if missing:
            raise PlacesError(f"{path}: missing column(s) {', '.join(missing)}")
        text: dict[tuple[str, int], str] = {}
        columns = {}
        frames = np.zeros(table.num_rows, dtype=np.int8)
        for i, n in enumerate(names):
            col = pc.cast(table.column(i), pa.string())
            if n == "frame":
                frames = _frames(col)
            else:
                columns[n] = _numbers(col, n, 0, text)
        return cls(_Table(columns, frames, text), path=path, crs=crs)

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

    def _check_index(self, column: str, rows: np.ndarray) -> None:
        """Site, drive or pose numbers of ``rows``: integers in [-1, 2**31); else PlacesError
        naming the first row (in the table's order) that is not."""
        values = self._cols[column][rows]
        with np.errstate(invalid="ignore"):
            bad = ~(np.isfinite(values) & (values == np.round(values)) & (values >= -1))
            bad |= ~(values < 2**31)
        if bad.any():
            row = int(rows[np.argmax(bad)])
            shown = self._text.get((column, row), values[np.argmax(bad)])
            raise PlacesError(f"{self._where(row, column)}: expected an integer, got {shown!r}")

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
        """Read a PLACES CSV (or a .gz/.bz2/.xz of one) by header name, streamed in bounded
        memory (``read_places_table``); ``crs`` overrides the inferred table CRS."""
        path = Path(path)
        if not path.is_file():  # a FIFO or a device would block or never end
            raise PlacesError(f"{path}: cannot read PLACES table: not a regular file")
        return cls(read_places_table(path), path=path, crs=crs)

    def __len__(self) -> int:
        return self._n

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
        text = self._text.get((column, row))
        if text is not None:
            raise PlacesError(f"{self._where(row, column)}: expected a number, got {text!r}")
        return float(self._cols[column][row])

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
        self._check_body(row, latitude=lat, longitude=lon, elevation=elev)
        return (lon, lat, elev) if _valid(lon, lat, elev) else None

    def _rows(self, site: int, drive: int) -> slice:
        """Where the ROVER rows of (site, drive) lie in the sorted index."""
        if not (-1 <= site < 2**31 and -1 <= drive < 2**31):
            return slice(0, 0)
        key = (site + 1) * (1 << 32) + drive + 1
        lo = int(np.searchsorted(self._rkey, key, side="left"))
        return slice(lo, int(np.searchsorted(self._rkey, key, side="right")))

    def _check_body(self, row: int, **values: float) -> None:
        """PlacesError naming the line and column of a value no place on Mars has: a latitude
        past +-90 deg, a longitude past +-360 deg, a map coordinate past half the sphere's
        circumference, an elevation outside ``MARS_ELEVATION_M`` (-9999 and empty: unknown)."""
        half = math.pi * MARS_RADIUS_M
        lo, hi = MARS_ELEVATION_M
        bounds = {
            "latitude": (-90.0, 90.0),
            "longitude": (-360.0, 360.0),
            "easting": (-half, half),
            "northing": (-half, half),
            "elevation": (lo, hi),
        }
        columns = {"latitude": "planetocentric_latitude"}
        for name, value in values.items():
            low, high = bounds[name]
            if _valid(value) and not low <= value <= high:
                raise PlacesError(
                    f"{self._where(row, columns.get(name, name))}: {value:g} is no {name} on "
                    f"Mars (expected {low:g} .. {high:g})"
                )

    def poses(self, site: int, drive: int) -> list[int]:
        """The pose numbers of the ROVER rows for (site, drive), ascending ([-1]: one row for
        every pose, or a table without a pose column; []: no row)."""
        return sorted(set(self._rpose[self._rows(site, drive)].tolist()))

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
        found = self._rows(site, drive)
        at = found.start + int(np.flatnonzero(self._rpose[found] == row_pose)[0])
        row = int(self._rrow[at])  # the first in the table's order (the sort is stable)
        e, n = self._value("easting", row), self._value("northing", row)
        lat, lon = self._value("planetocentric_latitude", row), self._value("longitude", row)
        elev = self._value("elevation", row)
        self._check_body(row, easting=e, northing=n, latitude=lat, longitude=lon, elevation=elev)
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
