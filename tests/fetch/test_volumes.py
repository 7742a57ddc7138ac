"""Curiosity volumes from the sol-range table; one product per id (newest version, newest
volume); a bad index row is a failure row and the rest go on."""

from __future__ import annotations

import shutil
from pathlib import Path, PurePosixPath

import pytest
import yaml

from mars_pairs.errors import ConfigError, FetchError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.download import RemoteFile
from mars_pairs.fetch.products import Product, mmm_version, newest_only
from mars_pairs.fetch.run import FAILURES, SKIPPED, fetch_products
from mars_pairs.fetch.volumes import (
    VolumeRange,
    load_volume_ranges,
    ranges_from_archive,
    shipped_table,
    sol_range_of_index,
    volumes_for_sols,
    write_volume_ranges,
)
from support import fetch_archive
from support.fetch_archive import write_config
from support.fetch_server import ArchiveServer

REAL_TABLE = (
    Path(__file__).resolve().parents[3] / "shared/real-archive/mslmst_volume_sol_ranges.csv"
)
CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_the_volumes_of_a_sol_are_those_whose_range_covers_it():
    # sol 1429: MSLMST_0014 (1158-1514) and MSLMST_0015 (1163-1648); MSLMST_0013 ends at 1417
    # and MSLMST_0012 at 1293 (the config named MSLMST_0012)
    assert volumes_for_sols((1429, 1429)) == ("MSLMST_0014", "MSLMST_0015")
    assert volumes_for_sols((1417, 1429)) == ("MSLMST_0013", "MSLMST_0014", "MSLMST_0015")
    assert volumes_for_sols((0, 0)) == ("MSLMST_0001",)
    assert volumes_for_sols((2702, 2702)) == ("MSLMST_0024",)
    with pytest.raises(FetchError, match=r"reach past sol 2702.*name the volumes"):
        volumes_for_sols((2700, 2800))


def test_the_shipped_table_is_package_data_and_the_real_one():
    rows = load_volume_ranges()
    assert shipped_table().is_file() and len(rows) == 24
    assert rows[12] == VolumeRange("MSLMST_0013", 1082, 1417)
    if not REAL_TABLE.is_file():
        pytest.skip("../shared/real-archive is absent")
    assert rows == load_volume_ranges(REAL_TABLE)


def test_a_refreshed_table_round_trips(tmp_path):
    import pandas as pd

    index = pd.DataFrame({"PLANET_DAY_NUMBER": [1431, 1429, 1500], "FILE_NAME": ["a", "b", "c"]})
    rows = [sol_range_of_index(index, "MSLMST_0099"), *load_volume_ranges()[:2]]
    assert rows[0] == VolumeRange("MSLMST_0099", 1429, 1500)
    path = tmp_path / "ranges.csv"
    write_volume_ranges(rows, path, comment="origin: the volumes' RDRINDEX tables")
    assert path.read_text().startswith("# origin: the volumes' RDRINDEX tables\nvolume_id,")
    assert load_volume_ranges(path) == tuple(sorted(rows, key=lambda r: r.volume))
    path.write_text("volume_id,first_sol,last_sol\nMSLMST_0001,9,3\n")
    with pytest.raises(FetchError, match="row 2: first sol after last sol"):
        load_volume_ranges(path)


def _p(product_id: str, volume: str) -> Product:
    rel = PurePosixPath(volume, "DATA", product_id + ".LBL")
    parsed = mmm_version(product_id)
    return Product("msl", product_id, RemoteFile(rel, f"x/{rel}"), volume=volume,
                   version=parsed[1] if parsed else None)  # fmt: skip


def test_newest_version_then_newest_volume_wins_and_the_rest_is_counted():
    a1 = "1429MR0070670010702567E01_DRCL"
    a2 = "1429MR0070670010702567E02_DRCL"
    gop = "1429MR0070670010702567E11_DRCL"  # GOP counter 1: another frame, not a version
    b = "1429MR0070680020702583E01_DRCL"
    listed = [_p(a1, "MSLMST_0014"), _p(a2, "MSLMST_0014"), _p(a1, "MSLMST_0015"),
              _p(gop, "MSLMST_0014"), _p(b, "MSLMST_0014"), _p(b, "MSLMST_0015"),
              _p(b, "MSLMST_0015")]  # fmt: skip
    kept, skipped = newest_only(listed)
    assert [(p.product_id, p.volume) for p in kept] == [
        (a2, "MSLMST_0014"), (gop, "MSLMST_0014"), (b, "MSLMST_0015")]  # fmt: skip
    assert sorted((s.product_id, s.reason) for s in skipped) == [
        (a1, "older version"), (a1, "older version"),
        (b, "listed twice"), (b, "same product in a newer volume")]  # fmt: skip
    assert all(s.stage == "index" for s in skipped)
    assert {s.detail for s in skipped if s.product_id == b} == {f"kept {b} in MSLMST_0015"}


@pytest.fixture()
def volumes_14_15(tmp_path_factory):
    """The fixture archive with MSLMST_0014 (all 4 products, E01) and MSLMST_0015 (two of
    them again, a third as E02, and a row whose path has backslashes)."""
    import pdr

    archive = fetch_archive.shared_archive(tmp_path_factory.getbasetemp())
    base = archive.root / "msl"
    src = base / fetch_archive.MSL_VOLUME
    records = pdr.read(str(src / "INDEX" / "RDRINDEX.LBL"))["INDEX_TABLE"].to_dict("records")
    records = [{k: str(v).strip() for k, v in r.items()} for r in records]
    if not (base / "MSLMST_0015").exists():
        for vol in ("MSLMST_0014", "MSLMST_0015"):
            shutil.copytree(src / "DATA", base / vol / "DATA")
        fetch_archive.write_pds3_index(base / "MSLMST_0014", records)
        newer = dict(records[2])
        newer["FILE_NAME"] = newer["FILE_NAME"].replace("E01_", "E02_")
        newer["PRODUCT_ID"] = newer["PRODUCT_ID"].replace("E01_", "E02_")
        folder = base / "MSLMST_0015" / newer["PATH_NAME"]
        shutil.copy2(folder / records[2]["FILE_NAME"], folder / newer["FILE_NAME"])
        bad = dict(records[0], PATH_NAME="DATA\\RDR\\SURFACE\\1429\\")
        fetch_archive.write_pds3_index(base / "MSLMST_0015", [records[0], records[1], newer, bad])
    return archive, records


def test_msl_volumes_come_from_the_table_and_each_product_once(volumes_14_15, tmp_path):
    archive, records = volumes_14_15
    ids = [r["PRODUCT_ID"] for r in records]
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "msl", volumes=None, sols=[1429, 1430])
        cfg = load_fetch_config(config)
        assert cfg.products.volumes == ()
        report = fetch_products(cfg, dry_run=True, progress=False)
        indexes = sorted(e.path for e in srv.log if e.path.endswith("RDRINDEX.LBL"))
    assert indexes == ["/msl/MSLMST_0014/INDEX/RDRINDEX.LBL", "/msl/MSLMST_0015/INDEX/RDRINDEX.LBL"]
    got = sorted((p.product_id, p.volume) for p in report.products)
    assert got == sorted([
        (ids[0], "MSLMST_0015"), (ids[1], "MSLMST_0015"),
        (ids[2].replace("E01_", "E02_"), "MSLMST_0015"), (ids[3], "MSLMST_0014")])  # fmt: skip
    assert sorted((s.product_id, s.reason) for s in report.skipped) == sorted([
        (ids[0], "same product in a newer volume"), (ids[1], "same product in a newer volume"),
        (ids[2], "older version")])  # fmt: skip
    # the bad row: one failure row naming it; the other rows went on
    assert [(f.stage, f.url.removeprefix(srv.url)) for f in report.failures] == [
        ("index", "/msl/MSLMST_0015/INDEX/RDRINDEX.TAB")]  # fmt: skip
    assert report.failures[0].message.startswith("row 4: refused path 'DATA\\\\RDR")
    assert "  skipped 2: same product in a newer volume" in report.format(True).splitlines()
    assert "  skipped 1: older version" in report.format(True).splitlines()
    # a dry run prints its failures and skips and writes no report file
    assert not (cfg.cache / SKIPPED).exists() and not (cfg.cache / FAILURES).exists()


def test_filters_at_the_index_and_the_label_are_counted_by_reason(volumes_14_15, tmp_path):
    archive, _ = volumes_14_15
    with ArchiveServer(archive.root) as srv:
        config = write_config(tmp_path, srv.url, "msl", sols=[1429, 1429], sites=[999])
        report = fetch_products(load_fetch_config(config), dry_run=True, progress=False)
    reasons = dict(
        line.strip().split(": ", 1)[::-1] for line in report.format(True).split("\n")[1:]
    )
    assert reasons == {"sol outside [1429, 1429]": "skipped 2", "site not in [999]": "skipped 2"}
    assert {s.stage for s in report.skipped if s.reason.startswith("site")} == {"label"}
    assert report.selected == 0 and not report.failures


def test_the_table_is_refreshed_from_the_volumes_own_indexes(volumes_14_15, tmp_path):
    from mars_pairs.fetch.cache import Cache
    from mars_pairs.fetch.download import Downloader

    archive, _ = volumes_14_15
    with ArchiveServer(archive.root) as srv:
        dl = Downloader(Cache(tmp_path / "cache"))
        rows = ranges_from_archive(f"{srv.url}/msl", ["MSLMST_0014", "MSLMST_0015"], dl)
    assert rows == [VolumeRange("MSLMST_0014", 1429, 1430), VolumeRange("MSLMST_0015", 1429, 1430)]


def test_configs_choose_msl_volumes_by_sols_and_validate_thumbnails(tmp_path):
    cfg = load_fetch_config(CONFIGS / "msl_gale.yaml")
    assert cfg.products.volumes == () and cfg.products.filters.sols == (1429, 1429)
    assert volumes_for_sols(cfg.products.filters.sols) == ("MSLMST_0014", "MSLMST_0015")
    assert "volumes:" not in yaml.safe_dump(yaml.safe_load(
        (CONFIGS / "msl_gale.yaml").read_text())["fetch"]["products"])  # fmt: skip
    path = tmp_path / "c.yaml"
    products = {"mission": "m2020", "archive": "x", "bundle": "b", "thumbnails": True}
    path.write_text(yaml.safe_dump({"fetch": {"cache": "c", "products": products}}))
    assert load_fetch_config(path).products.filters.thumbnails is True
    products["thumbnails"] = "yes"
    path.write_text(yaml.safe_dump({"fetch": {"cache": "c", "products": products}}))
    with pytest.raises(ConfigError, match=r"fetch\.products\.thumbnails"):
        load_fetch_config(path)


def test_a_volume_whose_index_fails_is_a_failure_row_and_the_others_go_on(volumes_14_15, tmp_path):
    archive, records = volumes_14_15
    ids = [r["PRODUCT_ID"] for r in records]
    with ArchiveServer(archive.root) as srv:
        cfg = load_fetch_config(
            write_config(tmp_path, srv.url, "msl", volumes=None, sols=[1429, 1430])
        )
        srv.fault("msl/MSLMST_0015/INDEX/RDRINDEX.TAB", *["404"] * (cfg.policy.retries + 1))
        report = fetch_products(cfg, dry_run=True, progress=False)
    assert [(f.product_id, f.stage) for f in report.failures] == [("MSLMST_0015", "index")]
    assert "404" in report.failures[0].message
    # MSLMST_0014's products all listed, from 0014 (0015 could not be read)
    assert sorted((p.product_id, p.volume) for p in report.products) == sorted(
        (i, "MSLMST_0014") for i in ids
    )


def _index_of_sols(folder: Path, sols: range) -> None:
    """``folder/INDEX/RDRINDEX.LBL`` + ``.TAB`` listing one product per sol."""
    rows = [{"VOLUME_ID": "MSLMST_0016", "PATH_NAME": f"DATA/RDR/SURFACE/{sol:04d}/",
             "FILE_NAME": f"{sol:04d}MR0070670010702567E01_DRCL.LBL",
             "PRODUCT_ID": f"{sol:04d}MR0070670010702567E01_DRCL", "INSTRUMENT_ID": "MAST_RIGHT",
             "PLANET_DAY_NUMBER": sol, "IMAGE_ID": str(sol)} for sol in sols]  # fmt: skip
    fetch_archive.write_pds3_index(folder, rows)


def test_the_refresh_fetches_indexes_as_the_listing_does(tmp_path):
    """Revalidated (a re-released index replaces the cached one) and checked against its
    label (a cut table is refused, naming it)."""
    from mars_pairs.fetch.cache import Cache
    from mars_pairs.fetch.download import Downloader, FetchPolicy

    root, fresh = tmp_path / "archive", tmp_path / "re-release"
    _index_of_sols(root / "msl" / "MSLMST_0016", range(1649, 1652))
    _index_of_sols(fresh, range(1649, 1700))
    policy = FetchPolicy(retries=1, backoff_s=0.01, read_timeout_s=2.0)
    dl = Downloader(Cache(tmp_path / "cache"), policy)
    with ArchiveServer(root) as srv:
        url = f"{srv.url}/msl"
        assert ranges_from_archive(url, ["MSLMST_0016"], dl) == [
            VolumeRange("MSLMST_0016", 1649, 1651)]  # fmt: skip
        for name in ("RDRINDEX.LBL", "RDRINDEX.TAB"):
            srv.replace(f"msl/MSLMST_0016/INDEX/{name}", (fresh / "INDEX" / name).read_bytes())
        assert ranges_from_archive(url, ["MSLMST_0016"], dl) == [
            VolumeRange("MSLMST_0016", 1649, 1699)]  # fmt: skip
        tab = "msl/MSLMST_0016/INDEX/RDRINDEX.TAB"
        srv.fault(tab, *["short"] * (policy.retries + 1))
        other = Downloader(Cache(tmp_path / "other"), policy)
        with pytest.raises(FetchError, match=r"RDRINDEX\.TAB: failed .* its label .* says"):
            ranges_from_archive(url, ["MSLMST_0016"], other)
