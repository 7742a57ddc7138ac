"""PLACES table generations (quaternion columns / upper-case roll-pitch-yaw) and pose lookup.

The real facts: ``../shared/real-archive/msl_localized_interp_head.csv`` (the current Curiosity
table's 26-column header and two rows), ``../shared/pds-samples/m2020/best_interp.csv``
(Perseverance, 28 columns), ``../shared/real-gale/rover_positions.csv`` (real Curiosity rows
with PLACES column names) and the sol-1429 Mastcam labels taken at site 56, drive 1632, pose 8.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv
import pytest

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.geometry.places import Places
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.pds import read_observation

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
QUAT = ("quat_s", "quat_v1", "quat_v2", "quat_v3")

#: The current Curiosity header (../shared/real-archive/msl_localized_interp_head.csv).
HEADER_26 = [
    "frame",
    "site",
    "drive",
    "pose",
    "landing_x",
    "landing_y",
    "landing_z",
    "northing",
    "easting",
    "planetocentric_latitude",
    "planetodetic_latitude",
    "longitude",
    "elevation",
    "map_pixel_line",
    "map_pixel_sample",
    "dem_pixel_line",
    "dem_pixel_sample",
    "roll",
    "pitch",
    "yaw",
    "quat_s",
    "quat_v1",
    "quat_v2",
    "quat_v3",
    "sclk",
    "sol",
]
#: The PDS3-era header: the same without the quaternion, upper case ("FRAME ... YAW, SCLK, SOL").
HEADER_22 = [c.upper() for c in HEADER_26 if c not in QUAT]


def _angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Rotation angle between two attitudes, written here (not the package's helper)."""
    cos = abs(float(np.dot(q1, q2))) / (np.linalg.norm(q1) * np.linalg.norm(q2))
    return math.degrees(2 * math.acos(min(1.0, cos)))


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"real file not found: {path} (../shared beside the checkout)")
    return path


def _rows(csv: Path) -> list[dict]:
    return pacsv.read_csv(csv).to_pylist()


def _write(path: Path, header: list[str], rows: list[dict]) -> Path:
    """A PLACES CSV with ``header``; cells by lower-case name, -9999 for what a row lacks."""
    lines = [",".join(header)]
    for r in rows:
        lines.append(",".join(str(r.get(c.lower(), -9999)) for c in header))
    path.write_text("\n".join(lines) + "\n")
    return path


# -- the roll/pitch/yaw convention, on real rows and labels -------------------------------------
def _z_y_x(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) as a matrix, then its quaternion (written here)."""
    r, p, y = np.radians([roll, pitch, yaw])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    m = rz @ ry @ rx
    s = math.sqrt(max(0.0, 1 + np.trace(m))) / 2
    v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / (4 * s)
    return np.array([s, *v])


def test_rpy_tables_reproduce_the_real_quaternion_columns(tmp_path: Path) -> None:
    """A table without quaternion columns gets the same attitude from roll/pitch/yaw: every
    attitude row of the real best_interp.csv and of the current Curiosity table's head."""
    for real, name in (
        (_need(SHARED / "pds-samples" / "m2020" / "best_interp.csv"), "m2020"),
        (_need(SHARED / "real-archive" / "msl_localized_interp_head.csv"), "msl"),
    ):
        rows = [r for r in _rows(real) if r["frame"] == "ROVER" and r["quat_s"] != -9999]
        header = [c for c in pacsv.read_csv(real).column_names if c not in QUAT]
        with_q = Places.from_csv(real)
        without = Places.from_csv(_write(tmp_path / f"{name}.csv", header, rows))
        assert without.attitude_columns == ("roll", "pitch", "yaw")
        worst = 0.0
        for r in rows:
            a = with_q.rover_pose(r["site"], r["drive"], r["pose"])
            b = without.rover_pose(r["site"], r["drive"], r["pose"])
            assert a is not None and b is not None
            assert (a.easting, a.northing) == (b.easting, b.northing)
            worst = max(worst, _angle_deg(a.quaternion, b.quaternion))
        assert len(rows) >= (9000 if name == "m2020" else 1)
        assert worst < 0.01, (name, worst)


def test_sol_1429_label_quaternions_match_roll_pitch_yaw() -> None:
    """The labels' ORIGIN_ROTATION_QUATERNION vs R = Rz(yaw) Ry(pitch) Rx(roll) of the
    rover_positions.csv row (56, 1632), and vs that row's own quaternion columns."""
    labels = sorted((SHARED / "pds-samples" / "msl").glob("1429MR*.LBL"))
    if len(labels) != 4:
        pytest.skip("the four real sol-1429 Mastcam labels are not in ../shared/pds-samples/msl")
    csv = _need(SHARED / "real-gale" / "rover_positions.csv")
    row = next(r for r in _rows(csv) if (r["site"], r["drive"]) == (56, 1632))
    from_rpy = _z_y_x(row["roll"], row["pitch"], row["yaw"])
    assert _angle_deg(from_rpy, np.array([row[c] for c in QUAT])) < 0.01
    for label in labels:
        obs = read_observation(label)
        assert (obs.rmc.site, obs.rmc.drive, obs.rmc.pose) == (56, 1632, 8)
        assert _angle_deg(np.asarray(obs.rover_quaternion), from_rpy) <= 0.5


# -- the four sol-1429 labels through both generations --------------------------------------------
def _tables_from_rover_positions(tmp_path: Path) -> tuple[Path, Path, dict]:
    """26-column (lower case, quaternion) and 22-column (upper case, roll/pitch/yaw) tables of
    rover_positions.csv; every row at pose 0, and (56, 1632) also at pose 8 (the labels') with
    the real values while its pose-0 row is moved 0.5 m and turned 3 degrees."""
    csv = _need(SHARED / "real-gale" / "rover_positions.csv")
    rows, real = [], None
    for r in _rows(csv):
        r = {**r, "pose": 0}
        if (r["site"], r["drive"]) == (56, 1632):
            real = r
            rows.append({**r, "easting": r["easting"] + 0.5, "yaw": r["yaw"] + 3.0, "quat_s": 1.0,
                         "quat_v1": 0.0, "quat_v2": 0.0, "quat_v3": 0.0})  # fmt: skip
            r = {**r, "pose": 8}
        rows.append(r)
    assert real is not None
    new = _write(tmp_path / "localized_interp.csv", HEADER_26, rows)
    old = _write(tmp_path / "LOCALIZED_INTERP_PDS3.csv", HEADER_22, rows)
    return new, old, real


def test_sol_1429_labels_located_through_both_generations(tmp_path: Path) -> None:
    labels = sorted((SHARED / "pds-samples" / "msl").glob("1429MR*.LBL"))
    if len(labels) != 4:
        pytest.skip("the four real sol-1429 Mastcam labels are not in ../shared/pds-samples/msl")
    head = _need(SHARED / "real-archive" / "msl_localized_interp_head.csv")
    assert pacsv.read_csv(head).column_names == HEADER_26  # the real current header
    new, old, real = _tables_from_rover_positions(tmp_path)
    assert len(pacsv.read_csv(new).column_names) == 26
    assert pacsv.read_csv(old).column_names[:3] == ["FRAME", "SITE", "DRIVE"]
    assert len(pacsv.read_csv(old).column_names) == 22
    current, pds3 = Places.from_csv(new), Places.from_csv(old)
    assert pds3.attitude_columns == ("roll", "pitch", "yaw")
    truth_q = np.array([real[c] for c in QUAT])
    for label in labels:
        obs = read_observation(label)
        a, b = current.locate(obs), pds3.locate(obs)
        for pose in (a, b):
            assert (pose.source, pose.match, pose.pose) == ("places", "site-drive-pose", 8)
            assert abs(pose.easting - real["easting"]) <= 0.01
            assert abs(pose.northing - real["northing"]) <= 0.01
            assert abs(pose.elevation_m - real["elevation"]) <= 0.01
            assert _angle_deg(pose.quaternion, truth_q) <= 0.5
            assert _angle_deg(pose.quaternion, np.asarray(obs.rover_quaternion)) <= 0.5
        gap = math.dist(
            (a.easting, a.northing, a.elevation_m), (b.easting, b.northing, b.elevation_m)
        )
        assert gap <= 0.01 and _angle_deg(a.quaternion, b.quaternion) <= 0.5


# -- the pose lookup -----------------------------------------------------------------------------
def _pose_table(tmp_path: Path, poses: list[int], name: str = "poses.csv") -> Path:
    """ROVER rows for (5, 100) at ``poses``, pose p standing p metres east of the first."""
    rows = [{"frame": "SITE", "site": 5, "drive": -1, "pose": -1, "northing": -272000.0,
             "easting": 8146000.0, "planetocentric_latitude": -4.59, "longitude": 137.43,
             "elevation": -4500.0, "roll": 0, "pitch": 0, "yaw": 0}]  # fmt: skip
    for p in poses:
        rows.append({**rows[0], "frame": "ROVER", "drive": 100, "pose": p,
                     "easting": 8146000.0 + max(p, 0) + 100.0, "yaw": 10.0 * p})  # fmt: skip
    return _write(tmp_path / name, HEADER_22, rows)


def _observation(
    site: int, drive: int, pose: int | None, offset: tuple[float, float, float] | None = None
) -> Observation:
    cam = CameraModel("CAHV", [0.8, 0.5, -1.97], [1, 0, 0], [0, 4000, 0], [0, 0, 4000])
    return Observation(
        label_path=Path("fake.LBL"), mission="msl", product_id="X", instrument="MAST_LEFT",
        sol=10, rmc=MotionCounter(site, drive, pose), width=1000, height=800, camera=cam,
        rover_offset_m=None if offset is None else np.array(offset),
        rover_quaternion=np.array([0.9238795, 0, 0, 0.3826834]),
    )  # fmt: skip


def _at(pose: int | None) -> Observation:
    return _observation(5, 100, pose)


@pytest.mark.parametrize(
    ("poses", "label", "row", "match"),
    [
        ([0, 4, 10], 4, 4, "site-drive-pose"),
        ([0, 4, 10], 6, 4, "earlier-pose"),  # the latest state before the image
        ([0, 4, 10], 12, 10, "earlier-pose"),
        ([5, 9], 2, 5, "later-pose"),  # nothing at or before it: the next state
        ([-1, 5], 2, -1, "site-drive"),  # the row for every pose beats a later one
        ([-1, 5], 7, 5, "earlier-pose"),
        ([-1], 8, -1, "site-drive"),  # Perseverance's best_interp.csv: pose -1 throughout
        ([0, 4, 10], None, 0, "site-drive"),  # a label without a pose: the first
    ],
)
def test_the_pose_row_is_chosen_and_recorded(
    tmp_path: Path, poses: list[int], label: int | None, row: int, match: str
) -> None:
    pose = Places.from_csv(_pose_table(tmp_path, poses)).locate(_at(label))
    assert (pose.pose, pose.match, pose.source) == (row, match, "places")
    assert pose.easting == pytest.approx(8146100.0 + max(row, 0))


def test_rows_differing_by_pose_are_not_duplicates_same_pose_conflicts_are(
    tmp_path: Path,
) -> None:
    places = Places.from_csv(_pose_table(tmp_path, [0, 4, 10]))  # 4 and 10 m apart: fine
    assert places.poses(5, 100) == [0, 4, 10]
    assert places.locate(_at(10)).pose == 10
    text = _pose_table(tmp_path, [0, 4], "conflict.csv").read_text()
    moved = text.splitlines()[-1].replace("8146104.0", "8146109.0")
    conflict = tmp_path / "conflict.csv"
    conflict.write_text(text + moved + "\n")
    places = Places.from_csv(conflict)
    with pytest.raises(PlacesError, match=r"conflict.csv: lines 4 and 5: .* drive 100 pose 4"):
        places.locate(_at(4))
    assert places.locate(_at(0)).pose == 0  # the other pose still works


def test_the_label_offset_fallback_says_so(tmp_path: Path) -> None:
    obs = _observation(5, 200, 3, (3.0, 4.0, 0.0))
    pose = Places.from_csv(_pose_table(tmp_path, [0])).locate(obs)
    assert (pose.source, pose.match, pose.pose) == ("label", "label-offset", None)


def test_a_table_without_pose_is_looked_up_by_site_and_drive() -> None:
    csv = _need(SHARED / "real-gale" / "rover_positions.csv")
    places = Places.from_csv(csv)
    assert not places.has_pose
    pose = places.rover_pose(56, 1632, 8)
    assert pose is not None and (pose.pose, pose.match) == (None, "site-drive")


# -- headers -------------------------------------------------------------------------------------
def test_missing_columns_are_named_with_the_file(tmp_path: Path) -> None:
    rows = [{"frame": "ROVER", "site": 1, "drive": 0, "pose": 0, "northing": -272000.0,
             "easting": 8146000.0, "planetocentric_latitude": -4.59, "longitude": 137.43,
             "elevation": -4500.0, "roll": 1, "pitch": 2, "yaw": 3}]  # fmt: skip
    no_yaw = _write(tmp_path / "no_yaw.csv", [c for c in HEADER_22 if c != "YAW"], rows)
    with pytest.raises(PlacesError, match=r"no_yaw.csv: missing column\(s\) quat_s.*yaw"):
        Places.from_csv(no_yaw)
    no_north = _write(tmp_path / "no_north.csv", [c for c in HEADER_22 if c != "NORTHING"], rows)
    with pytest.raises(PlacesError, match=r"no_north.csv: missing column\(s\) northing$"):
        Places.from_csv(no_north)
    twice = _write(tmp_path / "twice.csv", [*HEADER_22, "Site"], rows)
    with pytest.raises(PlacesError, match=r"twice.csv: column\(s\) site appear twice"):
        Places.from_csv(twice)
    mixed = _write(tmp_path / "mixed.csv", [c.title() for c in HEADER_22], rows)
    pose = Places.from_csv(mixed).rover_pose(1, 0, 0)
    assert pose is not None and pose.attitude_source == "places"


def test_fetch_reads_the_rover_positions_of_an_upper_case_table(tmp_path: Path) -> None:
    from mars_pairs.fetch.orbital import rover_positions

    new, old, real = _tables_from_rover_positions(tmp_path)
    a, b = rover_positions(new, sites=(56,)), rover_positions(old, sites=(56,))
    assert a.crs == b.crs and len(b.x) == len(a.x) >= 2
    assert real["easting"] in b.x.tolist() and real["northing"] in b.y.tolist()
