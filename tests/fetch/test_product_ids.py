"""Mars 2020 camera product ids (M2020 Camera SIS grammar) and PDS4 inventory rows -> labels."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import pytest
from lxml import etree

from mars_pairs.errors import FetchError
from mars_pairs.fetch.pds4_inventory import file_id_of_lidvid, products_from_inventory
from mars_pairs.fetch.products import (
    DRIVE_MAX,
    PDS4_NS,
    SITE_MAX,
    VERSION_MAX,
    ProductFilter,
    decode_drive,
    decode_site,
    decode_version,
    encode_drive,
    encode_site,
    encode_version,
    parse_m2020_id,
    with_label_facts,
    zcam_fields,
)

SHARED = Path(__file__).resolve().parents[3] / "shared"
REAL_ROWS = SHARED / "real-archive" / "mastcamz_inventory_rows.csv"
REAL_LABELS = SHARED / "pds-samples" / "m2020"
BUNDLE = PurePosixPath("mars2020_mastcamz_ops_calibrated")
TEMPLATE = "data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml"
ROOT = "https://archive.invalid/mars2020"

# id -> the fields it must parse to (sol, instrument, type, site, drive, filter, geometry,
# thumbnail, version); the ids follow the SIS layout with each field varied in turn
PARSED = {
    # the real labels' ids
    "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 1),
    "ZRF_0079_0673952814_113RAD_N0032430ZCAM03128_110085J03":
        (79, "MCZ_RIGHT", "RAD", 3, 2430, "F", "_", False, 3),
    # narrow-band filters L0..L7 / R0..R7
    "ZL0_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "0", "_", False, 1),
    "ZR7_0079_0673952814_113IOF_N0032430ZCAM03128_110085J01":
        (79, "MCZ_RIGHT", "IOF", 3, 2430, "7", "_", False, 1),
    # thumbnail (flag T), downsampled 2**3
    "ZLF_0047_0671110966_007RAD_T0031416ZCAM05001_110300J01":
        (47, "MCZ_LEFT", "RAD", 3, 1416, "F", "_", True, 1),
    # linearized with the nominal (L) / actual (A) stereo partner
    "ZRF_0052_0671559321_081RADLN0031950ZCAM05024_110085J01":
        (52, "MCZ_RIGHT", "RAD", 3, 1950, "F", "L", False, 1),
    "ZLF_0052_0671559321_081RADAN0031950ZCAM05024_110085J02":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "A", False, 2),
    # lossless (LU) and 2x2-downsampled products, a special flag, other zoom settings
    "ZRF_0045_0670943307_535RAS_N0031416ZCAM05003_1100LUJ01":
        (45, "MCZ_RIGHT", "RAS", 3, 1416, "F", "_", False, 1),
    "ZLEA0045_0670943307_535RZS_N0031416ZCAM05003_0341LLJ01":
        (45, "MCZ_LEFT", "RZS", 3, 1416, "E", "_", False, 1),
    # versions 99, 100 (A0), 135 (AZ), 136 (B0), 1035 (ZZ) (of distinct products)
    "ZLF_0052_0671559321_099RAD_N0031950ZCAM05024_110085J99":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 99),
    "ZLF_0052_0671559321_100RAD_N0031950ZCAM05024_110085JA0":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 100),
    "ZLF_0052_0671559321_135RAD_N0031950ZCAM05024_110085JAZ":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 135),
    "ZLF_0052_0671559321_136RAD_N0031950ZCAM05024_110085JB0":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 136),
    "ZLF_0052_0671559321_035RAD_N0031950ZCAM05024_110085JZZ":
        (52, "MCZ_LEFT", "RAD", 3, 1950, "F", "_", False, 1035),
    # site and drive counters past 999 / 9999 (letters), their last values, out of range
    "ZLF_1019_0757408892_144RAS_NA050000ZCAM07114_1100LMJ02":
        (1019, "MCZ_LEFT", "RAS", 1005, 0, "F", "_", False, 2),
    "ZLF_1019_0757408892_144RAS_NAA0A000ZCAM07114_1100LMJ02":
        (1019, "MCZ_LEFT", "RAS", 3600, 10000, "F", "_", False, 2),
    "ZLF_1019_0757408892_144RAS_NAAAAA00ZCAM07114_1100LMJ02":
        (1019, "MCZ_LEFT", "RAS", 10360, 36000, "F", "_", False, 2),
    "ZLF_1019_0757408892_144RAS_N7DVLJ35ZCAM07114_1100LMJ02":
        (1019, "MCZ_LEFT", "RAS", 32767, 65535, "F", "_", False, 2),
    "ZLF_1019_0757408892_144RAS_N___B123ZCAM07114_1100LMJ02":
        (1019, "MCZ_LEFT", "RAS", None, 11123, "F", "_", False, 2),
}  # fmt: skip

# id -> (reason it is left out, a piece of the detail)
LEFT_OUT = {
    "NLF_0052_0671559321_081EBY_N0031950NCAM00500_01_295J01": ("not a Mastcam-Z id", "NL"),
    "FLF_0052_0671559321_081RAS_N0031950FHAZ00102_01_295J01": ("not a Mastcam-Z id", "FL"),
    "ZL8_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "no narrow-band 8"),
    "ZLF_0052_0671559321_081RADXN0031950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "geometry"),
    "ZLF_0052_0671559321_081RAD_X0031950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "thumbnail flag"),
    "ZLF_0052_0671559321_081RAD_NA0A1950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "site 'A0A'"),
    "ZLF_0052_0671559321_081RAD_N7DW1950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "site '7DW'"),
    "ZLF_0052_0671559321_081RAD_N003LJ36ZCAM05024_110085J01": (
        "not an M2020 camera product id", "drive 'LJ36'"),
    "ZLF_ATL__0671559321_081RAD_N0031950ZCAM05024_110085J01": (
        "not an M2020 camera product id", "sol"),
    "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085": (
        "not an M2020 camera product id", "51 characters, not 54"),
}  # fmt: skip


def _row(product_id: str, status: str = "P") -> str:
    """A real-form inventory row: LID = id in lower case without its version; VID = version."""
    return (
        f"{status},urn:nasa:pds:{BUNDLE}:data:{product_id[:-2].lower()}"
        f"::{decode_version(product_id[-2:])}.0\r\n"
    )


def _inventory(tmp_path: Path, text: str):
    path = tmp_path / "collection_data.csv"
    path.write_bytes(text.encode())
    return products_from_inventory(path, ",", BUNDLE, TEMPLATE, ROOT, inventory_url="inv.csv")


def test_each_inventory_row_id_is_parsed_once(tmp_path, monkeypatch):
    """The LID's id is parsed once per row; its versioned id and fields come from that."""
    from mars_pairs.fetch import pds4_inventory, products

    parsed: list[str] = []
    real = products.parse_m2020_id

    def counting(text: str):  # type: ignore[no-untyped-def]
        parsed.append(text)
        return real(text)

    monkeypatch.setattr(products, "parse_m2020_id", counting)
    monkeypatch.setattr(pds4_inventory, "parse_m2020_id", counting)
    listing = _inventory(tmp_path, "".join(_row(i) for i in PARSED))
    assert len(listing.products) == len(PARSED) and not listing.failures
    assert len(parsed) == len(PARSED)


def test_counters_and_versions_follow_the_sis_tables_both_ways():
    assert [encode_site(n) for n in (0, 999, 1000, 3599, 3600, 10359, 10360, 27935, 27936)] == [
        "000", "999", "A00", "Z99", "AA0", "ZZ9", "AAA", "ZZZ", "0AA"]  # fmt: skip
    assert encode_site(SITE_MAX) == "7DV" and encode_drive(DRIVE_MAX) == "LJ35"
    assert [encode_drive(n) for n in (9999, 10000, 35999, 36000)] == [
        "9999", "A000", "Z999", "AA00"]  # fmt: skip
    assert [encode_version(n) for n in (1, 99, 100, 109, 110, 135, 136, VERSION_MAX)] == [
        "01", "99", "A0", "A9", "AA", "AZ", "B0", "ZZ"]  # fmt: skip
    assert all(decode_site(encode_site(n)) == n for n in range(SITE_MAX + 1))
    assert all(decode_drive(encode_drive(n)) == n for n in range(DRIVE_MAX + 1))
    assert all(decode_version(encode_version(n)) == n for n in range(1, VERSION_MAX + 1))
    bad_codes = [
        ("7DW", decode_site),
        ("0A0", decode_site),
        ("LJ36", decode_drive),
        ("A0A0", decode_drive),
        ("00", decode_version),
        ("0A", decode_version),
    ]
    for bad, decode in bad_codes:
        with pytest.raises(ValueError, match=repr(bad)):
            decode(bad)


@pytest.mark.parametrize("product_id", sorted(PARSED))
def test_every_mastcamz_id_the_sis_allows_is_parsed(product_id):
    names = ("sol", "instrument", "product_type", "site", "drive", "filter", "geometry",
             "thumbnail", "version")  # fmt: skip
    assert zcam_fields(product_id) == dict(zip(names, PARSED[product_id], strict=True))
    pid = parse_m2020_id(product_id)
    assert pid.file_id(pid.version) == product_id  # the version letters round-trip
    lid_form = zcam_fields(product_id[:-2].lower())  # the LID: lower case, no version
    assert lid_form["version"] is None and lid_form["site"] == PARSED[product_id][3]


def test_each_id_is_a_product_or_counted_out_with_its_reason(tmp_path):
    rows = [_row(i) for i in PARSED]
    lid_ids = {(i[:-2] if len(i) == 54 else i): i for i in LEFT_OUT}  # LIDs carry no version
    rows += [f"P,urn:nasa:pds:{BUNDLE}:data:{lid.lower()}::1.0\r\n" for lid in lid_ids]
    listing = _inventory(tmp_path, "".join(rows))
    assert not listing.failures
    got = {p.product_id: p for p in listing.products}
    assert set(got) == set(PARSED)
    for product_id, p in got.items():
        fields = (p.sol, p.instrument, p.product_type, p.site, p.drive, p.filter, p.geometry,
                  p.thumbnail, p.version)  # fmt: skip
        assert fields == PARSED[product_id]
        assert p.label.rel == BUNDLE / TEMPLATE.format(sol=p.sol, product_id=product_id)
    assert len(listing.skipped) == len(LEFT_OUT)
    for s in listing.skipped:
        base = s.product_id.partition("::")[0].rsplit(":", 1)[-1].upper()
        reason, detail = LEFT_OUT[lid_ids[base]]
        assert (s.reason, s.stage) == (reason, "index") and detail in s.detail


def test_filters_count_thumbnails_and_types_out_by_reason(tmp_path):
    listing = _inventory(tmp_path, "".join(_row(i) for i in PARSED))
    by_id = {p.product_id: p for p in listing.products}
    thumb = by_id["ZLF_0047_0671110966_007RAD_T0031416ZCAM05001_110300J01"]
    ras = by_id["ZRF_0045_0670943307_535RAS_N0031416ZCAM05003_1100LUJ01"]
    assert ProductFilter().why_not(thumb) == ("thumbnail", "fetch.products.thumbnails is false")
    assert ProductFilter(thumbnails=True).why_not(thumb) is None
    filt = ProductFilter(sols=(50, 60), product_types=("RAD",))
    assert filt.why_not(ras) == ("sol outside [50, 60]", "sol 45")
    assert ProductFilter(product_types=("RAD",)).why_not(ras) == (
        "product type RAS not in [RAD]",
        "product type RAS",
    )
    far = by_id["ZLF_1019_0757408892_144RAS_NA050000ZCAM07114_1100LMJ02"]
    assert ProductFilter(sites=(3,)).why_not(far) == ("site not in [3]", "site 1005")


def test_bad_inventory_rows_are_failure_rows_and_the_rest_goes_on(tmp_path):
    good = "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01"
    lid = f"urn:nasa:pds:{BUNDLE}:data:{good[:-2].lower()}"
    text = (
        f"X\r\n"  # one field
        f"P,{lid}\r\n"  # no VID
        f"P,{lid}::1.1\r\n"  # a minor version names no file
        f"P,{lid}::1036.0\r\n"  # past ZZ
        f"Q,{lid}::1.0\r\n"  # neither P nor S
        f"S,urn:nasa:pds:mars2020_mission:context:something::1.0\r\n" + _row(good)
    )
    listing = _inventory(tmp_path, text)
    assert [p.product_id for p in listing.products] == [good]
    assert [f.message.split(":")[0] for f in listing.failures] == [
        "row 1", "row 2", "row 3", "row 4", "row 5"]  # fmt: skip
    assert all(f.stage == "index" and f.url == "inv.csv" for f in listing.failures)
    assert "minor version" in listing.failures[2].message
    assert "1036" in listing.failures[3].message
    assert [s.reason for s in listing.skipped] == ["secondary member"]


def test_an_escaping_template_is_a_failure_row(tmp_path):
    path = tmp_path / "inv.csv"
    path.write_text(_row("ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01"))
    listing = products_from_inventory(path, ",", BUNDLE, "../{product_id}.xml", ROOT)
    assert not listing.products and "escapes the archive root" in listing.failures[0].message


def test_one_lid_with_several_vids_keeps_the_newest(tmp_path):
    pid = "ZRF_0079_0673952814_113RAD_N0032430ZCAM03128_110085J03"
    text = _row(pid[:-2] + "01") + _row(pid) + _row(pid[:-2] + "02")
    listing = _inventory(tmp_path, text)
    assert [p.product_id for p in listing.products] == [pid]
    assert sorted(s.product_id for s in listing.skipped) == [pid[:-2] + "01", pid[:-2] + "02"]
    assert {s.reason for s in listing.skipped} == {"older version"}


@pytest.mark.skipif(not REAL_ROWS.is_file(), reason="../shared/real-archive is absent")
def test_the_real_inventory_rows_resolve_to_the_real_label_files():
    listing = products_from_inventory(REAL_ROWS, ",", BUNDLE, TEMPLATE, ROOT)
    assert not listing.failures and not listing.skipped
    names = [p.label.rel.name for p in listing.products]
    assert names == [
        "ZLF_0047_0671110966_007RAD_T0031416ZCAM05001_110300J01.xml",
        "ZLF_0048_0671201721_937RZS_N0031708ZCAM05008_110050J01.xml",
        "ZRF_0045_0670943307_535RAS_N0031416ZCAM05003_1100LUJ01.xml",
        "ZLF_1019_0757408892_144RAS_N0490000ZCAM07114_1100LMJ02.xml",
        "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml",
        "ZRF_0079_0673952814_113RAD_N0032430ZCAM03128_110085J03.xml",
    ]
    assert listing.products[0].thumbnail and listing.products[3].site == 49
    assert str(listing.products[4].label.rel) == (
        "mars2020_mastcamz_ops_calibrated/data/sol/00052/ids/rdr/zcam/"
        "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
    )
    if not REAL_LABELS.is_dir():
        pytest.skip("../shared/pds-samples/m2020 is absent")
    real = sorted(p.name for p in REAL_LABELS.glob("*.xml"))
    assert sorted(names[4:]) == real


@pytest.mark.skipif(not REAL_LABELS.is_dir(), reason="../shared/pds-samples/m2020 is absent")
def test_the_real_labels_lidvid_names_their_own_file():
    ns = {"pds": PDS4_NS}
    for label in sorted(REAL_LABELS.glob("*.xml")):
        root = etree.parse(str(label)).getroot()
        lid = root.findtext("pds:Identification_Area/pds:logical_identifier", namespaces=ns)
        vid = root.findtext("pds:Identification_Area/pds:version_id", namespaces=ns)
        assert file_id_of_lidvid(f"{lid}::{vid}") == label.stem
        # the label's own image: its folder, the same stem, no size or MD5 in real labels
        listing_rel = BUNDLE / TEMPLATE.format(sol=zcam_fields(label.stem)["sol"],
                                               product_id=label.stem)  # fmt: skip
        from mars_pairs.fetch.download import RemoteFile
        from mars_pairs.fetch.products import Product

        p = Product("m2020", label.stem, RemoteFile(listing_rel, f"{ROOT}/{listing_rel}"))
        image = with_label_facts(p, label, ROOT).image
        assert image.rel == listing_rel.with_suffix(".IMG") and image.size is None


def test_a_lidvid_without_vid_or_with_a_versioned_id_is_refused():
    with pytest.raises(FetchError, match="no '::<VID>'"):
        file_id_of_lidvid(
            "urn:nasa:pds:b:data:zlf_0052_0671559321_081rad_n0031950zcam05024_110085j"
        )
    with pytest.raises(FetchError, match="carries a version"):
        file_id_of_lidvid(
            "urn:nasa:pds:b:data:zlf_0052_0671559321_081rad_n0031950zcam05024_110085j01::1.0"
        )
