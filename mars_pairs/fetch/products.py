"""Products in an archive index, the filters that choose them, and what their labels say.

A ``Product`` is one observation as an index lists it: identity and the fields filters test
(mission, sol, instrument, product type, site, drive; None where the index does not say) and
its label file. The image file is known once the label is read (``image_of_label``): PDS3
labels name it in ``^IMAGE`` (read with pdr); PDS4 labels in ``File_Area_Observational/File``
with its ``file_size`` and ``md5_checksum``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

from mars_pairs.errors import FetchError
from mars_pairs.fetch.cache import archive_path, join_url
from mars_pairs.fetch.download import RemoteFile

# Mastcam-Z: ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01 (DESIGN.md)
_ZCAM = re.compile(
    r"^Z(?P<eye>[LR])[A-Z_]_(?P<sol>\d{4})_\d{10}_\d{3}(?P<ptype>[A-Z]{3})_N(?P<site>\d{3})"
    r"(?P<drive>\d{4})"
)
_ZCAM_EYES = {"L": "MCZ_LEFT", "R": "MCZ_RIGHT"}
PDS4_NS = "http://pds.nasa.gov/pds4/pds/v1"


@dataclass(frozen=True)
class Product:
    """One indexed observation; ``label`` is its label file, ``image`` known after the label."""

    mission: str
    product_id: str
    label: RemoteFile
    sol: int | None = None
    instrument: str | None = None
    product_type: str | None = None
    site: int | None = None
    drive: int | None = None
    image: RemoteFile | None = None


@dataclass(frozen=True)
class ProductFilter:
    """Which products to fetch; None (or empty) means any. Sols inclusive (first, last)."""

    sols: tuple[int, int] | None = None
    instruments: tuple[str, ...] = ()
    product_types: tuple[str, ...] = ()
    sites: tuple[int, ...] = ()
    drives: tuple[int, ...] = ()

    def wants(self, p: Product, *, unknown_ok: bool = True) -> bool:
        """True when ``p`` passes; a field the index does not give passes if ``unknown_ok``."""

        def ok(value: object, allowed: tuple) -> bool:  # type: ignore[type-arg]
            if not allowed:
                return True
            if value is None:
                return unknown_ok
            return value in allowed

        if self.sols is not None:
            if p.sol is None:
                if not unknown_ok:
                    return False
            elif not self.sols[0] <= p.sol <= self.sols[1]:
                return False
        return (
            ok(p.instrument, tuple(i.upper() for i in self.instruments))
            and ok(p.product_type, tuple(t.upper() for t in self.product_types))
            and ok(p.site, self.sites)
            and ok(p.drive, self.drives)
        )

    @property
    def needs_label_fields(self) -> bool:
        """Whether site/drive filters may need the label (indexes may not list them)."""
        return bool(self.sites or self.drives)


def zcam_fields(product_id: str) -> dict[str, object]:
    """Sol, instrument, product type, site and drive encoded in a Mastcam-Z product id."""
    m = _ZCAM.match(product_id.upper())
    if not m:
        return {}
    return {
        "sol": int(m["sol"]),
        "instrument": _ZCAM_EYES[m["eye"]],
        "product_type": m["ptype"],
        "site": int(m["site"]),
        "drive": int(m["drive"]),
    }


def _sibling(label: RemoteFile, name: str, where: str) -> PurePosixPath:
    """The archive path of a file the label names (a bare file name in the label's folder)."""
    name = name.strip()
    if not name or PurePosixPath(name).name != name:
        raise FetchError(where, f"label names data file {name!r}, not a bare file name")
    return archive_path(str(label.rel.parent / name), where=where)


def pds3_label_facts(path: Path) -> dict[str, object]:
    """Image file name (``^IMAGE``), site and drive of a downloaded PDS3 label, via pdr."""
    import pdr

    try:
        meta = pdr.read(str(path)).metadata
        pointer = meta.get("^IMAGE")
        names = meta.get("ROVER_MOTION_COUNTER_NAME")
        values = meta.get("ROVER_MOTION_COUNTER")
    except Exception as exc:  # pdr raises many types on damaged labels
        raise FetchError(path, f"unreadable PDS3 label: {type(exc).__name__}: {exc}") from None
    if isinstance(pointer, (list, tuple)):
        pointer = pointer[0]
    facts: dict[str, object] = {"image": str(pointer) if pointer else None}
    if names and values and len(names) == len(values):
        counter = dict(zip((str(n).upper() for n in names), values, strict=True))
        facts["site"], facts["drive"] = counter.get("SITE"), counter.get("DRIVE")
    return facts


def pds4_label_facts(path: Path) -> dict[str, object]:
    """Image file name, size (bytes) and MD5 from a PDS4 label's File_Area_Observational."""
    from lxml import etree

    try:
        root = etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise FetchError(path, f"unreadable PDS4 label: {exc}") from None
    ns = {"pds": PDS4_NS}
    file_el = root.find("pds:File_Area_Observational/pds:File", ns)
    if file_el is None:
        raise FetchError(path, "File_Area_Observational/File: missing")
    name = file_el.findtext("pds:file_name", namespaces=ns)
    size = file_el.findtext("pds:file_size", namespaces=ns)
    md5 = file_el.findtext("pds:md5_checksum", namespaces=ns)
    try:
        size_bytes = int(size) if size else None
    except ValueError:
        raise FetchError(path, f"File/file_size: not an integer: {size!r}") from None
    return {"image": name, "size": size_bytes, "md5": md5.strip().lower() if md5 else None}


def with_label_facts(p: Product, label_path: Path, archive_root: str) -> Product:
    """The product with its image file (and site/drive from a PDS3 label when missing)."""
    where = p.label.url
    read = pds4_label_facts if p.mission == "m2020" else pds3_label_facts
    facts = read(label_path)
    name = facts.get("image")
    if not name:
        raise FetchError(where, "the label names no image file")
    rel = _sibling(p.label, str(name), where)
    image = RemoteFile(rel, join_url(archive_root, rel), facts.get("size"), facts.get("md5"))  # type: ignore[arg-type]
    site = p.site if p.site is not None else _int_or_none(facts.get("site"))
    drive = p.drive if p.drive is not None else _int_or_none(facts.get("drive"))
    return replace(p, image=image, site=site, drive=drive)


def _int_or_none(value: object) -> int | None:
    try:
        return None if value is None else int(value)  # type: ignore[call-overload]
    except (TypeError, ValueError):
        return None
