"""A download is kept only when it is what it claims; tables are revalidated; resumes use If-Range.

Against the loopback server and the fixture archive: HTML and short 200 answers for a PLACES
table, a PDS3 index table and a JPEG image never land under the real name and become a
FetchError (or a failure row), and a rerun completes; a part killed mid-download whose remote
file was replaced by one of the same size comes whole on the rerun; a changed PLACES table is
picked up on the next fetch and an unchanged one costs a 304; a Mastcam-Z-like label without
file_size/md5_checksum gets its image verified by Content-Length and a full decode.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path, PurePosixPath

import numpy as np
import pyarrow.parquet as pq
import pytest
from lxml import etree

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import Cache
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.download import Downloader, FetchPolicy, RemoteFile, Validator, sidecar
from mars_pairs.fetch.products import Product, with_label_facts
from mars_pairs.fetch.run import FAILURES, fetch_places, fetch_products
from support import fetch_archive
from support.fetch_archive import write_config
from support.fetch_server import ArchiveServer

FAST = FetchPolicy(retries=1, backoff_s=0.01, connect_timeout_s=2.0, read_timeout_s=2.0, workers=2)
REPO = Path(__file__).resolve().parents[2]
PDS4 = fetch_archive.PDS4


def _debris(cache: Path) -> list[Path]:
    return [p for p in cache.rglob("*") if p.name.endswith((".part", ".tmp", ".part.meta.json"))]


# -- HTML and short 200s: PLACES, the PDS3 index table, a JPEG --------------------------------
@pytest.mark.parametrize("fault", ["html", "html-as-file", "short"])
def test_places_table_bad_200_is_refused_and_a_rerun_completes(archive, server, tmp_path, fault):
    """A PLACES table cut inside a record is refused (no size is published for it: a cut
    exactly at a record end would look like a shorter table, see validate.py)."""
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    rel = f"msl/{fetch_archive.MSL_PLACES}"
    if fault == "short":
        fault = f"short:{(archive.root / rel).stat().st_size - 20}"  # inside the last record
    server.fault(rel, *[fault] * (cfg.policy.retries + 1))
    with pytest.raises(FetchError, match=r"localized_interp\.csv: failed after 2 attempts") as e:
        fetch_places(cfg)
    reason = {"html": "HTML page", "html-as-file": "HTML page", "short": "no line end"}
    assert re.search(reason[fault.split(":")[0]], str(e.value))
    target = cfg.cache / fetch_archive.MSL_PLACES
    assert not target.exists() and _debris(cfg.cache) == []
    assert fetch_places(cfg).read_bytes() == (archive.root / rel).read_bytes()


@pytest.mark.parametrize("fault", ["html", "short"])
def test_a_cached_places_table_survives_a_bad_revalidation(archive, server, tmp_path, fault):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "m2020"))
    good = fetch_places(cfg).read_bytes()
    rel = f"mars2020/{fetch_archive.M2020_PLACES}"
    server.fault(rel, *[fault] * (cfg.policy.retries + 1))
    with pytest.raises(FetchError):
        fetch_places(cfg)
    assert (cfg.cache / fetch_archive.M2020_PLACES).read_bytes() == good
    assert _debris(cfg.cache) == []


@pytest.mark.parametrize("fault", ["html", "short"])
def test_pds3_index_table_bad_200_is_refused_and_a_rerun_completes(
    archive, server, tmp_path, fault
):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    rel = f"msl/{fetch_archive.MSL_VOLUME}/INDEX/RDRINDEX.TAB"
    server.fault(rel, *[fault] * (cfg.policy.retries + 1))
    why = "HTML" if fault == "html" else r"396 bytes, its label .*RDRINDEX\.LBL says 792"
    report = fetch_products(cfg, dry_run=True, progress=False)
    assert report.selected == 0 and len(report.failures) == 1
    row = report.failures[0]
    assert (row.product_id, row.stage) == (fetch_archive.MSL_VOLUME, "index")
    assert row.url.endswith("RDRINDEX.TAB") and re.search(
        f"failed after 2 attempts: .*{why}", row.message
    )
    assert not (cfg.cache / fetch_archive.MSL_VOLUME / "INDEX" / "RDRINDEX.TAB").exists()
    assert _debris(cfg.cache) == []
    assert fetch_products(cfg, dry_run=True, progress=False).selected == 4


@pytest.mark.parametrize("fault", ["html", "html-as-file", "short"])
def test_jpeg_bad_200_is_a_failure_row_and_a_rerun_completes(archive, server, tmp_path, fault):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    label = archive.msl_labels[0]
    image = label.with_suffix(".jpg").relative_to(archive.root)
    server.fault(str(image), *[fault] * (cfg.policy.retries + 1))
    report = fetch_products(cfg, progress=False)
    assert report.selected == 3 and len(report.failures) == 1
    (row,) = pq.read_table(cfg.cache / FAILURES).to_pylist()
    assert row["stage"] == "image" and row["url"] == f"{server.url}/{image}"
    why = "HTML" if fault.startswith("html") else "truncated"
    assert why in row["message"]
    assert not (cfg.cache / image.relative_to("msl")).exists() and _debris(cfg.cache) == []
    again = fetch_products(cfg, progress=False)
    assert again.selected == 4 and not again.failures
    got = (cfg.cache / image.relative_to("msl")).read_bytes()
    assert got == (archive.root / image).read_bytes()


# -- resume: a kill, a replaced remote file ----------------------------------------------------
def _random(n: int, seed: int) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


def _kill_mid_download(srv: ArchiveServer, rel: str, cache: Path) -> int:
    """Run a fetch of ``rel`` in a child process, SIGKILL it half-way; the part's size."""
    srv.fault(rel, "stall")
    code = (
        "import sys; from pathlib import PurePosixPath as P\n"
        "from mars_pairs.fetch.cache import Cache\n"
        "from mars_pairs.fetch.download import Downloader, FetchPolicy, RemoteFile\n"
        "pol = FetchPolicy(retries=0, read_timeout_s=60, chunk_bytes=4096)\n"
        "Downloader(Cache(sys.argv[1]), pol).fetch(RemoteFile(P(sys.argv[2]), sys.argv[3]))\n"
    )
    part = cache / (rel + ".part")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    args = [sys.executable, "-c", code, str(cache), rel, f"{srv.url}/{rel}"]
    proc = subprocess.Popen(args, env=env, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 30
        while not (part.is_file() and part.stat().st_size > 0):
            assert proc.poll() is None, proc.stderr.read().decode()  # type: ignore[union-attr]
            assert time.monotonic() < deadline, "the download never started"
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    return part.stat().st_size


def test_killed_part_of_a_replaced_file_is_fetched_whole_not_stitched(tmp_path):
    root = tmp_path / "archive"
    rel = "data/big/TABLE.DAT"
    old, new = _random(200_000, 1), _random(200_000, 2)
    (root / "data/big").mkdir(parents=True)
    (root / rel).write_bytes(old)
    cache = tmp_path / "cache"
    with ArchiveServer(root, slow_s=30.0) as srv:
        kept = _kill_mid_download(srv, rel, cache)
        assert 0 < kept < len(old) and not (cache / rel).exists()
        assert Validator.read(sidecar(cache / (rel + ".part")), f"{srv.url}/{rel}") is not None
        srv.replace(rel, new)  # same size, other bytes: a re-release
        srv.reset_log()
        res = Downloader(Cache(cache), FAST).fetch(
            RemoteFile(PurePosixPath(rel), f"{srv.url}/{rel}")
        )
        (req,) = srv.requests_for(rel)
    assert res.path.read_bytes() == new  # whole, not old[:kept] + new[kept:]
    assert req.range == f"bytes={kept}-" and req.if_range and req.status == 200
    assert req.sent == len(new) and res.status == "downloaded"
    assert _debris(cache) == []


def test_an_unchanged_remote_is_resumed_after_a_kill(tmp_path):
    root = tmp_path / "archive"
    rel = "data/big/TABLE.DAT"
    data = _random(200_000, 3)
    (root / "data/big").mkdir(parents=True)
    (root / rel).write_bytes(data)
    cache = tmp_path / "cache"
    with ArchiveServer(root, slow_s=30.0) as srv:
        kept = _kill_mid_download(srv, rel, cache)
        srv.reset_log()
        res = Downloader(Cache(cache), FAST).fetch(
            RemoteFile(PurePosixPath(rel), f"{srv.url}/{rel}")
        )
        (req,) = srv.requests_for(rel)
    assert res.path.read_bytes() == data and res.status == "resumed"
    assert req.status == 206 and req.if_range and req.sent == len(data) - kept


def test_a_server_ignoring_if_range_is_not_stitched(served_raw, tmp_path):
    """A 206 whose ETag is not the part's (a server that ignores If-Range) restarts the part."""
    srv, root = served_raw
    rel = "X.DAT"
    old, new = _random(50_000, 4), _random(50_000, 5)
    (root / rel).write_bytes(old)
    cache = Cache(tmp_path / "c")
    part = cache.path(rel).with_name("X.DAT.part")
    part.parent.mkdir(parents=True)
    part.write_bytes(old[:20_000])
    sidecar(part).write_bytes(Validator(f"{srv.url}/{rel}", '"old-version"').dump(None))
    srv.replace(rel, new)
    srv.ignore_if_range = True
    res = Downloader(cache, FAST).fetch(RemoteFile(PurePosixPath(rel), f"{srv.url}/{rel}"))
    assert res.path.read_bytes() == new
    assert [e.status for e in srv.requests_for(rel)] == [206, 200]


# -- revalidation ------------------------------------------------------------------------------
def test_places_is_revalidated_304_when_unchanged_and_replaced_when_changed(archive, tmp_path):
    root = tmp_path / "archive" / "mars2020"
    rel = fetch_archive.M2020_PLACES
    (root / rel).parent.mkdir(parents=True)
    shutil.copy2(archive.root / "mars2020" / rel, root / rel)
    with ArchiveServer(root.parent) as srv:
        cfg = load_fetch_config(write_config(tmp_path, srv.url, "m2020"))
        url, logged = f"{srv.url}/mars2020/{rel}", f"mars2020/{rel}"
        first = fetch_places(cfg)
        stamp = first.stat().st_mtime_ns
        meta = Validator.read(sidecar(first), url)
        assert meta is not None and meta.etag and meta.size == first.stat().st_size
        assert fetch_places(cfg) == first and first.stat().st_mtime_ns == stamp
        again = srv.requests_for(logged)[1]
        assert again.status == 304 and again.sent == 0
        assert again.if_none_match == meta.etag and again.if_modified_since == meta.last_modified
        text = (root / rel).read_text()
        changed = text.replace("ROVER", "rover", 1)
        assert changed != text and len(changed) == len(text)
        srv.replace(logged, changed.encode())
        assert fetch_places(cfg).read_text() == changed
        third = srv.requests_for(logged)[2]
        assert third.status == 200 and third.if_none_match == meta.etag
        assert Validator.read(sidecar(first), url).etag not in (None, meta.etag)


def test_products_stay_cached_without_a_request(archive, server, tmp_path):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "m2020"))
    fetch_products(cfg, progress=False)
    server.reset_log()
    fetch_products(cfg, progress=False)
    gets = [e for e in server.log if e.method == "GET"]
    assert {e.path.rsplit("/", 1)[1] for e in gets} == {
        "collection_data.xml",
        "collection_data.csv",
    }
    assert all(e.status == 304 for e in gets)
    assert not list(cfg.cache.rglob("*.jpg.meta.json"))  # products carry no validator files


def test_damaged_products_in_the_cache_are_fetched_again(archive, server, tmp_path):
    """An HTML page under a label's name and a JPEG without its end (what an older release
    could keep) are refetched on the next run; the healthy products are not requested."""
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    fetch_products(cfg, progress=False)
    label = archive.msl_labels[0].relative_to(archive.root / "msl")
    image = archive.msl_labels[1].with_suffix(".jpg").relative_to(archive.root / "msl")
    (cfg.cache / label).write_bytes(b"<html><body>Service Unavailable</body></html>")
    whole = (cfg.cache / image).read_bytes()
    (cfg.cache / image).write_bytes(whole[: len(whole) // 2])
    server.reset_log()
    report = fetch_products(cfg, progress=False)
    assert report.selected == 4 and not report.failures and report.downloaded == 2
    fetched = sorted(e.path for e in server.log if e.method == "GET" and e.status == 200)
    assert fetched == sorted([f"/msl/{label}", f"/msl/{image}"])
    assert (cfg.cache / image).read_bytes() == whole
    assert (cfg.cache / label).read_bytes() == archive.msl_labels[0].read_bytes()


def test_a_changed_inventory_is_refetched_and_checked_against_its_collection_label(
    archive, tmp_path
):
    root = tmp_path / "archive"
    bundle = root / "mars2020" / fetch_archive.M2020_BUNDLE
    shutil.copytree(archive.root / "mars2020" / fetch_archive.M2020_BUNDLE, bundle)
    with ArchiveServer(root) as srv:
        cfg = load_fetch_config(write_config(tmp_path, srv.url, "m2020"))
        assert fetch_products(cfg, dry_run=True, progress=False).listed == 4
        inv = "mars2020/" + fetch_archive.M2020_BUNDLE + "/data/collection_data.csv"
        rows = (root / inv).read_text().splitlines(keepends=True)
        srv.replace(inv, "".join(rows[1:]).encode())  # one record fewer, the label unchanged
        with pytest.raises(FetchError, match=r"collection_data\.csv: .*4 records, the collect"):
            fetch_products(cfg, dry_run=True, progress=False)
        assert len((cfg.cache / inv.removeprefix("mars2020/")).read_text().splitlines()) == 5


# -- Mastcam-Z: labels without file_size / md5_checksum ----------------------------------------
def _strip_file_facts(label: Path, out: Path) -> None:
    tree = etree.parse(str(label))
    for name in ("file_size", "md5_checksum"):
        for el in tree.getroot().iter(f"{{{PDS4}}}{name}"):
            el.getparent().remove(el)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(etree.tostring(tree, xml_declaration=True, encoding="UTF-8"))


def _zcam_product(archive, root: Path, srv_url: str) -> tuple[Product, str]:
    src = archive.m2020_labels[0]
    rel = src.relative_to(archive.root)
    _strip_file_facts(src, root / rel)
    shutil.copy2(src.with_suffix(".jpg"), root / rel.with_suffix(".jpg"))
    p = Product("m2020", src.stem, RemoteFile(PurePosixPath(rel), f"{srv_url}/{rel}"))
    return p, str(rel.with_suffix(".jpg"))


@pytest.mark.parametrize("fault", [None, "short", "truncate", "html-as-file"])
def test_zcam_image_without_size_or_md5_is_checked_by_length_and_decode(archive, tmp_path, fault):
    root = tmp_path / "archive"
    with ArchiveServer(root) as srv:
        p, image = _zcam_product(archive, root, srv.url)
        dl = Downloader(Cache(tmp_path / "c"), FAST)
        got = dl.fetch(p.label)
        p = with_label_facts(p, got.path, srv.url)
        assert p.image.size is None and p.image.md5 is None  # as the real labels
        if fault:
            srv.fault(image, *[fault] * (FAST.retries + 1))
            why = {
                "short": "truncated",
                "truncate": "received|IncompleteRead",
                "html-as-file": "HTML",
            }[fault]
            with pytest.raises(FetchError, match=why):
                dl.fetch(replace(p.image, label=got.path))
            assert not (tmp_path / "c" / image).exists()
        res = dl.fetch(replace(p.image, label=got.path))
        assert res.path.read_bytes() == (root / image).read_bytes()


def test_zcam_img_array_is_checked_against_its_label(tmp_path):
    """A PDS4 .IMG without file_size: the label's Array_3D_Image says how many bytes it has."""
    root = tmp_path / "archive"
    rel = "data/sol/00052/ids/rdr/zcam/ZLF_TEST.IMG"
    data = _random(1000 + 3 * 20 * 30 * 2, 6)
    xml = (
        f'<?xml version="1.0"?>\n<Product_Observational xmlns="{PDS4}">'
        "<File_Area_Observational><File><file_name>ZLF_TEST.IMG</file_name></File>"
        '<Header><offset unit="byte">0</offset><object_length unit="byte">1000</object_length>'
        '</Header><Array_3D_Image><offset unit="byte">1000</offset><axes>3</axes>'
        "<Element_Array><data_type>SignedMSB2</data_type></Element_Array>"
        "<Axis_Array><elements>3</elements></Axis_Array><Axis_Array><elements>20</elements>"
        "</Axis_Array><Axis_Array><elements>30</elements></Axis_Array></Array_3D_Image>"
        "</File_Area_Observational></Product_Observational>\n"
    )
    (root / rel).parent.mkdir(parents=True)
    (root / rel).write_bytes(data)
    (root / rel).with_suffix(".xml").write_text(xml)
    with ArchiveServer(root) as srv:
        dl = Downloader(Cache(tmp_path / "c"), FAST)
        lrel = PurePosixPath(rel).with_suffix(".xml")
        label = dl.fetch(RemoteFile(lrel, f"{srv.url}/{lrel}")).path
        remote = RemoteFile(PurePosixPath(rel), f"{srv.url}/{rel}", label=label)
        srv.fault(rel, "short", "short")
        with pytest.raises(FetchError, match=r"2300 bytes, its label .*needs 4600"):
            dl.fetch(remote)
        assert dl.fetch(remote).path.read_bytes() == data


@pytest.fixture()
def served_raw(tmp_path):
    """A server whose ``ignore_if_range`` makes it answer a Range request with 206 always."""
    root = tmp_path / "raw"
    root.mkdir()
    with _IgnoringServer(root) as srv:
        yield srv, root


class _IgnoringServer(ArchiveServer):
    ignore_if_range = False

    def _app(self, environ, start_response):  # type: ignore[no-untyped-def]
        if self.ignore_if_range:
            environ.pop("HTTP_IF_RANGE", None)
        return super()._app(environ, start_response)
