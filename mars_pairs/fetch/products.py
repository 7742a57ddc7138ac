"""Products in an archive index, the ids that name them, the filters that choose them.

A ``Product`` is one observation as an index lists it: identity and the fields filters test
(mission, sol, instrument, product type, site, drive, filter, geometry, thumbnail, version;
None where the index does not say) and its label file. The image file is known once the label
is read (``image_of_label``): PDS3 labels name it in ``^IMAGE`` (read with pdr); PDS4 labels
in ``File_Area_Observational/File`` (real Mastcam-Z labels give no size or MD5 there).

Nothing is dropped silently: a product the parser or a filter leaves out is a ``Skipped``
(a reason that groups, e.g. ``sol outside [1429, 1429]``, and a detail), a row that cannot
be read is a ``Failure``; ``Listing`` carries all three.

**Mars 2020 camera product ids** (M2020 Camera EDR/RDR Data Products SIS, JPL D-99960, file
naming section; the counter and version tables on its pp. 185-189, as transcribed by public
filename parsers, e.g. the one citing
https://pds-imaging.jpl.nasa.gov/reviews/mars2020/mars2020_mission/document_camera/Mars2020_Camera_SIS.pdf)::

    ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01
    0-1 camera (ZL, ZR, NL, NR, FL, ...)   2 filter (Mastcam-Z: F, E, M, ... or 0-7 narrow band)
    3 special flag   4-7 sol   8 venue (_ flight)   9-18 SCLK   19 _   20-22 SCLK ms
    23-25 product type   26 geometry (_ raw, L/A linearized)   27 T thumbnail / N not
    28-30 site   31-34 drive   35-43 sequence (ZCAM05024)   44-47 camera specific
    (Mastcam-Z: _ + focal length mm)   48 downsampling   49-50 compression   51 producer
    52-53 version

Site (3 characters, 0..32767): 000-999; A00-Z99 = 1000-3599; AA0-ZZ9 = 3600-10359;
AAA-ZZZ = 10360-27935; 0AA-7DV = 27936-32767. Drive (4 characters, 0..65535): 0000-9999;
A000-Z999 = 10000-35999; AA00-LJ35 = 36000-65535. ``___``/``____`` (out of range) read as
unknown. Version (2 characters, 1..1035): 01-99, then A0..AZ, B0..ZZ (second character 0-9
then A-Z) = 100-1035. PDS4 LIDs carry the id without its version (52 characters, lower case);
the VID's major number is the version (``::3.0`` -> ``03``).

**Curiosity Mastcam/MAHLI/MARDI (MMM) ids** (Analyst's Notebook, "File naming for MSL MMM
EDRs and single frame RDRs"): ``1429MR0070670010702567E01_DRCL`` = sol 1429, camera MR,
sequence 007067, command 001, CDPID counter 07, CDPID 02567, type E, GOP counter 0,
version 1, processing code DRCL. Two rows that differ only in the version are one product.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath
from typing import SupportsIndex, SupportsInt, TypedDict

from mars_pairs.errors import FetchError, LabelError
from mars_pairs.fetch.cache import archive_path, join_url
from mars_pairs.fetch.download import RemoteFile
from mars_pairs.fetch.validate import (
    Extent,
    label_fault,
    pds3_extent,
    pds4_extent,
    read_pds3_label,
)

PDS4_NS = "http://pds.nasa.gov/pds4/pds/v1"
_DIGITS = "0123456789"
_LETTERS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"
_ALNUM = _DIGITS + _LETTERS
_ZCAM_EYES = {"ZL": "MCZ_LEFT", "ZR": "MCZ_RIGHT"}
#: Mars 2020 Navcam eyes (the SIS's camera field NL, NR; instrument ids as the labels')
_NCAM_EYES = {"NL": "NAVCAM_LEFT", "NR": "NAVCAM_RIGHT"}
#: The camera families a Mars 2020 bundle's inventory is read for (``fetch.products.camera``)
M2020_CAMERAS = {"zcam": _ZCAM_EYES, "ncam": _NCAM_EYES}
SITE_MAX = 32767
DRIVE_MAX = 65535
VERSION_MAX = 1035


# -- Mars 2020 counters and versions ------------------------------------------------------
def decode_site(code: str) -> int:
    """The site count (0..32767) a 3-character M2020 file-name site field encodes."""
    c = code.upper()
    kinds = "".join("d" if ch in _DIGITS else "L" if ch in _LETTERS else "?" for ch in c)
    n = None
    if len(c) == 3:
        if kinds == "ddd":
            n = int(c)
        elif kinds == "Ldd":
            n = 1000 + _LETTERS.index(c[0]) * 100 + int(c[1:])
        elif kinds == "LLd":
            n = 3600 + (_LETTERS.index(c[0]) * 26 + _LETTERS.index(c[1])) * 10 + int(c[2])
        elif kinds == "LLL":
            n = 10360 + _LETTERS.index(c[0]) * 676 + _LETTERS.index(c[1]) * 26
            n += _LETTERS.index(c[2])
        elif kinds == "dLL":
            n = 27936 + int(c[0]) * 676 + _LETTERS.index(c[1]) * 26 + _LETTERS.index(c[2])
    if n is None or n > SITE_MAX:
        raise ValueError(f"site {code!r} is not a site count of the SIS table (000..7DV)")
    return n


def encode_site(n: int) -> str:
    """The 3-character M2020 file-name site field of site count ``n`` (0..32767)."""
    if not 0 <= n <= SITE_MAX:
        raise ValueError(f"site {n} outside 0..{SITE_MAX}")
    if n < 1000:
        return f"{n:03d}"
    if n < 3600:
        return _LETTERS[(n - 1000) // 100] + f"{(n - 1000) % 100:02d}"
    if n < 10360:
        k, d = divmod(n - 3600, 10)
        return _LETTERS[k // 26] + _LETTERS[k % 26] + str(d)
    if n < 27936:
        k = n - 10360
        return _LETTERS[k // 676] + _LETTERS[k // 26 % 26] + _LETTERS[k % 26]
    k = n - 27936
    return str(k // 676) + _LETTERS[k // 26 % 26] + _LETTERS[k % 26]


def decode_drive(code: str) -> int:
    """The drive count (0..65535) a 4-character M2020 file-name drive field encodes."""
    c = code.upper()
    kinds = "".join("d" if ch in _DIGITS else "L" if ch in _LETTERS else "?" for ch in c)
    n = None
    if len(c) == 4:
        if kinds == "dddd":
            n = int(c)
        elif kinds == "Lddd":
            n = 10000 + _LETTERS.index(c[0]) * 1000 + int(c[1:])
        elif kinds == "LLdd":
            n = 36000 + (_LETTERS.index(c[0]) * 26 + _LETTERS.index(c[1])) * 100 + int(c[2:])
    if n is None or n > DRIVE_MAX:
        raise ValueError(f"drive {code!r} is not a drive count of the SIS table (0000..LJ35)")
    return n


def encode_drive(n: int) -> str:
    """The 4-character M2020 file-name drive field of drive count ``n`` (0..65535)."""
    if not 0 <= n <= DRIVE_MAX:
        raise ValueError(f"drive {n} outside 0..{DRIVE_MAX}")
    if n < 10000:
        return f"{n:04d}"
    if n < 36000:
        return _LETTERS[(n - 10000) // 1000] + f"{(n - 10000) % 1000:03d}"
    k, d = divmod(n - 36000, 100)
    return _LETTERS[k // 26] + _LETTERS[k % 26] + f"{d:02d}"


def decode_version(code: str) -> int:
    """The product version (1..1035) of a 2-character M2020 file-name version field."""
    c = code.upper()
    if len(c) == 2 and c.isdigit() and c != "00":
        return int(c)
    if len(c) == 2 and c[0] in _LETTERS and c[1] in _ALNUM:
        return 100 + _LETTERS.index(c[0]) * 36 + _ALNUM.index(c[1])
    raise ValueError(f"version {code!r} is not a version of the SIS table (01..99, A0..ZZ)")


def encode_version(n: int) -> str:
    """The 2-character M2020 file-name version field of product version ``n`` (1..1035)."""
    if not 1 <= n <= VERSION_MAX:
        raise ValueError(f"version {n} outside 1..{VERSION_MAX} (01..ZZ)")
    if n < 100:
        return f"{n:02d}"
    k, j = divmod(n - 100, 36)
    return _LETTERS[k] + _ALNUM[j]


# -- Mars 2020 product ids ----------------------------------------------------------------
# (start, end, name, allowed characters) of the fixed fields; site, drive, version decoded
_M2020_FIELDS = (
    (0, 2, "camera", _LETTERS),
    (2, 3, "filter", _ALNUM + "_"),
    (3, 4, "special flag", _ALNUM + "_"),
    (4, 8, "sol", _DIGITS),
    (8, 9, "venue", _LETTERS + "_"),
    (9, 19, "SCLK", _DIGITS),
    (19, 20, "separator", "_"),
    (20, 23, "SCLK milliseconds", _DIGITS),
    (23, 26, "product type", _ALNUM),
    (26, 27, "geometry", "_LA"),
    (27, 28, "thumbnail flag", "TN"),
    (28, 31, "site", _ALNUM + "_"),
    (31, 35, "drive", _ALNUM + "_"),
    (35, 44, "sequence", _ALNUM + "_"),
    (44, 48, "camera-specific field", _ALNUM + "_"),
    (48, 49, "downsampling", _DIGITS),
    (49, 51, "compression", _ALNUM),
    (51, 52, "producer", _LETTERS + "_"),
)


@dataclass(frozen=True)
class M2020Id:
    """The fields of a Mars 2020 camera product id (``version`` None in the LID form)."""

    text: str  # upper case, as parsed
    camera: str
    filter: str
    special: str
    sol: int
    venue: str
    sclk: int
    sclk_ms: int
    product_type: str
    geometry: str  # "_" raw, "L"/"A" linearized
    thumbnail: bool
    site: int | None  # None: "___" (out of range)
    drive: int | None
    sequence: str
    camera_specific: str
    downsampling: int  # 2**n per axis
    compression: str
    producer: str
    version: int | None

    @property
    def base(self) -> str:
        """The id without its version (what a PDS4 LID carries, upper case)."""
        return self.text[:52]

    def file_id(self, version: int) -> str:
        """The file name stem of this product at ``version``."""
        return self.base + encode_version(version)

    @property
    def is_mastcamz(self) -> bool:
        return self.camera in _ZCAM_EYES

    @property
    def is_navcam(self) -> bool:
        return self.camera in _NCAM_EYES


def parse_m2020_id(product_id: str) -> M2020Id:
    """Parse a Mars 2020 camera product id (54 characters, or 52 without the version).

    Raises ``FetchError(product_id, reason)`` naming the character position and field.
    """
    t = product_id.strip().upper()
    if len(t) not in (52, 54):
        raise FetchError(product_id, f"{len(t)} characters, not 54 (or 52 without a version)")
    for start, end, name, allowed in _M2020_FIELDS:
        bad = [ch for ch in t[start:end] if ch not in allowed]
        if bad:
            raise FetchError(product_id, f"chars {start}-{end - 1} ({name}): {t[start:end]!r}")
    if t[:2] in _ZCAM_EYES and t[2] in _DIGITS and t[2] not in "01234567":
        raise FetchError(product_id, f"char 2 (filter): Mastcam-Z has no narrow-band {t[2]}")
    try:
        site = None if t[28:31] == "___" else decode_site(t[28:31])
        drive = None if t[31:35] == "____" else decode_drive(t[31:35])
        version = decode_version(t[52:54]) if len(t) == 54 else None
    except ValueError as exc:
        raise FetchError(product_id, str(exc)) from None
    return M2020Id(
        text=t, camera=t[:2], filter=t[2], special=t[3], sol=int(t[4:8]), venue=t[8],
        sclk=int(t[9:19]), sclk_ms=int(t[20:23]), product_type=t[23:26], geometry=t[26],
        thumbnail=t[27] == "T", site=site, drive=drive, sequence=t[35:44],
        camera_specific=t[44:48], downsampling=int(t[48]), compression=t[49:51],
        producer=t[51], version=version,
    )  # fmt: skip


class ZcamFields(TypedDict, total=False):
    """The ``Product`` fields a Mastcam-Z product id encodes (``zcam_fields``)."""

    sol: int
    instrument: str
    product_type: str
    site: int | None
    drive: int | None
    filter: str
    geometry: str
    thumbnail: bool
    version: int | None


def zcam_fields(product_id: str) -> ZcamFields:
    """Fields a Mastcam-Z product id encodes ({} when it is not one): sol, instrument,
    product_type, site, drive, filter, geometry, thumbnail, version (None in the LID form)."""
    try:
        pid = parse_m2020_id(product_id)
    except FetchError:
        return {}
    return zcam_fields_of(pid)


def zcam_fields_of(pid: M2020Id, camera: str = "zcam") -> ZcamFields:
    """``zcam_fields`` of an id already parsed ({} when it is not an id of the ``camera``
    family: ``zcam`` Mastcam-Z, ``ncam`` Navcam; ``M2020_CAMERAS``)."""
    eyes = M2020_CAMERAS[camera]
    if pid.camera not in eyes:
        return {}
    return {
        "sol": pid.sol,
        "instrument": eyes[pid.camera],
        "product_type": pid.product_type,
        "site": pid.site,
        "drive": pid.drive,
        "filter": pid.filter,
        "geometry": pid.geometry,
        "thumbnail": pid.thumbnail,
        "version": pid.version,
    }


# -- Curiosity MMM product ids ------------------------------------------------------------
_MMM = re.compile(
    r"^(?P<sol>\d{4})(?P<camera>M[LRHD])(?P<seq>\d{6})(?P<cmd>\d{3})(?P<count>\d{2})"
    r"(?P<cdpid>\d{5})(?P<type>[A-Z])(?P<gop>[0-9A-Z])(?P<version>[0-9A-Z])_(?P<proc>[A-Z0-9]{4})$"
)


def mmm_version(product_id: str) -> tuple[str, int] | None:
    """(id without its version character, version) of a Curiosity MMM product id, else None.

    The version is the character before ``_`` (0-9, then A-Z as 10-35)."""
    m = _MMM.match(product_id.strip().upper())
    if not m:
        return None
    text = m.group(0)
    at = m.start("version")
    return text[:at] + "?" + text[at + 1 :], _ALNUM.index(m["version"])


# -- products, skips, failures ------------------------------------------------------------
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
    filter: str | None = None  # M2020 filter character
    geometry: str | None = None  # M2020: "_" raw, "L"/"A" linearized
    thumbnail: bool | None = None
    version: int | None = None  # product version (M2020 file version, MSL version digit)
    volume: str | None = None  # MSL: the PDS3 volume whose index listed it


@dataclass(frozen=True)
class Skipped:
    """A product (or index row) left out on purpose: ``reason`` groups, ``detail`` is its own."""

    product_id: str
    url: str  # its label URL, or the index/inventory URL for a row that named no label
    stage: str  # index | label
    reason: str
    detail: str = ""


@dataclass(frozen=True)
class Failure:
    """One product, file or index row that could not be fetched or read."""

    product_id: str
    url: str
    stage: str  # index | label | image
    error: str
    message: str


@dataclass
class Listing:
    """What an index yields: products, the ones left out and the rows that failed."""

    products: list[Product] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)

    def extend(self, other: Listing) -> None:
        self.products.extend(other.products)
        self.skipped.extend(other.skipped)
        self.failures.extend(other.failures)


def skip_counts(skipped: Iterable[Skipped]) -> list[tuple[str, int]]:
    """(reason, count) of the skipped products, most frequent first."""
    return sorted(Counter(s.reason for s in skipped).items(), key=lambda kv: (-kv[1], kv[0]))


def _identity(p: Product) -> str:
    """What two listings of one product share: the id without its version."""
    if p.mission == "msl":
        parsed = mmm_version(p.product_id)
        return parsed[0] if parsed else p.product_id.upper()
    return p.product_id.upper()[:52] if len(p.product_id) == 54 else p.product_id.upper()


def newest_only(products: Iterable[Product]) -> tuple[list[Product], list[Skipped]]:
    """One product per identity: the newest version, then the newest volume (by name), wins.

    The others are ``Skipped``: "older version", "same product in a newer volume" or
    "listed twice"; the order of the first listing of each identity is kept."""
    groups: dict[str, list[Product]] = {}
    for p in products:
        groups.setdefault(_identity(p), []).append(p)
    kept, skipped = [], []
    for group in groups.values():
        best = max(group, key=lambda p: (p.version or 0, p.volume or ""))
        kept.append(best)
        for p in group:
            if p is best:
                continue
            if (p.version or 0) < (best.version or 0):
                reason = "older version"
            elif (p.volume or "") < (best.volume or ""):
                reason = "same product in a newer volume"
            else:
                reason = "listed twice"
            kept_as = best.product_id + (f" in {best.volume}" if best.volume else "")
            skipped.append(Skipped(p.product_id, p.label.url, "index", reason, f"kept {kept_as}"))
    return kept, skipped


@dataclass(frozen=True)
class ProductFilter:
    """Which products to fetch; None (or empty) means any. Sols inclusive (first, last).

    Thumbnails (an id's thumbnail flag) are left out unless ``thumbnails``."""

    sols: tuple[int, int] | None = None
    instruments: tuple[str, ...] = ()
    product_types: tuple[str, ...] = ()
    sites: tuple[int, ...] = ()
    drives: tuple[int, ...] = ()
    thumbnails: bool = False
    #: only these product ids (upper case; a Mars 2020 id may be given without its version):
    #: the ids a terrain-label folder names (``fetch.products.terrain_labels``); () = any
    product_ids: frozenset[str] = frozenset()

    def named(self, product_id: str) -> bool:
        """Whether ``product_id`` is one of ``product_ids`` (or none are given)."""
        if not self.product_ids:
            return True
        pid = product_id.upper()
        return pid in self.product_ids or pid[:-2] in self.product_ids

    def why_not(self, p: Product, *, unknown_ok: bool = True) -> tuple[str, str] | None:
        """None when ``p`` passes, else (reason, detail); a field the index does not give
        passes if ``unknown_ok``."""
        checks: list[tuple[str, object, tuple[object, ...]]] = [
            ("instrument", p.instrument, tuple(i.upper() for i in self.instruments)),
            ("product type", p.product_type, tuple(t.upper() for t in self.product_types)),
            ("site", p.site, self.sites),
            ("drive", p.drive, self.drives),
        ]
        if self.sols is not None:
            first, last = self.sols
            if p.sol is None:
                if not unknown_ok:
                    return "sol unknown", "neither index nor label gives it"
            elif not first <= p.sol <= last:
                return f"sol outside [{first}, {last}]", f"sol {p.sol}"
        for name, value, allowed in checks:
            if not allowed:
                continue
            if value is None:
                if not unknown_ok:
                    return f"{name} unknown", "neither index nor label gives it"
            elif value not in allowed:
                shown = ", ".join(str(a) for a in allowed)
                if name in ("site", "drive"):
                    return f"{name} not in [{shown}]", f"{name} {value}"
                return f"{name} {value} not in [{shown}]", f"{name} {value}"
        if p.thumbnail and not self.thumbnails:
            return "thumbnail", "fetch.products.thumbnails is false"
        if not self.named(p.product_id):
            return "not named by the terrain labels", f"{len(self.product_ids)} ids named"
        return None

    def wants(self, p: Product, *, unknown_ok: bool = True) -> bool:
        """True when ``p`` passes; a field the index does not give passes if ``unknown_ok``."""
        return self.why_not(p, unknown_ok=unknown_ok) is None

    @property
    def needs_label_fields(self) -> bool:
        """Whether site/drive filters may need the label (indexes may not list them)."""
        return bool(self.sites or self.drives)


def _sibling(label: RemoteFile, name: str, where: str) -> PurePosixPath:
    """The archive path of a file the label names (a bare file name in the label's folder)."""
    name = name.strip()
    if not name or PurePosixPath(name).name != name:
        raise FetchError(where, f"label names data file {name!r}, not a bare file name")
    return archive_path(str(label.rel.parent / name), where=where)


class LabelFacts(TypedDict, total=False):
    """What a product label says of its image (``pds3_label_facts``, ``pds4_label_facts``):
    the file name, size (bytes), MD5 (hex, lower case), ``Extent``, and the label's raw site
    and drive values (PDS3)."""

    image: str | None
    size: int | None
    md5: str | None
    extent: Extent | None
    site: object
    drive: object


def pds3_label_facts(path: Path) -> LabelFacts:
    """Image file name (``^IMAGE``), its ``Extent``, site and drive of a downloaded PDS3
    label, read by the bounded label loader (``validate.read_pds3_label``); ``FetchError``
    naming ``path``."""
    try:
        meta = read_pds3_label(path)
    except LabelError as exc:
        raise FetchError(path, f"unreadable PDS3 label: {label_fault(exc)}") from None
    pointer = meta.get("^IMAGE")
    names = meta.get("ROVER_MOTION_COUNTER_NAME")
    values = meta.get("ROVER_MOTION_COUNTER")
    if isinstance(pointer, (list, tuple)):
        pointer = pointer[0]
    facts: LabelFacts = {"image": str(pointer) if pointer else None}
    if pointer:
        facts["extent"] = pds3_extent(meta, str(pointer))
    if names and values and len(names) == len(values):
        counter = dict(zip((str(n).upper() for n in names), values, strict=True))
        facts["site"], facts["drive"] = counter.get("SITE"), counter.get("DRIVE")
    return facts


def pds4_label_facts(path: Path) -> LabelFacts:
    """Image file name, size (bytes), MD5 and ``Extent`` from a PDS4 label's
    File_Area_Observational, read by the bounded XML loader (``pds.xml.load_xml``);
    ``FetchError`` naming ``path``."""
    from mars_pairs.pds.common import read_bytes
    from mars_pairs.pds.xml import load_xml

    try:
        data, longer = read_bytes(path)
        if longer:
            raise LabelError(path, None, f"larger than {len(data)} bytes: not a label")
        root = load_xml(data, path)
    except LabelError as exc:
        raise FetchError(path, f"unreadable PDS4 label: {label_fault(exc)}") from None
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
    return {
        "image": name,
        "size": size_bytes,
        "md5": md5.strip().lower() if md5 else None,
        "extent": pds4_extent(root, name.strip()) if name else None,
    }


def with_label_facts(p: Product, label_path: Path, archive_root: str) -> Product:
    """The product with its image file (and site/drive from a PDS3 label when missing).

    The image's ``RemoteFile`` carries what the label says of its size (``extent``), so the
    content checks of the image (a download, or the cached file on a rerun) do not parse the
    label a second time."""
    where = p.label.url
    read = pds4_label_facts if p.mission == "m2020" else pds3_label_facts
    facts = read(label_path)
    name = facts.get("image")
    if not name:
        raise FetchError(where, "the label names no image file")
    rel = _sibling(p.label, str(name), where)
    image = RemoteFile(
        rel,
        join_url(archive_root, rel),
        facts.get("size"),
        facts.get("md5"),
        extent=facts.get("extent"),
    )
    site = p.site if p.site is not None else _int_or_none(facts.get("site"))
    drive = p.drive if p.drive is not None else _int_or_none(facts.get("drive"))
    return replace(p, image=image, site=site, drive=drive)


def _int_or_none(value: object) -> int | None:
    """``int(value)``, or None when ``value`` is None or no integer (what ``int`` refuses)."""
    if not isinstance(value, (str, bytes, SupportsInt, SupportsIndex)):
        return None
    try:
        return int(value)
    except (TypeError, ValueError):
        return None
