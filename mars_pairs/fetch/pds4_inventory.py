"""Perseverance PDS4 bundles: a collection label -> its inventory -> the product labels.

The collection label (``Product_Collection``) names its inventory file and delimiter
(``File_Area_Inventory/Inventory``); inventory rows are ``P,<lidvid>`` (primary members) and
``S,<lidvid>`` (secondary, skipped and counted). A LID's last field is the product id in
lower case without its 2-character version; the VID gives the version
(``...110085j::3.0`` is file ``..._110085J03``; ``products.encode_version`` past 99). The
label's path in the bundle comes from a template (the archive's own layout, e.g.
``data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml``, ``product_id`` the file name stem),
filled from the fields the Mastcam-Z product id encodes (sol, instrument, type, site, drive,
filter, geometry, thumbnail, version).
"""

from __future__ import annotations

import csv
import re
from dataclasses import replace
from pathlib import Path, PurePosixPath

from lxml import etree

from mars_pairs.errors import FetchError, LabelError
from mars_pairs.fetch.cache import archive_path, join_url
from mars_pairs.fetch.download import RemoteFile
from mars_pairs.fetch.products import (
    PDS4_NS,
    Failure,
    Listing,
    M2020Id,
    Product,
    Skipped,
    newest_only,
    parse_m2020_id,
    zcam_fields_of,
)
from mars_pairs.fetch.validate import delimiter_of, label_fault


def inventory_of(collection_label: Path, collection_rel: PurePosixPath) -> PurePosixPath:
    """Archive path of the inventory table the collection label describes."""
    root = _parse(collection_label)
    ns = {"pds": PDS4_NS}
    area = root.find("pds:File_Area_Inventory", ns)
    name = area.findtext("pds:File/pds:file_name", namespaces=ns) if area is not None else None
    if not name:
        raise FetchError(collection_label, "File_Area_Inventory/File/file_name: missing")
    return archive_path(str(collection_rel.parent / name.strip()), where=str(collection_label))


def inventory_delimiter(collection_label: Path) -> str:
    """The inventory's field delimiter (``Inventory/field_delimiter``; comma by default)."""
    return delimiter_of(_parse(collection_label), collection_label)


def file_version(vid: str) -> int:
    """The file version a PDS4 VID gives (``1.0`` -> 1, ``3.0`` -> 3); ValueError otherwise.

    Only ``N.0`` is attested (real labels: ``version_id`` 1.0 <-> ``...J01``, 3.0 <-> ``J03``);
    a VID with a minor part names no file and is refused."""
    m = re.fullmatch(r"(\d+)\.(\d+)", vid.strip())
    if not m:
        raise ValueError(f"VID {vid!r} is not <major>.<minor>")
    if int(m[2]) != 0:
        raise ValueError(f"VID {vid!r}: a minor version names no file (only N.0 is attested)")
    return int(m[1])


def file_id_of_lidvid(lidvid: str) -> str:
    """The file name stem of a Mars 2020 camera product's LIDVID (upper case, with version).

    ``...:zlf_0052_..._110085j::1.0`` -> ``ZLF_0052_..._110085J01``. Raises ``FetchError``
    (the LIDVID, the reason) when the VID is missing or names no file, or the id does not
    follow the camera SIS grammar."""
    version = _vid_version(lidvid)
    return _at_version(parse_m2020_id(_lid_id(lidvid)), version, lidvid).text


def _lid_id(lidvid: str) -> str:
    """The product id a LIDVID's LID ends with (as written: lower case, no version)."""
    return lidvid.strip().partition("::")[0].rsplit(":", 1)[-1]


def _vid_version(lidvid: str) -> int:
    """The file version a LIDVID's VID gives; ``FetchError`` naming the LIDVID otherwise."""
    _, sep, vid = lidvid.strip().partition("::")
    if not sep:
        raise FetchError(lidvid, "no '::<VID>' after the LID")
    try:
        return file_version(vid)
    except ValueError as exc:
        raise FetchError(lidvid, str(exc)) from None


def _at_version(pid: M2020Id, version: int, lidvid: str) -> M2020Id:
    """The id of a LID (parsed, without version) at a file ``version``: what parsing the file
    id would give; ``FetchError`` naming the LIDVID when the LID's id carries a version."""
    if pid.version is not None:
        raise FetchError(lidvid, "the LID's product id carries a version (54 characters)")
    try:
        return replace(pid, text=pid.file_id(version), version=version)
    except ValueError as exc:
        raise FetchError(lidvid, str(exc)) from None


def products_from_inventory(
    inventory: Path,
    delimiter: str,
    bundle: PurePosixPath,
    label_template: str,
    archive_root: str,
    inventory_url: str | None = None,
    camera: str = "zcam",
) -> Listing:
    """Products of the inventory's primary members that are products of the ``camera``
    family (``zcam`` Mastcam-Z, ``ncam`` Navcam: ``products.M2020_CAMERAS``).

    A secondary member, or a product id of another camera (or outside the SIS grammar), is
    ``Skipped``; a row that is not ``P|S,<LID>::<VID>``, whose VID names no file or whose
    label path escapes the archive is a ``Failure`` (stage ``index``) naming the row; the
    other rows go on. One LID listed with several VIDs keeps the newest (``newest_only``)."""
    url = inventory_url or str(inventory)
    try:
        text = inventory.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FetchError(inventory, f"unreadable inventory: {exc}") from None
    out = Listing()

    def fail(number: int, lidvid: str, reason: str, error: str = "FetchError") -> None:
        out.failures.append(Failure(lidvid, url, "index", error, f"row {number}: {reason}"))

    for number, row in enumerate(csv.reader(text.splitlines(), delimiter=delimiter), 1):
        if not row or not "".join(row).strip():
            continue
        status = row[0].strip().upper()
        if len(row) != 2 or status not in ("P", "S"):
            fail(number, delimiter.join(row), f"expected 'P|S,<lidvid>', got {row!r}")
            continue
        lidvid = row[1].strip()
        if status == "S":
            out.skipped.append(Skipped(lidvid, url, "index", "secondary member", f"row {number}"))
            continue
        try:
            pid = parse_m2020_id(_lid_id(lidvid))  # once per row: carried from here on
        except FetchError as exc:
            out.skipped.append(
                Skipped(lidvid, url, "index", "not an M2020 camera product id", exc.reason)
            )
            continue
        if not zcam_fields_of(pid, camera):
            what = "a Mastcam-Z" if camera == "zcam" else "a Navcam"
            out.skipped.append(
                Skipped(lidvid, url, "index", f"not {what} id", f"camera {pid.camera}")
            )
            continue
        try:
            pid = _at_version(pid, _vid_version(lidvid), lidvid)
            product_id, fields = pid.text, zcam_fields_of(pid, camera)
            inside = label_template.format(product_id=product_id, lid=lidvid.partition("::")[0],
                                           **fields)  # fmt: skip
            rel = bundle / archive_path(inside, where=f"{url}: row {number}")
        except (KeyError, IndexError, ValueError) as exc:
            raise FetchError("fetch.products.label_path", f"bad template: {exc}") from None
        except FetchError as exc:
            fail(number, lidvid, exc.reason)
            continue
        out.products.append(
            Product(
                mission="m2020",
                product_id=product_id,
                label=RemoteFile(rel, join_url(archive_root, rel)),
                **fields,
            )
        )
    out.products, older = newest_only(out.products)
    out.skipped.extend(older)
    return out


def _parse(path: Path) -> etree._Element:
    """The collection label at ``path``, read by the bounded XML loader (``pds.xml``)."""
    from mars_pairs.pds.common import read_bytes
    from mars_pairs.pds.xml import load_xml

    try:
        data, longer = read_bytes(path)
        if longer:
            raise LabelError(path, None, f"larger than {len(data)} bytes: not a label")
        return load_xml(data, path)
    except LabelError as exc:
        raise FetchError(path, f"unreadable collection label: {label_fault(exc)}") from None
