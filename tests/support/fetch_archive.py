"""A fixture archive in the real layouts, built from the synthetic missions.

msl/MSLMST_0001/INDEX/RDRINDEX.LBL + RDRINDEX.TAB      PDS3 index (pdr reads it)
msl/MSLMST_0001/DATA/RDR/SURFACE/<sol>/<product>.LBL + .jpg
msl/MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv
mars2020/mars2020_mastcamz_ops_calibrated/data/collection_data.xml + collection_data.csv
mars2020/mars2020_mastcamz_ops_calibrated/data/sol/<sol>/ids/rdr/zcam/<product>.xml + .jpg
    (labels carry file_size and md5_checksum of their image, as PDS4 File does)
mars2020/mars2020_rover_places/data_localizations/best_interp.csv
orbital/<mission>/{dem,ortho}_{striped,cog}.tif     the DEM/ortho as striped GeoTIFF and COG
orbital/m2020/dem_eqc0_cog.tif                      the DEM in eqc lat_ts=0 (USGS Jezero CRS)
"""

from __future__ import annotations

import functools
import hashlib
import shutil
from dataclasses import dataclass
from pathlib import Path

import rasterio
import rasterio.shutil
import yaml
from lxml import etree
from rasterio.warp import Resampling, calculate_default_transform, reproject

from mars_pairs.pds import read_observation
from mars_pairs.synth import generate_mission

MSL_VOLUME = "MSLMST_0001"
M2020_BUNDLE = "mars2020_mastcamz_ops_calibrated"
MSL_PLACES = "MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv"
M2020_PLACES = "mars2020_rover_places/data_localizations/best_interp.csv"
LABEL_TEMPLATE = "data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml"
EQC0 = "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"
PDS4 = "http://pds.nasa.gov/pds4/pds/v1"

# (name, data type, width): the MSL index columns; tests reorder them
MSL_COLUMNS = (
    ("VOLUME_ID", "CHARACTER", 11),
    ("PATH_NAME", "CHARACTER", 40),
    ("FILE_NAME", "CHARACTER", 40),
    ("PRODUCT_ID", "CHARACTER", 40),
    ("INSTRUMENT_ID", "CHARACTER", 12),
    ("PLANET_DAY_NUMBER", "ASCII_INTEGER", 5),
    ("IMAGE_ID", "CHARACTER", 30),
)


@dataclass(frozen=True)
class Archive:
    root: Path
    msl_labels: tuple[Path, ...]  # archive files (labels) of the MSL volume
    m2020_labels: tuple[Path, ...]


def write_pds3_index(
    volume_dir: Path, rows: list[dict[str, object]], columns=MSL_COLUMNS, name: str = "RDRINDEX"
) -> None:
    """``INDEX/<name>.LBL`` + ``.TAB``: a fixed-width ASCII table, quoted strings, CRLF rows."""
    starts, cells, pos = [], [], 1
    for i, (_, dtype, width) in enumerate(columns):
        quote = dtype == "CHARACTER"
        starts.append(pos + (1 if quote else 0))
        pos += width + (2 if quote else 0) + (1 if i < len(columns) - 1 else 0)
    row_bytes = pos - 1 + 2
    for row in rows:
        parts = []
        for col, dtype, width in columns:
            value = str(row[col])
            if len(value) > width:
                raise ValueError(f"{col}: {value!r} wider than {width}")
            parts.append(f'"{value:<{width}}"' if dtype == "CHARACTER" else f"{value:>{width}}")
        line = ",".join(parts) + "\r\n"
        assert len(line) == row_bytes
        cells.append(line)
    index = volume_dir / "INDEX"
    index.mkdir(parents=True, exist_ok=True)
    (index / f"{name}.TAB").write_bytes("".join(cells).encode("ascii"))
    objs = []
    for (col, dtype, width), start in zip(columns, starts, strict=True):
        fmt = f"A{width}" if dtype == "CHARACTER" else f"I{width}"
        objs.append(
            f"  OBJECT = COLUMN\r\n    NAME = {col}\r\n    DATA_TYPE = {dtype}\r\n"
            f'    START_BYTE = {start}\r\n    BYTES = {width}\r\n    FORMAT = "{fmt}"\r\n'
            f'    DESCRIPTION = "{col}"\r\n  END_OBJECT = COLUMN\r\n'
        )
    label = (
        "PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\n"
        f"RECORD_BYTES = {row_bytes}\r\nFILE_RECORDS = {len(rows)}\r\n"
        f'^INDEX_TABLE = "{name}.TAB"\r\nVOLUME_ID = "{volume_dir.name}"\r\n'
        "OBJECT = INDEX_TABLE\r\n  INTERCHANGE_FORMAT = ASCII\r\n"
        f"  ROWS = {len(rows)}\r\n  COLUMNS = {len(columns)}\r\n  ROW_BYTES = {row_bytes}\r\n"
        "  INDEX_TYPE = SINGLE\r\n" + "".join(objs) + "END_OBJECT = INDEX_TABLE\r\nEND\r\n"
    )
    (index / f"{name}.LBL").write_bytes(label.encode("ascii"))


def _msl(src: Path, root: Path, columns=MSL_COLUMNS) -> tuple[Path, ...]:
    volume = root / "msl" / MSL_VOLUME
    rows, labels = [], []
    for label in sorted((src / "labels").glob("*.LBL")):
        obs = read_observation(label)
        path_name = f"DATA/RDR/SURFACE/{obs.sol:04d}/"
        dest = volume / path_name
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(label, dest / label.name)
        shutil.copy2(label.with_suffix(".jpg"), dest / label.with_suffix(".jpg").name)
        labels.append(dest / label.name)
        rows.append({
            "VOLUME_ID": MSL_VOLUME, "PATH_NAME": path_name, "FILE_NAME": label.name,
            "PRODUCT_ID": obs.product_id, "INSTRUMENT_ID": obs.instrument,
            "PLANET_DAY_NUMBER": obs.sol, "IMAGE_ID": obs.product_id.split("_")[0],
        })  # fmt: skip
    write_pds3_index(volume, rows, columns)
    places = root / "msl" / MSL_PLACES
    places.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(next((src / "places").glob("*.csv")), places)
    return tuple(labels)


def _with_file_facts(label: Path, image: Path) -> bytes:
    """The PDS4 label with file_size and md5_checksum of its image in File (schema order)."""
    tree = etree.parse(str(label))
    file_el = tree.getroot().find(f"{{{PDS4}}}File_Area_Observational/{{{PDS4}}}File")
    name = file_el.find(f"{{{PDS4}}}file_name")
    size = etree.Element(f"{{{PDS4}}}file_size", unit="byte")
    size.text = str(image.stat().st_size)
    md5 = etree.Element(f"{{{PDS4}}}md5_checksum")
    md5.text = hashlib.md5(image.read_bytes()).hexdigest()
    anchor = file_el.find(f"{{{PDS4}}}creation_date_time")
    anchor = name if anchor is None else anchor
    anchor.addnext(size)
    size.addnext(md5)
    return etree.tostring(tree, xml_declaration=True, encoding="UTF-8")


def inventory_row(product_id: str, status: str = "P") -> str:
    """The real form: the LID ends with the id in lower case without its 2-character version,
    which the VID gives (``..._110085J03`` -> ``..._110085j::3.0``); CRLF-terminated."""
    lid = f"urn:nasa:pds:{M2020_BUNDLE}:data:{product_id[:-2].lower()}"
    return f"{status},{lid}::{int(product_id[-2:])}.0\r\n"


def _m2020(src: Path, root: Path) -> tuple[Path, ...]:
    bundle = root / "mars2020" / M2020_BUNDLE
    rows, labels = [], []
    for label in sorted((src / "labels").glob("*.xml")):
        obs = read_observation(label)
        dest = bundle / LABEL_TEMPLATE.format(sol=obs.sol, product_id=obs.product_id)
        dest.parent.mkdir(parents=True, exist_ok=True)
        image = label.with_suffix(".jpg")
        shutil.copy2(image, dest.with_suffix(".jpg"))
        dest.write_bytes(_with_file_facts(label, image))
        labels.append(dest)
        rows.append(inventory_row(obs.product_id))
    rows.append("S,urn:nasa:pds:mars2020_mission:context:something::1.0\r\n")
    data = bundle / "data"
    (data / "collection_data.csv").write_text("".join(rows))
    (data / "collection_data.xml").write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n<Product_Collection xmlns="{PDS4}">\n'
        "  <File_Area_Inventory>\n    <File><file_name>collection_data.csv</file_name></File>\n"
        '    <Inventory><offset unit="byte">0</offset><parsing_standard_id>PDS DSV 1'
        "</parsing_standard_id><records>%d</records><record_delimiter>Carriage-Return "
        "Line-Feed</record_delimiter><field_delimiter>Comma</field_delimiter>"
        "<reference_type>inventory_has_member_product</reference_type></Inventory>\n"
        "  </File_Area_Inventory>\n</Product_Collection>\n" % len(rows)
    )
    places = root / "mars2020" / M2020_PLACES
    places.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(next((src / "places").glob("*.csv")), places)
    return tuple(labels)


def _rasters(src: Path, out: Path, eqc0: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name in ("dem", "ortho"):
        with rasterio.open(src / "orbital" / f"{name}.tif") as ds:
            rasterio.shutil.copy(ds, out / f"{name}_striped.tif", driver="GTiff",
                                 TILED="NO", COMPRESS="DEFLATE", BLOCKYSIZE=16)  # fmt: skip
            rasterio.shutil.copy(ds, out / f"{name}_cog.tif", driver="COG",
                                 COMPRESS="DEFLATE", BLOCKSIZE=256)  # fmt: skip
    if eqc0:
        with rasterio.open(src / "orbital" / "dem.tif") as ds:
            tr, w, h = calculate_default_transform(ds.crs, EQC0, ds.width, ds.height, *ds.bounds)
            prof = ds.profile | {"crs": EQC0, "transform": tr, "width": w, "height": h}
            tmp = out / "dem_eqc0.tif"
            with rasterio.open(tmp, "w", **prof) as dst:
                reproject(
                    rasterio.band(ds, 1), rasterio.band(dst, 1), resampling=Resampling.nearest
                )
            with rasterio.open(tmp) as ds2:
                rasterio.shutil.copy(
                    ds2, out / "dem_eqc0_cog.tif", driver="COG", COMPRESS="DEFLATE"
                )
            tmp.unlink()


def build_archive(msl_src: Path, m2020_src: Path, root: Path) -> Archive:
    """Lay the two synthetic missions out as the real archives do, under ``root``."""
    msl = _msl(msl_src, root)
    m2020 = _m2020(m2020_src, root)
    _rasters(msl_src, root / "orbital" / "msl", eqc0=False)
    _rasters(m2020_src, root / "orbital" / "m2020", eqc0=True)
    return Archive(root, msl, m2020)


@functools.cache
def shared_archive(base: Path) -> Archive:
    """Both synthetic missions (2 stops x 2 images each) as archives, built once per run."""
    src = base / "fetch-mission"
    generate_mission(src, mission="both", stops=2, images_per_stop=2, size="small")
    return build_archive(src / "msl", src / "m2020", base / "fetch-archive")


def write_config(tmp: Path, url: str, mission: str, **products) -> Path:
    """A build config whose fetch section points at the loopback archive."""
    if mission == "msl":
        prod = {"mission": "msl", "archive": f"{url}/msl", "volumes": ["MSLMST_0001"]}
        places = {"archive": f"{url}/msl", "path": MSL_PLACES}
    else:
        prod = {
            "mission": "m2020",
            "archive": f"{url}/mars2020",
            "bundle": M2020_BUNDLE,
            "label_path": LABEL_TEMPLATE,
        }
        places = {"archive": f"{url}/mars2020", "path": M2020_PLACES}
    prod.update(products)
    doc = {
        "fetch": {"cache": "cache", "retries": 1, "backoff_s": 0.01, "timeout_s": 0.5,
                  "workers": 2, "products": prod, "places": places},
        "geometry": {"radius": 200},
    }  # fmt: skip
    path = tmp / f"{mission}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path
