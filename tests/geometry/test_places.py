"""PLACES tables: lookup by (site, drive), the label fallback, and the real m2020 table."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.frames import M2020_PLACES_CRS, MSL_PLACES_CRS, TangentFrame, lonlat_to_map
from mars_pairs.geometry.places import Places
from mars_pairs.observation import MotionCounter, Observation

HEADER = (
    "frame,site,drive,pose,landing_x,landing_y,landing_z,northing,easting,"
    "planetocentric_latitude,planetodetic_latitude,longitude,elevation,map_pixel_line,"
    "map_pixel_sample,dem_pixel_line,dem_pixel_sample,roll,pitch,yaw,quat_s,quat_v1,quat_v2,"
    "quat_v3,areoid,radius,sclk,sol"
)


def _row(
    frame: str,
    site: int,
    drive: int,
    lon: float,
    lat: float,
    elev: float,
    crs: str,
    quat: tuple[float, float, float, float] | None,
) -> str:
    x, y = lonlat_to_map(lon, lat, crs)
    q = quat if quat is not None else (-9999.0,) * 4
    cols = [
        frame,
        site,
        drive,
        -1,
        0,
        0,
        0,
        f"{y:.3f}",
        f"{x:.3f}",
        lat,
        lat,
        lon,
        elev,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        *q,
        3394507.0,
        3391937.0,
        0,
        10,
    ]
    return ",".join(str(c) for c in cols)


def _observation(site: int, drive: int, offset: tuple[float, float, float] | None) -> Observation:
    cam = CameraModel("CAHV", [0.8, 0.5, -1.97], [1, 0, 0], [0, 4000, 0], [0, 0, 4000])
    return Observation(
        label_path=Path("fake.LBL"),
        mission="msl",
        product_id="X",
        instrument="MAST_LEFT",
        sol=10,
        rmc=MotionCounter(site, drive, 0),
        width=1000,
        height=800,
        camera=cam,
        rover_offset_m=None if offset is None else np.array(offset),
        rover_quaternion=np.array([0.9238795, 0, 0, 0.3826834]),
    )


@pytest.fixture()
def gale_table(tmp_path: Path) -> Path:
    crs = MSL_PLACES_CRS
    rows = [
        HEADER,
        _row("SITE", 5, -1, 137.40, -4.60, -4500.0, crs, (1.0, 0.0, 0.0, 0.0)),
        _row("ROVER", 5, 100, 137.401, -4.601, -4501.5, crs, (0.7071068, 0, 0, 0.7071068)),
        _row("ROVER", 5, 200, 137.402, -4.602, -4502.0, crs, None),
        _row("SITE", 6, -1, 137.41, -4.61, -4510.0, crs, (1.0, 0.0, 0.0, 0.0)),
    ]
    path = tmp_path / "localized_interp.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def test_crs_is_inferred_from_the_rows(gale_table: Path) -> None:
    assert Places.from_csv(gale_table).crs == MSL_PLACES_CRS


def test_rover_row_wins_and_carries_its_attitude(gale_table: Path) -> None:
    pose = Places.from_csv(gale_table).locate(_observation(5, 100, (1.0, 2.0, 0.0)))
    assert pose.source == "places" and pose.attitude_source == "places"
    x, y = lonlat_to_map(137.401, -4.601, MSL_PLACES_CRS)
    assert (pose.easting, pose.northing) == pytest.approx((float(x), float(y)), abs=1e-3)
    np.testing.assert_allclose(pose.quaternion, [0.7071068, 0, 0, 0.7071068])


def test_missing_attitude_falls_back_to_the_label(gale_table: Path) -> None:
    pose = Places.from_csv(gale_table).locate(_observation(5, 200, None))
    assert pose.source == "places" and pose.attitude_source == "label"
    np.testing.assert_allclose(pose.quaternion, [0.9238795, 0, 0, 0.3826834])


def test_no_rover_row_uses_the_label_offset_from_the_site_origin(gale_table: Path) -> None:
    offset = (120.0, -35.0, 1.5)  # NED metres from the SITE origin
    pose = Places.from_csv(gale_table).locate(_observation(6, 42, offset))
    assert pose.source == "label"
    back = TangentFrame(137.41, -4.61, -4510.0).lonlat_to_ned(
        pose.longitude, pose.latitude, pose.elevation_m
    )
    np.testing.assert_allclose(back, offset, atol=1e-6)
    assert pose.elevation_m == pytest.approx(-4511.5, abs=0.01)


def test_no_row_and_no_site_is_a_clear_error(gale_table: Path) -> None:
    with pytest.raises(PlacesError, match=r"site 9 drive 1"):
        Places.from_csv(gale_table).locate(_observation(9, 1, (1.0, 1.0, 0.0)))


def test_unreadable_and_incomplete_tables(tmp_path: Path) -> None:
    with pytest.raises(PlacesError, match="cannot read"):
        Places.from_csv(tmp_path / "absent.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,site,drive\nSITE,1,-1\n")
    with pytest.raises(PlacesError, match="missing column"):
        Places.from_csv(bad)


def test_real_m2020_table(samples_dir: Path) -> None:
    places = Places.from_csv(samples_dir / "m2020" / "best_interp.csv")
    assert places.crs == M2020_PLACES_CRS
    pose = places.rover_pose(3, 1950)
    assert pose is not None
    assert (pose.easting, pose.northing) == (4354557.816, 1093309.691)
    # the table's own easting/northing follow from its lat/lon through the CRS
    x, y = lonlat_to_map(pose.longitude, pose.latitude, places.crs)
    assert (float(x), float(y)) == pytest.approx((pose.easting, pose.northing), abs=1e-3)
    # and the exact tangent frame reproduces its landing_x/y/z offsets from the SITE origin
    origin = places.site_origin(3)
    assert origin is not None
    ned = TangentFrame(*origin).lonlat_to_ned(pose.longitude, pose.latitude, pose.elevation_m)
    np.testing.assert_allclose(ned, [9.996, 63.730, -0.930], atol=0.05)


# -- damaged tables (issue 17) ----------------------------------------------------------------
def _with_cell(table: Path, line: int, column: str, value: str) -> Path:
    lines = table.read_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[HEADER.split(",").index(column)] = value
    lines[line - 1] = ",".join(cells)
    out = table.with_name(f"{column}-{line}.csv")
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize(("column", "value"), [("site", "abc"), ("drive", ""), ("drive", "1.5")])
def test_a_bad_site_or_drive_cell_names_the_line_and_column(
    gale_table: Path, column: str, value: str
) -> None:
    bad = _with_cell(gale_table, 3, column, value)
    with pytest.raises(PlacesError, match=rf"{bad.name}: line 3: {column}: expected an integer"):
        Places.from_csv(bad)


def test_a_text_easting_fails_only_the_observations_of_its_row(gale_table: Path) -> None:
    places = Places.from_csv(_with_cell(gale_table, 3, "easting", "x"))
    with pytest.raises(PlacesError, match=r"line 3: easting: expected a number, got 'x'"):
        places.locate(_observation(5, 100, None))
    assert places.locate(_observation(6, 42, (1.0, 2.0, 0.0))).source == "label"


def test_conflicting_rover_rows_are_refused_identical_ones_kept(gale_table: Path) -> None:
    lines = gale_table.read_text().splitlines()
    crs = MSL_PLACES_CRS
    moved = _row("ROVER", 5, 100, 137.403, -4.601, -4501.5, crs, (0.7071068, 0, 0, 0.7071068))
    conflict = gale_table.with_name("conflict.csv")
    conflict.write_text("\n".join([*lines, moved]) + "\n")
    places = Places.from_csv(conflict)
    with pytest.raises(PlacesError, match=r"lines 3 and 6: conflicting ROVER rows .* m apart"):
        places.locate(_observation(5, 100, None))
    assert places.locate(_observation(5, 200, None)).source == "places"  # the others still work
    same = gale_table.with_name("same.csv")
    same.write_text("\n".join([*lines, lines[2]]) + "\n")
    assert Places.from_csv(same).locate(_observation(5, 100, None)).source == "places"


def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "places.csv"
    os.mkfifo(fifo)
    with pytest.raises(PlacesError, match="not a regular file"):
        Places.from_csv(fifo)


def test_curiosity_crs_from_rounded_longitudes() -> None:
    """rover_positions.csv's 7-decimal longitudes read as lat_ts ~0.0015 by acos: still eqc 0."""
    from mars_pairs.geometry.frames import MSL_PLACES_CRS
    from mars_pairs.geometry.places import infer_places_crs

    assert infer_places_crs(8141618.407, 137.3540271) == MSL_PLACES_CRS
    assert "+lat_ts=0.05" in infer_places_crs(8141618.407 * math.cos(math.radians(0.05)),
                                               137.3540271)  # fmt: skip
