"""Index-driven product fetches from the fixture archive over a real loopback server."""

from __future__ import annotations

import hashlib
import shutil

import pyarrow.parquet as pq
import pytest
import yaml

from mars_pairs.errors import ConfigError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.products import ProductFilter
from mars_pairs.fetch.run import FAILURES, fetch_products
from mars_pairs.pds import read_observation
from support import fetch_archive
from support.fetch_archive import write_config
from support.fetch_server import ArchiveServer

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s


def _gets(srv: ArchiveServer, suffix: str) -> list[str]:
    return [e.path for e in srv.log if e.method == "GET" and e.path.endswith(suffix)]


def test_msl_products_from_the_pds3_index_mirror_the_archive(archive, server, tmp_path):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    report = fetch_products(cfg, progress=False)
    assert report.selected == 4 and not report.failures
    for label in archive.msl_labels:
        rel = label.relative_to(archive.root / "msl")
        assert (cfg.cache / rel).read_bytes() == label.read_bytes()
        jpg = rel.with_suffix(".jpg")
        assert (cfg.cache / jpg).read_bytes() == label.with_suffix(".jpg").read_bytes()
        # the product fields come from the index/label, and agree with the label
        p = next(p for p in report.products if str(p.label.rel) == str(rel))
        obs = read_observation(label)
        assert (p.sol, p.instrument, p.product_type) == (obs.sol, obs.instrument, "DRCL")
        assert (p.site, p.drive) == (obs.rmc.site, obs.rmc.drive)
    server.reset_log()
    again = fetch_products(cfg, progress=False)
    assert again.downloaded == 0 and again.selected == 4
    # a rerun fetches no product; the index files (mutable tables) are revalidated: 304
    gets = [e for e in server.log if e.method == "GET"]
    assert sorted(e.path.rsplit("/", 1)[1] for e in gets) == ["RDRINDEX.LBL", "RDRINDEX.TAB"]
    assert all(e.status == 304 and e.if_none_match and e.sent == 0 for e in gets)


def test_index_columns_are_read_by_name_not_position(archive, server, tmp_path):
    """A second volume whose index lists the same columns in another order and width."""
    vol2 = archive.root / "msl" / "MSLMST_0002"
    if not vol2.exists():
        shutil.copytree(archive.root / "msl" / fetch_archive.MSL_VOLUME / "DATA", vol2 / "DATA")
        import pdr

        rows = pdr.read(str(archive.root / "msl/MSLMST_0001/INDEX/RDRINDEX.LBL"))["INDEX_TABLE"]
        records = rows.to_dict("records")
        cols = list(reversed(fetch_archive.MSL_COLUMNS))
        cols = [(n, t, w + 3) for n, t, w in cols]
        fetch_archive.write_pds3_index(vol2, records, cols)
    one = fetch_products(
        load_fetch_config(write_config(tmp_path, server.url, "msl")), dry_run=True, progress=False
    )
    two = fetch_products(
        load_fetch_config(
            write_config(tmp_path / "..", server.url, "msl", volumes=["MSLMST_0002"])
        ),
        dry_run=True,
        progress=False,
    )
    key = lambda r: sorted((p.product_id, p.sol, p.instrument, p.site) for p in r.products)  # noqa: E731
    assert key(one) == key(two) and len(key(one)) == 4


@pytest.mark.parametrize(
    ("filters", "count"),
    [
        (ProductFilter(sols=(1429, 1429)), 2),
        (ProductFilter(instruments=("MAST_LEFT",)), 2),
        (ProductFilter(product_types=("DRCX",)), 0),
        (ProductFilter(sols=(1430, 1430), instruments=("MAST_RIGHT",)), 1),
    ],
)
def test_msl_filters(archive, server, tmp_path, filters, count):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    report = fetch_products(cfg, filters=filters, dry_run=True, progress=False)
    assert report.selected == count


def test_site_drive_filter_reads_the_labels_when_the_index_lacks_them(archive, server, tmp_path):
    obs = read_observation(archive.msl_labels[0])
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl"))
    filt = ProductFilter(sites=(obs.rmc.site,), drives=(obs.rmc.drive,))
    report = fetch_products(cfg, filters=filt, progress=False)
    same = [p for p in archive.msl_labels if read_observation(p).rmc.drive == obs.rmc.drive]
    assert report.selected == len(same) >= 1
    assert len(_gets(server, ".jpg")) == len(same)  # images of the others were never fetched


def test_m2020_products_from_the_pds4_inventory_verify_md5(archive, server, tmp_path):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "m2020"))
    dry = fetch_products(cfg, dry_run=True, progress=False)
    sizes = sum(p.with_suffix(".jpg").stat().st_size for p in archive.m2020_labels)
    assert dry.selected == 4 and dry.image_bytes == sizes == dry.to_fetch_bytes
    assert _gets(server, ".jpg") == []  # a dry run downloads no image
    assert dry.format(True).startswith(f"dry run: 4 products (4 listed), {sizes} image bytes")
    report = fetch_products(cfg, progress=False)
    assert report.selected == 4 and not report.failures
    for p in report.products:
        data = (cfg.cache / p.image.rel).read_bytes()
        assert hashlib.md5(data).hexdigest() == p.image.md5 and len(data) == p.image.size
    sol52 = fetch_products(cfg, filters=ProductFilter(sols=(52, 52)), dry_run=True, progress=False)
    assert {p.sol for p in sol52.products} == {52} and sol52.to_fetch_bytes == 0


def test_failures_become_rows_and_a_rerun_completes(archive, server, tmp_path):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "m2020"))
    bad_label = archive.m2020_labels[0].relative_to(archive.root)
    bad_image = archive.m2020_labels[1].with_suffix(".jpg").relative_to(archive.root)
    server.fault(str(bad_label), "404")
    server.fault(str(bad_image), *["corrupt"] * (cfg.policy.retries + 1))
    report = fetch_products(cfg, progress=False)
    assert report.selected == 2 and len(report.failures) == 2
    rows = pq.read_table(cfg.cache / FAILURES).to_pylist()
    assert {(r["stage"], r["url"].removeprefix(server.url + "/")) for r in rows} == {
        ("label", str(bad_label)),
        ("image", str(bad_image)),
    }
    assert any("MD5" in r["message"] for r in rows) and any("404" in r["message"] for r in rows)
    leftovers = [p for p in cfg.cache.rglob("*") if p.suffix in (".part", ".tmp")]
    assert leftovers == [] and not (cfg.cache / bad_image.relative_to("mars2020")).exists()
    assert server.faults == {str(bad_label): [], str(bad_image): []}  # every fault was used
    server.reset_log()
    again = fetch_products(cfg, progress=False)
    assert again.selected == 4 and not again.failures
    gets = [e for e in server.log if e.method == "GET"]
    fetched = sorted(e.path for e in gets if e.status != 304)  # 304: revalidated tables
    assert sorted(e.path.rsplit("/", 1)[1] for e in gets if e.status == 304) == [
        "collection_data.csv",
        "collection_data.xml",
    ]
    assert fetched == sorted(
        [f"/{bad_label}", f"/{bad_label.with_suffix('.jpg')}", f"/{bad_image}"]
    )  # only what was missing
    assert pq.read_table(cfg.cache / FAILURES).num_rows == 0


def test_an_unreachable_index_is_one_failure_row(archive, server, tmp_path):
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl", volumes=["MSLMST_9999"]))
    report = fetch_products(cfg, progress=False)
    assert report.selected == 0
    assert [(f.product_id, f.stage) for f in report.failures] == [("MSLMST_9999", "index")]
    assert "HTTP 404" in report.failures[0].message
    assert pq.read_table(cfg.cache / FAILURES).num_rows == 1


def test_index_entries_that_escape_the_cache_are_refused(archive, server, tmp_path):
    vol = archive.root / "msl" / "MSLMST_0666"
    row = {"VOLUME_ID": "MSLMST_0666", "PATH_NAME": "../../../../tmp/", "FILE_NAME": "x.LBL",
           "PRODUCT_ID": "X_DRCL", "INSTRUMENT_ID": "MAST_LEFT", "PLANET_DAY_NUMBER": 1,
           "IMAGE_ID": "X"}  # fmt: skip
    fetch_archive.write_pds3_index(vol, [row])
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl", volumes=["MSLMST_0666"]))
    report = fetch_products(cfg, progress=False)  # one failure row naming the row, no abort
    assert report.selected == 0 and [f.stage for f in report.failures] == ["index"]
    assert "row 1: refused path '../../../../tmp/x.LBL' (escapes the archive root)" in (
        report.failures[0].message
    )
    assert not (tmp_path / "tmp").exists() and not (cfg.cache.parent / "tmp" / "x.LBL").exists()


def test_config_errors_name_the_key(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"fetch": {"cache": "c", "products": {"mission": "mer"}}}))
    with pytest.raises(ConfigError, match=r"fetch\.products\.mission"):
        load_fetch_config(path)
    products = {"mission": "msl", "archive": "x"}
    path.write_text(yaml.safe_dump({"fetch": {"cache": "c", "products": products}}))
    with pytest.raises(ConfigError, match=r"fetch\.products\.volumes"):
        load_fetch_config(path)


def test_edrindex_is_read_the_same_way(archive, server, tmp_path):
    import pdr

    vol = archive.root / "msl" / fetch_archive.MSL_VOLUME
    if not (vol / "INDEX" / "EDRINDEX.LBL").exists():
        rows = pdr.read(str(vol / "INDEX" / "RDRINDEX.LBL"))["INDEX_TABLE"].to_dict("records")
        fetch_archive.write_pds3_index(vol, rows[:3], name="EDRINDEX")
    cfg = load_fetch_config(write_config(tmp_path, server.url, "msl", index="EDRINDEX"))
    assert fetch_products(cfg, dry_run=True, progress=False).selected == 3
