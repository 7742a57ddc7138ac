"""validate.check_file: what a file of each kind must look like, on real and generated files.

Real files come from ../shared/pds-samples and ../shared/real-archive (skipped when absent).
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from PIL import Image
from rasterio.transform import from_origin

from mars_pairs.fetch.validate import (
    KINDS,
    ContentError,
    check_content_type,
    check_file,
    kind_of,
)
from support import fetch_archive

SHARED = Path(__file__).resolve().parents[3] / "shared"
if not SHARED.is_dir():
    SHARED = Path("/work/shared")
SAMPLES, REAL = SHARED / "pds-samples", SHARED / "real-archive"
MSL_LABEL = SAMPLES / "msl" / "1429MR0070670010702567E01_DRCL.LBL"
ZCAM = SAMPLES / "m2020" / "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
HTML = b"<!DOCTYPE html>\n<html><body><h1>502 Bad Gateway</h1></body></html>\n"


def _real(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"{path} is absent (the real archive samples live in ../shared)")
    return path


def _cut(src: Path, dst: Path, keep: int | None = None) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2 if keep is None else keep])
    return dst


def _png(w: int = 40, h: int = 30) -> bytes:
    buf = io.BytesIO()
    pixels = np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(buf, format="PNG")
    return buf.getvalue()


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "html"])
def test_an_html_page_is_refused_for_every_kind(tmp_path, kind):
    path = tmp_path / "f"
    path.write_bytes(HTML)
    with pytest.raises(ContentError, match=f"an HTML page, not {kind}"):
        check_file(path, kind, where="http://x/f")
    check_file(path, "html")


def test_html_content_type_is_refused_except_for_html():
    with pytest.raises(ContentError, match=r"HTML page \(text/html\), not jpeg"):
        check_content_type("jpeg", "text/html; charset=utf-8", "http://x/a.jpg")
    for ok in ("text/csv", "application/octet-stream", None, "image/jpeg"):
        check_content_type("places", ok, "u")
    check_content_type("html", "text/html", "u")


def test_kinds_by_name():
    assert [kind_of(n) for n in ("a.LBL", "b.xml", "c.TAB", "d.jpg", "e.IMG", "f.tif", "g")] == [
        "pds3_label",
        "pds4_label",
        "pds3_table",
        "jpeg",
        "img",
        "geotiff",
        "data",
    ]


def test_pds3_label_whole_cut_and_non_ascii(tmp_path):
    label = _real(MSL_LABEL)
    check_file(label, "pds3_label")
    with pytest.raises(ContentError, match="no END line"):
        check_file(_cut(label, tmp_path / "cut.LBL"), "pds3_label")
    bad = tmp_path / "bad.LBL"
    bad.write_bytes(label.read_bytes().replace(b"PDS3", "PDS\u00e9".encode(), 1))
    with pytest.raises(ContentError, match="non-ASCII byte 0xc3"):
        check_file(bad, "pds3_label")
    odl = tmp_path / "odl.LBL"
    odl.write_bytes(b"OBJECT = TABLE\r\n  ROWS = 1\r\nEND_OBJECT = TABLE\r\nEND\r\n")
    check_file(odl, "pds3_label")  # ODL without PDS_VERSION_ID
    odl.write_bytes(b"OBJECT = TABLE\r\n  ROWS = 1\r\nEND_OBJECT = TABLE\r\n")
    with pytest.raises(ContentError, match="no END line"):
        check_file(odl, "pds3_label")


def test_pds4_label_whole_cut_doctype_and_foreign_root(tmp_path):
    label = _real(ZCAM)
    check_file(label, "pds4_label")
    with pytest.raises(ContentError, match="not a readable PDS4 label"):
        check_file(_cut(label, tmp_path / "cut.xml"), "pds4_label")
    evil = tmp_path / "evil.xml"
    evil.write_bytes(
        b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY e "boom">]>'
        b'<Product_Observational xmlns="http://pds.nasa.gov/pds4/pds/v1">&e;'
        b"</Product_Observational>"
    )
    with pytest.raises(ContentError, match="DOCTYPE"):
        check_file(evil, "pds4_label")
    other = tmp_path / "other.xml"
    other.write_bytes(b'<Ingest_LDD xmlns="http://pds.nasa.gov/pds4/pds/v1"/>')
    with pytest.raises(ContentError, match="root element is Ingest_LDD"):
        check_file(other, "pds4_label")


def test_places_real_tables_pass_and_damaged_ones_do_not(tmp_path):
    for real in (SAMPLES / "m2020" / "best_interp.csv", REAL / "msl_localized_interp_head.csv"):
        check_file(_real(real), "places")
    best = (SAMPLES / "m2020" / "best_interp.csv").read_bytes()
    upper = tmp_path / "upper.csv"  # the PDS3-era tables write their header in upper case
    head, rest = best.split(b"\n", 1)
    upper.write_bytes(head.upper() + b"\n" + rest)
    check_file(upper, "places")
    mid = tmp_path / "mid.csv"
    mid.write_bytes(best[: best.index(b"\n", 5000) + 40])
    with pytest.raises(ContentError, match="no line end"):
        check_file(mid, "places")
    short_row = tmp_path / "row.csv"
    short_row.write_bytes(best[: best.index(b"\n", 5000) + 40] + b"\n")
    with pytest.raises(ContentError, match=r"line \d+: \d+ fields, the header has 28"):
        check_file(short_row, "places")
    no_col = tmp_path / "nocol.csv"
    no_col.write_bytes(best.replace(b"easting", b"eastin", 1))
    with pytest.raises(ContentError, match="header lacks easting"):
        check_file(no_col, "places")


def test_inventory_against_its_collection_label(tmp_path):
    label = _real(REAL / "pds4_collection_label_example.xml")
    inv = _real(REAL / "pds4_collection_inventory_example.csv")
    check_file(inv, "inventory", label=label)  # 55 records, as the label says
    check_file(_real(REAL / "mastcamz_inventory_rows.csv"), "inventory")
    fewer = tmp_path / "fewer.csv"
    fewer.write_bytes(b"".join(inv.read_bytes().splitlines(keepends=True)[:-1]))
    with pytest.raises(ContentError, match=r"54 records, the collection label .* says 55"):
        check_file(fewer, "inventory", label=label)
    odd = tmp_path / "odd.csv"
    odd.write_bytes(b"X,urn:nasa:pds:a::1.0\r\n")
    with pytest.raises(ContentError, match="record 1: expected 'P,<lidvid>'"):
        check_file(odd, "inventory")


def test_pds3_table_is_its_labels_rows_times_row_bytes(tmp_path):
    rows = [
        {"VOLUME_ID": "V", "PATH_NAME": "DATA/", "FILE_NAME": f"X{i}.LBL", "PRODUCT_ID": f"X{i}",
         "INSTRUMENT_ID": "MAST_LEFT", "PLANET_DAY_NUMBER": i, "IMAGE_ID": "X"}
        for i in range(3)
    ]  # fmt: skip
    fetch_archive.write_pds3_index(tmp_path / "VOL", rows)
    lbl, tab = tmp_path / "VOL/INDEX/RDRINDEX.LBL", tmp_path / "VOL/INDEX/RDRINDEX.TAB"
    check_file(tab, "pds3_table", label=lbl)
    part = tab.with_name("RDRINDEX.TAB.part")  # checked before the rename, by the archive name
    _cut(tab, part, tab.stat().st_size - 1)
    with pytest.raises(
        ContentError, match=r"\d+ bytes, its label .* says \d+ \(INDEX_TABLE: 3 ROWS"
    ):
        check_file(part, "pds3_table", label=lbl)


def test_jpeg_and_png_decode_in_full(tmp_path):
    jpg = _real(SAMPLES / "msl" / "1429MR0070670010702567E01_DRCL.jpg")
    check_file(jpg, "jpeg")
    with pytest.raises(ContentError, match=r"truncated|end marker"):
        check_file(_cut(jpg, tmp_path / "cut.jpg"), "jpeg")
    with pytest.raises(ContentError, match=r"truncated|end marker"):
        check_file(_cut(jpg, tmp_path / "end.jpg", jpg.stat().st_size - 2), "jpeg")
    png = tmp_path / "a.png"
    png.write_bytes(_png())
    check_file(png, "png")
    with pytest.raises(ContentError, match="not a JPEG"):
        check_file(png, "jpeg")
    with pytest.raises(ContentError):
        check_file(_cut(png, tmp_path / "cut.png"), "png")


def test_img_size_from_real_labels(tmp_path):
    """Sizes a real label gives its .IMG: PDS3 FILE_RECORDS x RECORD_BYTES (1339 x 3588),
    PDS4 Mastcam-Z headers + Array_3D_Image (52736 + 3 x 1200 x 1648 x 2 bytes)."""
    for label, size in (
        (_real(MSL_LABEL), 1339 * 3588),
        (_real(ZCAM), 52736 + 3 * 1200 * 1648 * 2),
    ):
        lbl = tmp_path / label.name
        shutil.copy2(label, lbl)
        img = lbl.with_suffix(".IMG.part")
        with open(img, "wb") as fh:
            fh.truncate(size)  # sparse: only the size matters here
        check_file(img, "img", label=lbl)
        with open(img, "r+b") as fh:
            fh.truncate(size - 1)
        with pytest.raises(ContentError, match=f"{size - 1} bytes, its label"):
            check_file(img, "img", label=lbl)
    # the PDS3 size is exact: one byte more is refused too
    img = (tmp_path / MSL_LABEL.name).with_suffix(".IMG.part")
    with open(img, "r+b") as fh:
        fh.truncate(1339 * 3588 + 1)
    with pytest.raises(ContentError, match="says exactly 4804332"):
        check_file(img, "img", label=tmp_path / MSL_LABEL.name)


def test_geotiff_reads_every_block(tmp_path):
    path = tmp_path / "dem.tif"
    data = np.arange(64 * 64, dtype=np.float32).reshape(64, 64)
    prof = {"driver": "GTiff", "width": 64, "height": 64, "count": 1, "dtype": "float32",
            "transform": from_origin(0, 64, 1, 1), "tiled": True, "blockxsize": 16,
            "blockysize": 16, "compress": "deflate"}  # fmt: skip
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(data, 1)
    check_file(path, "geotiff")
    with pytest.raises(ContentError, match="not a readable GeoTIFF"):
        check_file(_cut(path, tmp_path / "cut.tif"), "geotiff")


def test_an_inventory_whose_label_names_an_unknown_delimiter_is_refused(tmp_path):
    """The check reads the delimiter as the listing does (``validate.delimiter_of``):
    a name that is not a PDS4 delimiter is refused, not read as a comma."""
    label = tmp_path / "collection.xml"
    label.write_text(
        '<?xml version="1.0"?>\n<Product_Collection xmlns="http://pds.nasa.gov/pds4/pds/v1">'
        "<File_Area_Inventory><File><file_name>inv.csv</file_name></File><Inventory>"
        "<records>1</records><field_delimiter>Colon</field_delimiter></Inventory>"
        "</File_Area_Inventory></Product_Collection>\n"
    )
    inv = tmp_path / "inv.csv"
    inv.write_bytes(b"P,urn:nasa:pds:a:b:c::1.0\r\n")
    with pytest.raises(
        ContentError, match=r"collection\.xml\): .*field_delimiter: unknown 'Colon'"
    ):
        check_file(inv, "inventory", label=label)
