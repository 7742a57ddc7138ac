"""Labels in the fetch path: read by the bounded loaders, once per product and run.

Labels read on fetch worker threads go through the bounded label loader: a pathological PDS3
label (an index label or a product label) is a failure row naming the file within seconds,
never a hang or an unbounded parse (pdr alone takes ~1 min on 10,000 repeated pointers, and
no wall-clock limit runs off the main thread). A product's label is parsed once per run: what
it says of its ``.IMG`` (``Extent``) travels with the image's ``RemoteFile`` to the checks of a
download and of a cached image."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path, PurePosixPath

import pytest

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import Cache
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.download import Downloader, FetchPolicy, RemoteFile
from mars_pairs.fetch.pds3_index import read_index_table
from mars_pairs.fetch.products import Product, pds3_label_facts, with_label_facts
from mars_pairs.fetch.run import fetch_products
from mars_pairs.fetch.validate import Extent, check_file
from mars_pairs.pds import pds3
from mars_pairs.pds import xml as pds_xml
from support import fetch_archive, fetch_server
from support.fetch_archive import write_config
from support.threads import on_a_thread

served = fetch_server.served  # the loopback server fixture
FAST = FetchPolicy(retries=1, backoff_s=0.01, connect_timeout_s=2.0, read_timeout_s=2.0)
PDS4 = fetch_archive.PDS4
BUDGET_S = 20.0
#: what pdr parses quadratically (its index_duplicate_pointers); the pre-scan refuses it
PATHOLOGICAL = "PDS_VERSION_ID = PDS3\r\n" + "^A = 1\r\n" * 10_000 + "END\r\n"
VOLUME = fetch_archive.MSL_VOLUME
GOOD, BAD = "1429MR0070670010702567E01_DRCL", "1429MR0070680020702583E01_DRCL"
SURFACE = "DATA/RDR/SURFACE/1429/"


def within_budget(fn, *args):
    """``fn(*args)``'s result (or the exception it raised) on a worker thread, within
    BUDGET_S (``support.threads.on_a_thread``)."""
    return on_a_thread(fn, *args, budget_s=BUDGET_S)[1]


def _product_label(product_id: str) -> str:
    """A small PDS3 product label whose ``^IMAGE`` is a 10 x 100 byte FIXED_LENGTH .IMG."""
    return (
        "PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = 100\r\n"
        f'FILE_RECORDS = 10\r\n^IMAGE = "{product_id}.IMG"\r\nPRODUCT_ID = "{product_id}"\r\n'
        "ROVER_MOTION_COUNTER_NAME = (SITE, DRIVE)\r\nROVER_MOTION_COUNTER = (56, 1632)\r\n"
        "OBJECT = IMAGE\r\n  LINES = 10\r\n  LINE_SAMPLES = 100\r\n  SAMPLE_BITS = 8\r\n"
        "  BANDS = 1\r\nEND_OBJECT = IMAGE\r\nEND\r\n"
    )


def _volume(root: Path, products: tuple[str, ...] = (GOOD, BAD)) -> Path:
    """``msl/<VOLUME>`` with an index of ``products``: GOOD (label + .IMG), BAD (a
    pathological label)."""
    volume = root / "msl" / VOLUME
    data = volume / SURFACE
    data.mkdir(parents=True)
    rows = []
    for pid in products:
        text = _product_label(pid) if pid == GOOD else PATHOLOGICAL
        (data / f"{pid}.LBL").write_text(text)
        rows.append({"VOLUME_ID": VOLUME, "PATH_NAME": SURFACE, "FILE_NAME": f"{pid}.LBL",
                     "PRODUCT_ID": pid, "INSTRUMENT_ID": "MAST_RIGHT", "PLANET_DAY_NUMBER": 1429,
                     "IMAGE_ID": pid[:20]})  # fmt: skip
    (data / f"{GOOD}.IMG").write_bytes(bytes(1000))
    fetch_archive.write_pds3_index(volume, rows)
    return volume


def test_a_pathological_product_label_is_one_failure_row_naming_it(served, tmp_path):
    srv, root = served
    _volume(root)
    cfg = load_fetch_config(write_config(tmp_path, srv.url, "msl"))
    report = within_budget(lambda: fetch_products(cfg, progress=False))
    assert not isinstance(report, BaseException), report
    (failure,) = report.failures
    assert failure.product_id == BAD and failure.stage == "label"
    assert failure.url == f"{srv.url}/msl/{VOLUME}/{SURFACE}{BAD}.LBL"
    assert "^A: repeated more than 64 times" in failure.message
    assert [p.product_id for p in report.products] == [GOOD]  # the other product goes on


def test_a_pathological_index_label_is_one_failure_row_for_its_volume(served, tmp_path):
    srv, root = served
    volume = _volume(root)
    label = volume / "INDEX" / "RDRINDEX.LBL"
    text = label.read_bytes()
    assert text.endswith(b"\r\nEND\r\n")
    label.write_bytes(text[:-5] + b"^A = 1\r\n" * 10_000 + b"END\r\n")
    cfg = load_fetch_config(write_config(tmp_path, srv.url, "msl"))
    report = within_budget(lambda: fetch_products(cfg, progress=False))
    assert not isinstance(report, BaseException), report
    (failure,) = report.failures
    assert (failure.product_id, failure.stage) == (VOLUME, "index")
    assert failure.url.endswith(f"{VOLUME}/INDEX/RDRINDEX.TAB")
    assert "RDRINDEX.LBL is unreadable: ^A: repeated more than 64 times" in failure.message
    assert report.products == []


@pytest.mark.parametrize("reader", ["label facts", "index table", "table check", "image check"])
def test_each_fetch_label_reader_refuses_a_pathological_label_naming_it(tmp_path, reader):
    label = tmp_path / "BAD.LBL"
    label.write_text(PATHOLOGICAL)
    data = tmp_path / "BAD.IMG"
    data.write_bytes(bytes(100))
    calls = {
        "label facts": lambda: pds3_label_facts(label),
        "index table": lambda: read_index_table(label),
        "table check": lambda: check_file(data, "pds3_table", label=label, where="U"),
        "image check": lambda: check_file(data, "img", label=label, where="U"),
    }
    error = within_budget(calls[reader])
    assert isinstance(error, FetchError), error
    assert "^A: repeated more than 64 times" in error.reason
    assert str(label) in str(error)


def test_a_warm_rerun_parses_a_product_label_once(served, tmp_path, monkeypatch):
    """Once for its facts; the checks of its .IMG (downloaded or cached) use the extent."""
    srv, root = served
    _volume(root, (GOOD,))
    parses: Counter[str] = Counter()
    real = pds3.load_label

    def counting(data: bytes, path: Path, longer: bool = False):  # type: ignore[no-untyped-def]
        parses[Path(path).name] += 1
        return real(data, path, longer)

    monkeypatch.setattr(pds3, "load_label", counting)
    cfg = load_fetch_config(write_config(tmp_path, srv.url, "msl"))
    first = fetch_products(cfg, progress=False)
    assert (first.downloaded, first.cached, first.failures) == (2, 0, [])
    assert parses[f"{GOOD}.LBL"] == 1
    parses.clear()
    again = fetch_products(cfg, progress=False)
    assert (again.downloaded, again.cached, again.failures) == (0, 2, [])
    assert parses[f"{GOOD}.LBL"] == 1
    # the carried extent still guards the cached image: a cut one is fetched again, whole
    image = cfg.cache / VOLUME / SURFACE / f"{GOOD}.IMG"
    image.write_bytes(bytes(500))
    parses.clear()
    third = fetch_products(cfg, progress=False)
    assert (third.downloaded, third.cached, third.failures) == (1, 1, [])
    assert image.stat().st_size == 1000 and parses[f"{GOOD}.LBL"] == 1


def test_a_pds4_image_is_checked_without_parsing_its_label_again(served, tmp_path, monkeypatch):
    srv, root = served
    rel = PurePosixPath("data/sol/00052/ids/rdr/zcam/ZLF_TEST.IMG")
    lrel = rel.with_suffix(".xml")
    (root / rel).parent.mkdir(parents=True)
    (root / rel).write_bytes(bytes(1000 + 3 * 20 * 30 * 2))
    (root / lrel).write_text(
        f'<?xml version="1.0"?>\n<Product_Observational xmlns="{PDS4}">'
        "<File_Area_Observational><File><file_name>ZLF_TEST.IMG</file_name></File>"
        '<Array_3D_Image><offset unit="byte">1000</offset><axes>3</axes>'
        "<Element_Array><data_type>SignedMSB2</data_type></Element_Array>"
        "<Axis_Array><elements>3</elements></Axis_Array><Axis_Array><elements>20</elements>"
        "</Axis_Array><Axis_Array><elements>30</elements></Axis_Array></Array_3D_Image>"
        "</File_Area_Observational></Product_Observational>\n"
    )
    dl = Downloader(Cache(tmp_path / "c"), FAST)
    label = dl.fetch(RemoteFile(lrel, f"{srv.url}/{lrel}")).path
    p = Product("m2020", "ZLF_TEST", RemoteFile(lrel, f"{srv.url}/{lrel}"))
    image = replace(with_label_facts(p, label, srv.url).image, label=label)
    assert image.extent == Extent(4600, "4600 (Array_3D_Image at byte 1000)")
    parses = []
    real = pds_xml.load_xml
    monkeypatch.setattr(
        pds_xml, "load_xml", lambda data, path: parses.append(path) or real(data, path)
    )
    assert dl.fetch(image).status == "downloaded"
    assert dl.fetch(image).status == "cached"
    assert parses == []
    (tmp_path / "c" / rel).write_bytes(bytes(2300))  # cut: the carried extent refuses it
    assert dl.fetch(image).status == "downloaded" and parses == []
