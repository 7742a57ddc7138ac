"""PLACES tables at archive scale: peak memory of reading one, against reading it whole.

``python benchmarks/bench_places.py [--rows 3000000]`` writes a PLACES CSV of ``--rows`` rows
in the layout of the real MSL localized_interp table (the header of
``../shared/real-archive/msl_localized_interp_head.csv``: 26 columns, a SITE row per site then
its ROVER rows, values in that file's formats) to a temporary folder, then reads it in a fresh
process per case and prints a markdown table:

- ``read_places_table`` (what ``locate`` and the build use: streamed, only the used columns
  kept as float64);
- the anchor: ``pyarrow.csv.read_csv`` of the whole table (every column materialised), the
  plain way to read it.

Memory is the growth of the peak resident set (``VmHWM``) over the process after its imports;
time is the read's wall time. The load average is printed before and after: on a shared machine
compare rows of one run only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

HEADER = [
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
ROWS_PER_SITE = 1000


def write_table(path: Path, rows: int, seed: int = 0) -> None:
    """A PLACES CSV of ``rows`` rows (one SITE row then ROVER rows per site), written in
    record batches of one site group each 100 sites."""
    rng = np.random.default_rng(seed)
    options = pacsv.WriteOptions(include_header=True)
    with pacsv.CSVWriter(path, _schema(), write_options=options) as writer:
        done = 0
        site = 1
        while done < rows:
            n = min(ROWS_PER_SITE * 100, rows - done)
            sites = site + np.arange(n) // ROWS_PER_SITE
            drive = np.arange(n) % ROWS_PER_SITE
            frame = np.where(drive == 0, "SITE", "ROVER")
            lat = -4.59 + rng.normal(0, 0.01, n)
            lon = 137.44 + rng.normal(0, 0.01, n)
            q = rng.normal(size=(n, 4))
            q /= np.linalg.norm(q, axis=1, keepdims=True)
            cols: dict[str, object] = {
                "frame": frame, "site": sites, "drive": drive - (drive == 0),
                "pose": np.where(drive == 0, -1, 0),
            }  # fmt: skip
            for name in HEADER[4:]:
                cols.setdefault(name, np.round(rng.normal(0, 100, n), 3))
            cols.update(
                planetocentric_latitude=lat, planetodetic_latitude=lat, longitude=lon,
                elevation=np.round(-4500 + rng.normal(0, 20, n), 3),
                quat_s=q[:, 0], quat_v1=q[:, 1], quat_v2=q[:, 2], quat_v3=q[:, 3],
                sclk=397502188 + np.arange(n) * 10, sol=sites // 10,
            )  # fmt: skip
            writer.write_table(pa.table({k: cols[k] for k in HEADER}, schema=_schema()))
            done += n
            site += n // ROWS_PER_SITE + 1


def _schema() -> pa.Schema:
    kinds = {"frame": pa.string(), "site": pa.int64(), "drive": pa.int64(), "pose": pa.int64()}
    kinds.update(sclk=pa.int64(), sol=pa.int64())
    return pa.schema([(n, kinds.get(n, pa.float64())) for n in HEADER])


def _hwm_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _case(kind: str, path: str) -> None:
    """Run in a fresh process: read ``path`` as ``kind``, print a JSON line."""
    if kind == "read_places_table":
        from mars_pairs.geometry.places import read_places_table

        base = _hwm_mib()
        start = time.perf_counter()
        read_places_table(Path(path))
    else:
        base = _hwm_mib()
        start = time.perf_counter()
        pacsv.read_csv(path)
    seconds = time.perf_counter() - start
    print(json.dumps({"seconds": seconds, "growth_mib": _hwm_mib() - base}))


REAL_HEAD = (
    Path(__file__).resolve().parents[1] / "../shared/real-archive/msl_localized_interp_head.csv"
)


def main() -> None:
    if REAL_HEAD.is_file():  # the layout is the real table's (shared/ beside the clone)
        real = REAL_HEAD.read_text().splitlines()[0].split(",")
        assert real == HEADER, f"{REAL_HEAD}: header {real} differs from the benchmark's"
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=3_000_000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "localized_interp.csv"
        write_table(path, args.rows)
        size = path.stat().st_size / 2**20
        load0 = os.getloadavg()
        out = []
        for kind in ("read_places_table", "pyarrow.csv.read_csv (whole table)"):
            done = subprocess.run(
                [sys.executable, __file__, "--case", kind.split()[0], str(path)],
                capture_output=True, text=True, check=True,
            )  # fmt: skip
            out.append((kind, json.loads(done.stdout.strip().splitlines()[-1])))
        load1 = os.getloadavg()
    print(
        f"PLACES table of {args.rows:,} rows x {len(HEADER)} columns, {size:.0f} MiB; "
        f"load average {load0[0]:.2f} before, {load1[0]:.2f} after\n"
    )
    print("| read | seconds | peak RSS growth MiB | bytes per row |")
    print("|---|---:|---:|---:|")
    for kind, r in out:
        per_row = r["growth_mib"] * 2**20 / args.rows
        print(f"| {kind} | {r['seconds']:.2f} | {r['growth_mib']:.0f} | {per_row:.0f} |")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--case":
        _case(sys.argv[2], sys.argv[3])
    else:
        main()
