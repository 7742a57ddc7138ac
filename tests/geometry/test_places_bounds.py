"""A PLACES table is read in bounded memory and bounded expansion, and bad bytes are named:
only the used columns are kept (float64, no Python object per row), a compressed table may
not expand past its limit, a byte that is not UTF-8 is a PlacesError naming the file."""

from __future__ import annotations

import gzip
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest

from mars_pairs.errors import PlacesError
from mars_pairs.geometry.places import Places, read_places_table

REAL = Path(__file__).resolve().parents[2].parent / "shared/pds-samples/m2020/best_interp.csv"


def big_table(path: Path, rows: int) -> Path:
    """A 28-column table of the real header's layout: ``rows`` ROVER rows, one SITE row."""
    rng = np.random.default_rng(0)
    header = REAL.read_text().splitlines()[0].split(",") if REAL.is_file() else None
    if header is None:
        pytest.skip(f"the real PLACES table is not at {REAL} (../shared beside the checkout)")
    cols: dict[str, object] = {}
    for name in header:
        cols[name] = rng.normal(size=rows).round(3)
    cols["frame"] = np.array(["ROVER"] * rows, dtype=object)
    cols["frame"][0] = "SITE"
    cols["site"] = np.arange(rows) // 1000 + 1
    cols["drive"] = np.arange(rows) % 1000
    cols["drive"][0] = -1
    cols["pose"] = np.full(rows, -1)
    cols["easting"] = 4354494.0 + rng.normal(size=rows)
    cols["longitude"] = 77.45 + rng.normal(size=rows) * 1e-5
    for q, v in zip(("quat_s", "quat_v1", "quat_v2", "quat_v3"), (1.0, 0, 0, 0), strict=True):
        cols[q] = np.full(rows, v)
    pacsv.write_csv(pa.table({n: cols[n] for n in header}), path)
    return path


def test_memory_is_a_few_bytes_a_used_cell(tmp_path: Path) -> None:
    rows = 300_000
    csv = big_table(tmp_path / "big.csv", rows)
    probe = (
        "import json, resource, sys\n"
        "from mars_pairs.geometry.places import Places\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        f"p = Places.from_csv({str(csv)!r})\n"
        "after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "print(json.dumps([len(p), (after - before) * 1024, p.poses(1, 5)]))\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    n, grown, poses = json.loads(out.stdout)
    size = csv.stat().st_size
    assert n == rows and poses == [-1]
    # 13 used columns as float64 (~104 bytes a row) plus the index and one block in flight;
    # the table of Python objects it replaces took ~9x the file's size
    assert grown < 0.5 * size, f"{grown / rows:.0f} bytes a row for a {size / rows:.0f}-byte row"


def test_a_decompression_bomb_is_refused_naming_the_file(tmp_path: Path) -> None:
    bomb = tmp_path / "places.csv.gz"
    header = b"frame,site,drive,northing,easting,planetocentric_latitude,longitude,elevation\n"
    with gzip.open(bomb, "wb", compresslevel=9) as fh:
        fh.write(header)
        for _ in range(64):
            fh.write(b"ROVER,1,1,0,0,0,0,0\n" * (1 << 16))
    with pytest.raises(PlacesError, match=r"places\.csv\.gz: .*expands past 1048576 bytes"):
        read_places_table(bomb, limit=1 << 20)


def test_a_compressed_table_reads_as_the_plain_one(tmp_path: Path) -> None:
    if not REAL.is_file():
        pytest.skip(f"the real PLACES table is not at {REAL}")
    packed = tmp_path / "best_interp.csv.gz"
    packed.write_bytes(gzip.compress(REAL.read_bytes()))
    plain, unpacked = Places.from_csv(REAL), Places.from_csv(packed)
    assert len(plain) == len(unpacked) == 9223
    a, b = plain.rover_pose(3, 1950), unpacked.rover_pose(3, 1950)
    assert a is not None and b is not None
    assert (a.easting, a.northing, a.elevation_m) == (b.easting, b.northing, b.elevation_m)
    assert a.quaternion is not None and b.quaternion is not None
    assert np.array_equal(a.quaternion, b.quaternion)


def test_a_byte_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    if not REAL.is_file():
        pytest.skip(f"the real PLACES table is not at {REAL}")
    lines = REAL.read_bytes().splitlines(keepends=True)
    at = next(i for i, line in enumerate(lines) if line.startswith(b"ROVER,3,1950,"))
    lines[at] = lines[at].replace(b"ROVER", b"ROV\xffR", 1)
    bad = tmp_path / "best_interp.csv"
    bad.write_bytes(b"".join(lines))
    with pytest.raises(PlacesError, match=r"best_interp\.csv: cannot read PLACES table: not UTF-8"):
        Places.from_csv(bad)


@pytest.mark.parametrize(
    ("column", "value", "named"),
    [
        ("planetocentric_latitude", "1000.0", "planetocentric_latitude: 1000 is no latitude"),
        ("easting", "1e308", "easting: 1e+308 is no easting"),
        ("elevation", "3e38", "elevation: 3e+38 is no elevation"),
    ],
)
def test_a_value_no_place_on_mars_has_is_refused(
    tmp_path: Path, column: str, value: str, named: str
) -> None:
    if not REAL.is_file():
        pytest.skip(f"the real PLACES table is not at {REAL}")
    lines = REAL.read_text().splitlines(keepends=True)
    header = lines[0].strip().split(",")
    at = next(i for i, line in enumerate(lines) if line.startswith("ROVER,3,1950,"))
    cells = lines[at].rstrip("\n").split(",")
    cells[header.index(column)] = value
    lines[at] = ",".join(cells) + "\n"
    bad = tmp_path / "best_interp.csv"
    bad.write_text("".join(lines))
    with pytest.raises(PlacesError, match=rf"best_interp\.csv: line {at + 1}: {re.escape(named)}"):
        Places.from_csv(bad).rover_pose(3, 1950)
