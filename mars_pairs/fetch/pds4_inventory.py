"""Perseverance PDS4 bundles: a collection label -> its inventory -> the product labels.

The collection label (``Product_Collection``) names its inventory file and delimiter
(``File_Area_Inventory/Inventory``); inventory rows are ``P,<lidvid>`` (primary members) and
``S,<lidvid>`` (secondary, skipped). A LID's last field is the product id; the label's path
in the bundle comes from a template (the archive's own layout, e.g.
``data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml``), filled from the fields the Mastcam-Z
product id encodes (sol, instrument, type, site, drive).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from lxml import etree

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import archive_path, join_url
from mars_pairs.fetch.download import RemoteFile
from mars_pairs.fetch.products import PDS4_NS, Product, zcam_fields

DELIMITERS = {
    "Comma": ",",
    "Horizontal Tab": "\t",
    "Semicolon": ";",
    "Vertical Bar": "|",
}


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
    root = _parse(collection_label)
    text = root.findtext(
        "pds:File_Area_Inventory/pds:Inventory/pds:field_delimiter", namespaces={"pds": PDS4_NS}
    )
    if text is None:
        return ","
    if text.strip() not in DELIMITERS:
        raise FetchError(collection_label, f"Inventory/field_delimiter: unknown {text!r}")
    return DELIMITERS[text.strip()]


def products_from_inventory(
    inventory: Path,
    delimiter: str,
    bundle: PurePosixPath,
    label_template: str,
    archive_root: str,
) -> Iterable[Product]:
    """One Product per primary member whose product id is a Mastcam-Z id."""
    try:
        text = inventory.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FetchError(inventory, f"unreadable inventory: {exc}") from None
    for number, row in enumerate(csv.reader(text.splitlines(), delimiter=delimiter), 1):
        if not row or not row[0].strip():
            continue
        if len(row) < 2:
            raise FetchError(inventory, f"row {number}: expected 'P,<lidvid>', got {row!r}")
        if row[0].strip().upper() != "P":
            continue
        lid = row[1].strip().split("::")[0]
        product_id = lid.rsplit(":", 1)[-1].upper()
        fields = zcam_fields(product_id)
        if not fields:
            continue
        try:
            inside = label_template.format(product_id=product_id, lid=lid, **fields)
        except (KeyError, IndexError, ValueError) as exc:
            raise FetchError("fetch.products.label_path", f"bad template: {exc}") from None
        rel = bundle / archive_path(inside, where=f"{inventory}: row {number}")
        yield Product(
            mission="m2020",
            product_id=product_id,
            label=RemoteFile(rel, join_url(archive_root, rel)),
            **fields,  # type: ignore[arg-type]
        )


def _parse(path: Path) -> etree._Element:
    try:
        return etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise FetchError(path, f"unreadable collection label: {exc}") from None
