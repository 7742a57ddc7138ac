"""A replica of the real PDS archive, from the real files in ../shared, in their real paths.

What is real and what is made, so that a test on it says what it proves:

- Labels: the real Curiosity sol-1429 Mastcam labels (``../shared/pds-samples/msl``, PDS3,
  ``^IMAGE`` -> ``.IMG``) and the real Mastcam-Z labels (``../shared/pds-samples/m2020``,
  PDS4, no ``file_size``/``md5_checksum``), byte for byte, under the archive's own paths
  (``MSLMST_00NN/DATA/RDR/SURFACE/<sol>/``; ``data/sol/<5-digit sol>/ids/rdr/zcam/``, file
  name = upper-case product id + version, ``../shared/real-archive/README.md``).
- Images: the ``.IMG`` each label names, laid out as the label says (PDS3: 8-bit band
  sequential; PDS4: ODL3 + VICAR headers, then ``SignedMSB2`` Band/Line/Sample at the label's
  offset), with pixel values from the real browse JPEGs. The header bytes are filler.
- Curiosity indexes: ``INDEX/RDRINDEX.LBL`` + ``.TAB`` per volume MSLMST_0013..0015 (the
  real-archive README names these three for sol 1429; the shipped sol-range table ends 0013 at
  sol 1417, so a fetch for sol 1429 reads 0014 and 0015 only) in the PDS3
  fixed-width layout with the real column names; the rows are made from the labels (the real
  index holds ~75 MB of them); 0013 lists products of other sols, 0015 lists one of the
  sol-1429 products again (a re-release).
- Mastcam-Z inventory: the real rows of ``mastcamz_inventory_rows.csv`` (CRLF, LIDVIDs with
  the version in the VID), behind a ``Product_Collection`` label modelled on the real
  ``pds4_collection_label_example.xml``.
- PLACES: Mars 2020 ``best_interp.csv`` (real, 28 columns); Curiosity's current 26-column
  ``localized_interp.csv`` and the PDS3-era 22-column upper-case one, both made from the real
  positions in ``../shared/real-gale/rover_positions.csv`` (its header names; the pose column
  is made: 0 for every real row, which for site 56 drive 1632 is moved 0.5 m east and turned
  3 degrees, plus a pose-8 row holding the real position, the sol-1429 labels' pose: a wrong
  pose choice shows).
- Orbital maps: the PLACES bundles' maps in their paths and formats (Curiosity
  ``MSLPLC_1XXX/DATA/MAPS/msl_orbital_{dem,map}.img``: VICAR; Mars 2020
  ``data_maps/m20_orbital_{dem,map}.{xml,img}``: PDS4 label + raw image), written by GDAL, on
  the PLACES grids (the Mars 2020 grid recovered from the table's ``map_pixel``/``dem_pixel``
  columns: upper left 4351080 E, 1094650 N, DEM 1 m, map 0.25 m), cropped around the rovers.
  The terrain is synthetic (``mars_pairs.synth``), shifted to the PLACES elevations: the
  real maps are gigabytes.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from PIL import Image
from rasterio.transform import from_origin

from mars_pairs.synth.ortho import make_ortho
from mars_pairs.synth.terrain import make_dem
from support.real_samples import SHARED

SAMPLES = SHARED / "pds-samples"
REAL_ARCHIVE = SHARED / "real-archive"
REAL_GALE = SHARED / "real-gale"

MSL_PLACES_CRS = "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"
M2020_PLACES_CRS = (
    "+proj=eqc +lat_ts=18.4663 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"
)

MSL_VOLUMES = ("MSLMST_0013", "MSLMST_0014", "MSLMST_0015")
MSL_PLACES_CURRENT = "msl_places/data_localizations/localized_interp.csv"
MSL_PLACES_PDS3 = "MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv"
MSL_MAPS = "MSLPLC_1XXX/DATA/MAPS"
M2020_BUNDLE = "mars2020_mastcamz_ops_calibrated"
M2020_COLLECTION = "data/collection_data.xml"
M2020_INVENTORY = "data/collection_data_inventory.csv"
M2020_PLACES_BUNDLE = "urn-nasa-pds-mars2020_rover_places"
M2020_PLACES = f"{M2020_PLACES_BUNDLE}/data_localizations/best_interp.csv"
M2020_MAPS = f"{M2020_PLACES_BUNDLE}/data_maps"

# the Mars 2020 PLACES map grid, from best_interp.csv's map/dem pixel columns (upper left)
M2020_GRID_ORIGIN = (4351080.0, 1094650.0)
CROP_M = 512  # replica map crops: metres on a side, around the rovers


@dataclass(frozen=True)
class Replica:
    """The replica's root (serve it: ``msl/`` and ``mars2020/`` are the archive roots)."""

    root: Path
    msl_labels: tuple[str, ...]  # archive paths under msl/
    m2020_labels: tuple[str, ...]  # archive paths under mars2020/

    @property
    def msl(self) -> Path:
        return self.root / "msl"

    @property
    def m2020(self) -> Path:
        return self.root / "mars2020"


def available() -> str | None:
    """None when ../shared holds what the replica needs, else the reason it does not."""
    for folder in (SAMPLES / "msl", SAMPLES / "m2020", REAL_ARCHIVE, REAL_GALE):
        if not folder.is_dir():
            return f"{folder} not found (../shared beside the checkout)"
    return None


# -- Curiosity -----------------------------------------------------------------------------
def _msl_img(jpeg: Path, out: Path) -> None:
    """The 8-bit band-sequential image a DRCL label's ^IMAGE names, from its browse JPEG."""
    rgb = np.asarray(Image.open(jpeg).convert("RGB"), dtype=np.uint8)
    out.write_bytes(np.ascontiguousarray(rgb.transpose(2, 0, 1)).tobytes())


def _index_rows(label: Path, volume: str) -> dict[str, object]:
    from mars_pairs.pds import read_observation

    obs = read_observation(label)
    return {
        "VOLUME_ID": volume,
        "PATH_NAME": f"DATA/RDR/SURFACE/{obs.sol:04d}/",
        "FILE_NAME": label.name,
        "PRODUCT_ID": obs.product_id,
        "INSTRUMENT_ID": obs.instrument,
        "PLANET_DAY_NUMBER": obs.sol,
        "IMAGE_ID": obs.product_id.split("_")[0],
    }


def _msl_archive(root: Path) -> tuple[str, ...]:
    from support.fetch_archive import write_pds3_index

    labels = sorted((SAMPLES / "msl").glob("1429*.LBL"))
    volume = "MSLMST_0014"  # the labels' RELEASE_ID
    rows: dict[str, list[dict[str, object]]] = {v: [] for v in MSL_VOLUMES}
    placed = []
    for label in labels:
        rel = f"{volume}/DATA/RDR/SURFACE/1429/{label.name}"
        dest = root / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(label, dest)
        _msl_img(label.with_suffix(".jpg"), dest.with_suffix(".IMG"))
        rows[volume].append(_index_rows(label, volume))
        placed.append(rel)
    # a re-release: 0015 lists the first product again (same file in its own volume)
    again = root / f"MSLMST_0015/DATA/RDR/SURFACE/1429/{labels[0].name}"
    again.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(root / placed[0], again)
    shutil.copyfile((root / placed[0]).with_suffix(".IMG"), again.with_suffix(".IMG"))
    rows["MSLMST_0015"].append(_index_rows(labels[0], "MSLMST_0015"))
    # 0013: products of other sols (left out by the sol filter, never fetched)
    for sol in (1300, 1417):
        row = dict(_index_rows(labels[1], "MSLMST_0013"))
        pid = f"{sol}MR0070680020702583E01_DRCL"
        row.update(PATH_NAME=f"DATA/RDR/SURFACE/{sol:04d}/", FILE_NAME=f"{pid}.LBL",
                   PRODUCT_ID=pid, PLANET_DAY_NUMBER=sol, IMAGE_ID=pid.split("_")[0])  # fmt: skip
        rows["MSLMST_0013"].append(row)
    for v in MSL_VOLUMES:
        write_pds3_index(root / v, rows[v])
    return tuple(placed)


def _gale_rows() -> list[dict[str, str]]:
    with open(REAL_GALE / "rover_positions.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def msl_places_tables(folder: Path) -> tuple[Path, Path]:
    """The 26-column current and 22-column PDS3-era Curiosity PLACES tables, from the real
    positions of ``rover_positions.csv``; returns (current, pds3)."""
    header26 = (REAL_ARCHIVE / "msl_localized_interp_head.csv").read_text().splitlines()[0]
    cols26 = header26.split(",")
    quat = ("quat_s", "quat_v1", "quat_v2", "quat_v3")
    cols22 = [c for c in cols26 if c not in quat]
    assert len(cols26) == 26 and len(cols22) == 22
    rows = []
    for r in _gale_rows():
        out = {c: "" for c in cols26}
        out.update({k: v for k, v in r.items() if k in out})
        lat = float(r["planetocentric_latitude"])
        out["planetodetic_latitude"] = f"{lat:.9f}"  # a sphere: the same
        for c in ("landing_x", "landing_y", "landing_z"):
            out[c] = "0.000"
        for c in ("map_pixel_line", "map_pixel_sample", "dem_pixel_line", "dem_pixel_sample"):
            out[c] = "-1.00"
        out["pose"] = "0"
        if (r["site"], r["drive"]) == ("56", "1632"):
            rows.append({**out, "pose": "8"})  # the real row: where the labels were taken
            out = _moved(out, east_m=0.5, yaw_deg=3.0)  # a made-up earlier pose
        rows.append(out)
    folder.mkdir(parents=True, exist_ok=True)
    current, pds3 = folder / "localized_interp_26.csv", folder / "localized_interp_22.csv"
    with open(current, "w", newline="") as fh:
        w = csv.DictWriter(fh, cols26, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    with open(pds3, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow([c.upper() for c in cols22])
        w.writerows([[row[c] for c in cols22] for row in rows])
    return current, pds3


def _moved(row: dict[str, str], *, east_m: float, yaw_deg: float) -> dict[str, str]:
    """The row moved ``east_m`` metres east (eqc lat_ts 0 map units: metres on the sphere) and
    turned ``yaw_deg`` about the vertical (yaw and the quaternion both: the quaternion
    q' = q_z(yaw) * q, rotating site-frame vectors about down)."""
    out = dict(row)
    out["easting"] = f"{float(row['easting']) + east_m:.3f}"
    lon = float(row["longitude"]) + math.degrees(east_m / 3396190.0)
    out["longitude"] = f"{lon:.9f}"
    out["yaw"] = f"{float(row['yaw']) + yaw_deg:.6f}"
    half = math.radians(yaw_deg) / 2
    qz = (math.cos(half), 0.0, 0.0, math.sin(half))
    q = tuple(float(row[c]) for c in ("quat_s", "quat_v1", "quat_v2", "quat_v3"))
    s1, v1 = qz[0], qz[1:]
    s2, v2 = q[0], q[1:]
    s = s1 * s2 - sum(a * b for a, b in zip(v1, v2, strict=True))
    cross = (v1[1] * v2[2] - v1[2] * v2[1], v1[2] * v2[0] - v1[0] * v2[2],
             v1[0] * v2[1] - v1[1] * v2[0])  # fmt: skip
    v = [s1 * b + s2 * a + c for a, b, c in zip(v1, v2, cross, strict=True)]
    for name, value in zip(("quat_s", "quat_v1", "quat_v2", "quat_v3"), (s, *v), strict=True):
        out[name] = f"{value:.9f}"
    return out


# -- Perseverance --------------------------------------------------------------------------
def _m2020_img(label: Path, jpeg: Path, out: Path) -> None:
    """Headers (filler) then SignedMSB2 Band/Line/Sample at the label's array offset."""
    from lxml import etree

    ns = {"pds": "http://pds.nasa.gov/pds4/pds/v1"}
    root = etree.parse(str(label)).getroot()
    arr = root.find("pds:File_Area_Observational/pds:Array_3D_Image", ns)
    offset = int(arr.findtext("pds:offset", namespaces=ns))
    dims = [int(e.text) for e in arr.findall("pds:Axis_Array/pds:elements", ns)]
    rgb = np.asarray(Image.open(jpeg).convert("RGB"), dtype=np.int16)
    data = (rgb.transpose(2, 0, 1) * 64).astype(">i2")  # radiance-like counts, never 0
    data = np.maximum(data, 1).astype(">i2")
    assert list(data.shape) == dims, (data.shape, dims)
    header = b"LBLSIZE=32960 (replica ODL3/VICAR header filler)".ljust(offset, b" ")
    out.write_bytes(header + data.tobytes())


def _m2020_archive(root: Path) -> tuple[str, ...]:
    bundle = root / M2020_BUNDLE
    placed = []
    for label in sorted((SAMPLES / "m2020").glob("Z*.xml")):
        sol = int(label.name[4:8])
        rel = f"{M2020_BUNDLE}/data/sol/{sol:05d}/ids/rdr/zcam/{label.name}"
        dest = root / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(label, dest)
        _m2020_img(label, label.with_suffix(".jpg"), dest.with_suffix(".IMG"))
        placed.append(rel)
    inventory = (REAL_ARCHIVE / "mastcamz_inventory_rows.csv").read_bytes()
    (bundle / M2020_INVENTORY).write_bytes(inventory)
    n_rows = inventory.count(b"\n")
    coll = _collection_label(n_rows, len(inventory), Path(M2020_INVENTORY).name)
    (bundle / M2020_COLLECTION).write_bytes(coll)
    places = root / M2020_PLACES
    places.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(SAMPLES / "m2020" / "best_interp.csv", places)
    return tuple(placed)


def _collection_label(rows: int, size: int, name: str) -> bytes:
    """A Product_Collection label with the real example's File_Area_Inventory structure."""
    from lxml import etree

    ns = "http://pds.nasa.gov/pds4/pds/v1"
    tree = etree.parse(str(REAL_ARCHIVE / "pds4_collection_label_example.xml"))
    root = tree.getroot()
    q = {"pds": ns}
    root.find(
        "pds:Identification_Area/pds:logical_identifier", q
    ).text = f"urn:nasa:pds:{M2020_BUNDLE}:data"
    area = root.find("pds:File_Area_Inventory", q)
    area.find("pds:File/pds:file_name", q).text = name
    for tag, value in (("file_size", size), ("records", rows)):
        el = area.find(f"pds:File/pds:{tag}", q)
        if el is not None:
            el.text = str(value)
    inv = area.find("pds:Inventory", q)
    for tag, value in (("records", rows),):
        el = inv.find(f"pds:{tag}", q)
        if el is not None:
            el.text = str(value)
    md5 = area.find("pds:File/pds:md5_checksum", q)
    if md5 is not None:
        md5.getparent().remove(md5)
    return etree.tostring(tree, xml_declaration=True, encoding="UTF-8")


# -- orbital maps --------------------------------------------------------------------------
def _terrain(
    seed: int,
    n: int,
    res_m: float,
    factor: int,
    anchors: list[tuple[float, float, float]],
    origin: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """A synthetic DEM (n x n at res_m, row 0 north, upper left ``origin`` in map metres)
    moved so that it passes through each anchor (x, y, elevation m) by a least-squares plane,
    and its ortho at res_m / factor."""
    rng = np.random.default_rng(seed)
    dem, boulders = make_dem(rng, n, res_m, 0.0)
    x0, y0 = origin
    cols = np.array([(x - x0) / res_m - 0.5 for x, _, _ in anchors])
    rows = np.array([(y0 - y) / res_m - 0.5 for _, y, _ in anchors])
    z_at = dem[
        np.clip(np.round(rows).astype(int), 0, n - 1), np.clip(np.round(cols).astype(int), 0, n - 1)
    ]
    want = np.array([h for _, _, h in anchors])
    dem = dem + float(np.mean(want - z_at))
    ortho = make_ortho(rng, dem, res_m, factor, boulders)
    return dem.astype(np.float32), ortho


def _write(path: Path, driver: str, data: np.ndarray, crs: str, origin: tuple[float, float],
           res: float, nodata: float | None = None) -> None:  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(
        path, "w", driver=driver, width=data.shape[1], height=data.shape[0], count=1,
        dtype=data.dtype.name, crs=crs, transform=from_origin(origin[0], origin[1], res, res),
        nodata=nodata,
    ) as ds:  # fmt: skip
        ds.write(data, 1)


def _crop_origin(
    xs: list[float], ys: list[float], grid: tuple[float, float], res: float
) -> tuple[float, float]:
    """Upper left of a CROP_M square centred on the positions, snapped to the map grid."""
    cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    step = res * 4  # on both the DEM and the 4x finer map grid
    x0 = grid[0] + math.floor((cx - CROP_M / 2 - grid[0]) / step) * step
    y0 = grid[1] - math.floor((grid[1] - (cy + CROP_M / 2)) / step) * step
    return x0, y0


def _msl_maps(root: Path) -> None:
    rows = [r for r in _gale_rows() if (r["site"], r["drive"]) == ("56", "1632")]
    xs, ys = [float(r["easting"]) for r in rows], [float(r["northing"]) for r in rows]
    origin = _crop_origin(xs, ys, (8141036.5, -271512.1), 1.0)
    anchors = [(x, y, float(r["elevation"])) for x, y, r in zip(xs, ys, rows, strict=True)]
    dem, ortho = _terrain(56, CROP_M, 1.0, 2, anchors, origin)
    _write(root / MSL_MAPS / "msl_orbital_dem.img", "VICAR", dem, MSL_PLACES_CRS, origin, 1.0)
    _write(root / MSL_MAPS / "msl_orbital_map.img", "VICAR", ortho, MSL_PLACES_CRS, origin, 0.5)


def _m2020_maps(root: Path) -> None:
    want = {("3", "1950"), ("3", "2430")}
    with open(SAMPLES / "m2020" / "best_interp.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh)
                if r["frame"] == "ROVER" and (r["site"], r["drive"]) in want]  # fmt: skip
    xs, ys = [float(r["easting"]) for r in rows], [float(r["northing"]) for r in rows]
    origin = _crop_origin(xs, ys, M2020_GRID_ORIGIN, 1.0)
    anchors = [(x, y, float(r["elevation"])) for x, y, r in zip(xs, ys, rows, strict=True)]
    dem, ortho = _terrain(2020, CROP_M, 1.0, 4, anchors, origin)
    maps = root / M2020_MAPS
    _write(maps / "m20_orbital_dem.xml", "PDS4", dem, M2020_PLACES_CRS, origin, 1.0)
    _write(maps / "m20_orbital_map.xml", "PDS4", ortho, M2020_PLACES_CRS, origin, 0.25)


# -- the whole replica ---------------------------------------------------------------------
def build_replica(root: Path) -> Replica:
    """Write the replica archive under ``root`` (``msl/`` and ``mars2020/``)."""
    msl, m2020 = root / "msl", root / "mars2020"
    msl_labels = _msl_archive(msl)
    current, pds3 = msl_places_tables(root / "_tables")
    for src, rel in ((current, MSL_PLACES_CURRENT), (pds3, MSL_PLACES_PDS3)):
        (msl / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.move(src, msl / rel)
    shutil.rmtree(root / "_tables")
    _msl_maps(msl)
    m2020_labels = _m2020_archive(m2020)
    _m2020_maps(m2020)
    return Replica(root, msl_labels, m2020_labels)


@functools.lru_cache(maxsize=4)
def shared_replica(base: Path) -> Replica:
    """One replica per test session (under pytest's base temp folder)."""
    return build_replica(Path(base) / "replica-archive")


def _csv_text(rows: list[list[str]]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()
