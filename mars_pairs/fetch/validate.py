"""What a downloaded archive file of each kind must look like, checked before it is kept.

``check_file(path, kind, label=..., where=url)`` raises ``ContentError`` (a ``FetchError``
naming ``where`` and the reason) when the bytes at ``path`` are not a file of ``kind``;
``check_content_type`` refuses an HTML answer for a file that is not HTML. The checks are pure
reads of the file (and of its local label where one describes it):

    pds3_label   ASCII ODL text: starts with PDS_VERSION_ID (or an ``NAME = value`` line) and
                 has an ``END`` line (a cut label has none)
    pds4_label   XML parsed by lxml without DTD, entities or network; root ``Product_*`` in
                 the PDS4 namespace
    places       CSV whose header has the PLACES columns (by name, any case), every row as wide
                 as the header, the last record ended by its newline
    inventory    PDS4 collection inventory: every record ``P,<lidvid>`` or ``S,<lidvid>``, the
                 last one ended; as many records as the collection label's ``Inventory/records``
    csv          any CSV: rectangular, the last record ended
    pds3_table   a PDS3 table (the index ``.TAB``): exactly offset + ROWS x ROW_BYTES bytes of
                 the object its label points at it
    jpeg, png    decoded in full by Pillow (every pixel; a JPEG also needs its end marker)
    img          a PDS3 or PDS4 ``.IMG`` beside its label: at least the bytes of every data
                 object the label places in it (PDS3 FIXED_LENGTH: exactly FILE_RECORDS x
                 RECORD_BYTES); without a label, only the transfer checks apply
    geotiff      opened by rasterio and every block of every band read
    data         no structure known: only refused when it is an HTML page

Every kind but ``html`` also refuses a body that is an HTML page. What a check cannot see: a
CSV cut exactly at a record boundary (no size is published for PLACES tables; the transfer's
Content-Length is the guard there), and the pixel values of a raw ``.IMG`` array (its size is).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from lxml import etree

from mars_pairs.errors import ArgumentError, ContentError, FetchError, ImageError, LabelError

KINDS = (
    "pds3_label",
    "pds4_label",
    "places",
    "inventory",
    "csv",
    "pds3_table",
    "jpeg",
    "png",
    "img",
    "geotiff",
    "html",
    "data",
)
_BY_SUFFIX = {
    ".lbl": "pds3_label",
    ".xml": "pds4_label",
    ".csv": "csv",
    ".tab": "pds3_table",
    ".jpg": "jpeg",
    ".jpeg": "jpeg",
    ".png": "png",
    ".img": "img",
    ".tif": "geotiff",
    ".tiff": "geotiff",
    ".htm": "html",
    ".html": "html",
}
#: PLACES columns present in every form of the table: Curiosity's localized_interp.csv (26
#: columns) and Perseverance's best_interp.csv (28), ../shared/real-archive and pds-samples
PLACES_COLUMNS = ("frame", "site", "drive", "northing", "easting", "elevation")
HTML_TYPES = ("text/html", "application/xhtml+xml")
PDS4_NS = "http://pds.nasa.gov/pds4/pds/v1"

#: PDS4 ``field_delimiter`` names (the PDS4 standard's Inventory class) -> the character.
DELIMITERS = {
    "Comma": ",",
    "Horizontal Tab": "\t",
    "Semicolon": ";",
    "Vertical Bar": "|",
}
LABEL_MAX_BYTES = 16 << 20  # a text label or table description larger than this is refused
_ODL_LINE = re.compile(rb"^\s*\^?[A-Za-z][A-Za-z0-9_:]*\s*=", re.MULTILINE)
_END_LINE = re.compile(rb"^[ \t]*END[ \t]*\r?$", re.MULTILINE)
_HTML_HEAD = re.compile(
    rb"^(\xef\xbb\xbf)?\s*<(!doctype\s+html|html[\s>]|head[\s>]|body[\s>])", re.I
)
_PDS4_BYTES = re.compile(r"(\d+)$")


def kind_of(rel: PurePosixPath | str) -> str:
    """The kind an archive file has by its name (``data`` when the suffix says nothing)."""
    return _BY_SUFFIX.get(PurePosixPath(str(rel)).suffix.lower(), "data")


def check_content_type(kind: str, content_type: str | None, where: object) -> None:
    """Refuse an HTML response (``Content-Type: text/html``) for any kind but ``html``."""
    media = (content_type or "").split(";")[0].strip().lower()
    if kind != "html" and media in HTML_TYPES:
        raise ContentError(where, f"the server answered with an HTML page ({media}), not {kind}")


def check_file(
    path: Path,
    kind: str,
    *,
    label: Path | None = None,
    where: object = None,
    extent: Extent | None = None,
) -> None:
    """Raise ``ContentError`` naming ``where`` (default: ``path``) unless ``path`` is a ``kind``.

    ``label``: the local label that describes the file (a PDS3 index label for its table, a
    product label for its ``.IMG``, the collection label for its inventory), or None.
    ``extent``: for an ``img``, what its label says of its size, read with the label's other
    facts (``pds3_extent``, ``pds4_extent``); None: read from ``label`` here.
    """
    where = path if where is None else where
    if kind not in KINDS:
        raise ArgumentError(f"unknown file kind {kind!r}; expected one of {KINDS}")
    with open(path, "rb") as fh:
        head = fh.read(1024)
    _refuse_html(head, kind, where)
    if kind == "img":
        _img(path, label, where, extent)
    else:
        _CHECKS[kind](path, label, where)


def _refuse_html(head: bytes, kind: str, where: object) -> None:
    """``ContentError`` naming ``where`` when the file's first bytes ``head`` are an HTML page
    (an error page served in place of the file) and ``kind`` is not html."""
    if kind != "html" and _HTML_HEAD.match(head):
        raise ContentError(where, f"an HTML page, not {kind} (starts {_show(head)})")


def quick_check(
    path: Path,
    kind: str,
    *,
    label: Path | None = None,
    where: object = None,
    extent: Extent | None = None,
) -> None:
    """The cheap part of ``check_file``, for a file already in the cache (run on every fetch).

    Reads at most the first and last KiB, except labels (checked whole: they are small): an
    HTML page, a JPEG without its end marker, a PNG without its IEND chunk, or an ``.IMG``
    shorter than its label's arrays (``extent``, else read from ``label``: the local label
    that describes it) is refused.
    """
    where = path if where is None else where
    if kind in ("pds3_label", "pds4_label"):
        check_file(path, kind, where=where)
        return
    if kind == "img":
        _img(path, label, where, extent)  # a stat (and the label): no image bytes read
    with open(path, "rb") as fh:
        head = fh.read(1024)
        fh.seek(max(0, path.stat().st_size - 1024))
        tail = fh.read()
    _refuse_html(head, kind, where)
    if kind == "jpeg" and not tail.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise ContentError(where, "JPEG has no end marker (cut short?)")
    if kind == "png" and not tail.endswith(b"IEND\xaeB`\x82"):
        raise ContentError(where, "PNG has no IEND chunk (cut short?)")


# -- text ----------------------------------------------------------------------------------
def _small(path: Path, what: str, where: object) -> bytes:
    size = path.stat().st_size
    if size > LABEL_MAX_BYTES:
        raise ContentError(where, f"{size} bytes is too large for a {what}")
    return path.read_bytes()


def _pds3_label(path: Path, label: Path | None, where: object) -> None:
    data = _small(path, "PDS3 label", where)
    if not data.isascii():
        at = next(i for i, b in enumerate(data) if b > 0x7F)
        raise ContentError(where, f"not a PDS3 label: non-ASCII byte 0x{data[at]:02x} at {at}")
    text = data.lstrip()
    if not (text.startswith(b"PDS_VERSION_ID") or _ODL_LINE.match(text)):
        raise ContentError(where, f"not a PDS3 label: starts {_show(data)}")
    if not _END_LINE.search(data):
        raise ContentError(where, "not a complete PDS3 label: no END line (cut short?)")


def _pds4_root(path: Path, where: object, what: str = "PDS4 label") -> Any:
    from mars_pairs.pds.xml import load_xml

    try:
        root = load_xml(_small(path, what, where), path)
    except LabelError as exc:
        raise ContentError(where, exc.reason) from None
    local = str(root.tag).rsplit("}", 1)[-1]
    if not local.startswith("Product_"):
        raise ContentError(where, f"not a PDS4 product: root element is {local}")
    return root


def _pds4_label(path: Path, label: Path | None, where: object) -> None:
    _pds4_root(path, where)


def _records(path: Path, where: object, delimiter: str = ",") -> list[list[str]]:
    """The CSV records of a text file whose last record is ended by a newline."""
    data = path.read_bytes()
    if not data:
        raise ContentError(where, "empty file")
    if not data.endswith(b"\n"):
        raise ContentError(where, "the last record has no line end (cut short?)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ContentError(where, f"not UTF-8 text: byte {exc.start}") from None
    return [row for row in csv.reader(io.StringIO(text), delimiter=delimiter) if row]


def _rectangular(rows: list[list[str]], where: object) -> None:
    width = len(rows[0])
    for number, row in enumerate(rows[1:], 2):
        if len(row) != width:
            raise ContentError(
                where, f"line {number}: {len(row)} fields, the header has {width} (cut short?)"
            )


def _csv(path: Path, label: Path | None, where: object) -> None:
    rows = _records(path, where)
    if not rows:
        raise ContentError(where, "no records")
    _rectangular(rows, where)


def _places(path: Path, label: Path | None, where: object) -> None:
    rows = _records(path, where)
    if not rows:
        raise ContentError(where, "no header")
    header = {c.strip().lower() for c in rows[0]}
    missing = [c for c in PLACES_COLUMNS if c not in header]
    if missing:
        raise ContentError(
            where, f"not a PLACES table: header lacks {', '.join(missing)} ({_show(path)})"
        )
    if len(rows) < 2:
        raise ContentError(where, "a PLACES table without rows")
    _rectangular(rows, where)


def _inventory(path: Path, label: Path | None, where: object) -> None:
    delimiter, expected = ",", None
    if label is not None:
        delimiter, expected = _inventory_facts(label, where)
    rows = _records(path, where, delimiter)
    for number, row in enumerate(rows, 1):
        if row[0].strip().upper() not in ("P", "S") or len(row) < 2:
            shown = delimiter.join(row)[:60]
            raise ContentError(where, f"record {number}: expected 'P,<lidvid>', got {shown!r}")
    if expected is not None and len(rows) != expected:
        raise ContentError(
            where, f"{len(rows)} records, the collection label {label} says {expected}"
        )


def delimiter_of(root: etree._Element, where: object) -> str:
    """The field delimiter a parsed collection label gives its inventory (comma when it names
    none); ``FetchError`` naming ``where`` for one that is not a PDS4 delimiter name."""
    text = root.findtext(
        "pds:File_Area_Inventory/pds:Inventory/pds:field_delimiter", namespaces={"pds": PDS4_NS}
    )
    if text is None:
        return ","
    if text.strip() not in DELIMITERS:
        raise FetchError(where, f"Inventory/field_delimiter: unknown {text!r}")
    return DELIMITERS[text.strip()]


def _inventory_facts(label: Path, where: object) -> tuple[str, int | None]:
    """(delimiter, records) of the collection label's ``File_Area_Inventory/Inventory``."""
    about = f"{where} (its collection label {label})"
    root = _pds4_root(label, about, "collection label")
    try:
        delimiter = delimiter_of(root, label)
    except FetchError as exc:
        raise ContentError(about, exc.reason) from None
    inv = root.find(f"{{{PDS4_NS}}}File_Area_Inventory/{{{PDS4_NS}}}Inventory")
    records = "" if inv is None else (inv.findtext(f"{{{PDS4_NS}}}records") or "").strip()
    return delimiter, int(records) if records.isdigit() else None


# -- tables and arrays described by a label ------------------------------------------------
def read_pds3_label(path: Path) -> Mapping[str, Any]:
    """The PDS3 label in the file at ``path``, parsed by the bounded loader of the label
    readers (``pds.pds3.load_label``: at most ``pds.common.MAX_LABEL_BYTES`` read, then a
    structural pre-scan that refuses an oversized or pathological label before pdr parses it),
    so that parsing is bounded in time and memory on a fetch worker thread too.

    Raises ``LabelError`` naming ``path`` (and the keyword at fault, if any).
    """
    from mars_pairs.pds.common import read_bytes
    from mars_pairs.pds.pds3 import load_label

    data, longer = read_bytes(path)
    return load_label(data, path, longer)


def label_fault(exc: LabelError) -> str:
    """What a ``LabelError`` says is wrong, without its path: ``[FIELD: ]reason``."""
    return f"{exc.field}: {exc.reason}" if exc.field else exc.reason


def _pds3_meta(label: Path, where: object) -> Mapping[str, Any]:
    try:
        return read_pds3_label(label)
    except LabelError as exc:
        raise ContentError(where, f"its label {label} is unreadable: {label_fault(exc)}") from None


def _pointer_target(meta: Any, name: str) -> tuple[str, Any] | None:
    """(object name, pointer value) of the ``^OBJECT`` pointer that names file ``name``."""
    for key, value in meta.items():
        if not str(key).startswith("^"):
            continue
        target = value[0] if isinstance(value, (list, tuple)) else value
        if str(target).strip().upper() == name.upper():
            return str(key)[1:], value
    return None


def _pds3_offset(pointer: Any, meta: Any) -> int | None:
    """Bytes before the object in its file: ``"F"`` -> 0, ``("F", n)`` -> (n - 1) records."""
    if isinstance(pointer, str):
        return 0
    if isinstance(pointer, (list, tuple)) and len(pointer) == 2 and isinstance(pointer[1], int):
        record = meta.get("RECORD_BYTES")
        return (pointer[1] - 1) * record if isinstance(record, int) else None
    return None


def _pds3_table(path: Path, label: Path | None, where: object) -> None:
    if label is None:
        return
    meta = _pds3_meta(label, where)
    found = _pointer_target(meta, path_name(path))
    if found is None:
        raise ContentError(where, f"its label {label} points at no file {path_name(path)}")
    obj, pointer = found
    table = meta.get(obj)
    rows = row_bytes = None
    if table is not None and hasattr(table, "get"):
        rows, row_bytes = table.get("ROWS"), table.get("ROW_BYTES")
    offset = _pds3_offset(pointer, meta)
    if not (isinstance(rows, int) and isinstance(row_bytes, int)) or offset is None:
        return
    expected, size = offset + rows * row_bytes, path.stat().st_size
    if size != expected:
        raise ContentError(
            where,
            f"{size} bytes, its label {label} says {expected} ({obj}: {rows} ROWS x "
            f"{row_bytes} ROW_BYTES)",
        )


@dataclass(frozen=True)
class Extent:
    """What a label says of the size of its data file: ``size`` bytes (None: it does not say),
    exactly (``exact``: PDS3 FIXED_LENGTH records) or at least (the end of its last data
    object); ``what`` says where the number comes from."""

    size: int | None
    what: str = ""
    exact: bool = False


def label_extent(label: Path, name: str, where: object) -> Extent:
    """The ``Extent`` the local label file ``label`` gives its data file ``name`` (parses it;
    ``ContentError`` naming ``where`` when the label is unreadable)."""
    if label.suffix.lower() == ".xml":
        return pds4_extent(_pds4_root(label, f"{where} (its label {label})"), name)
    return pds3_extent(_pds3_meta(label, where), name)


def _img(path: Path, label: Path | None, where: object, extent: Extent | None = None) -> None:
    if extent is None:
        if label is None:
            return
        extent = label_extent(label, path_name(path), where)
    if extent.size is None:
        return
    size = path.stat().st_size
    said = "its label" if label is None else f"its label {label}"
    if extent.exact and size != extent.size:
        raise ContentError(where, f"{size} bytes, {said} says {extent.what}")
    if size < extent.size:
        raise ContentError(where, f"{size} bytes, {said} needs {extent.what} (cut short?)")


def pds3_extent(meta: Mapping[str, Any], name: str) -> Extent:
    """The ``Extent`` a parsed PDS3 label (``read_pds3_label``) gives its data file ``name``:
    exactly FILE_RECORDS x RECORD_BYTES for FIXED_LENGTH records, else at least the end of the
    object whose pointer names the file."""
    records, record_bytes = meta.get("FILE_RECORDS"), meta.get("RECORD_BYTES")
    if (
        meta.get("RECORD_TYPE") == "FIXED_LENGTH"
        and isinstance(records, int)
        and isinstance(record_bytes, int)
    ):
        total = records * record_bytes
        what = f"exactly {total} (FILE_RECORDS {records} x RECORD_BYTES {record_bytes})"
        return Extent(total, what, exact=True)
    found = _pointer_target(meta, name)
    if found is None:
        return Extent(None)
    obj, pointer = found
    image, offset = meta.get(obj), _pds3_offset(pointer, meta)
    if image is None or not hasattr(image, "get") or offset is None:
        return Extent(None)
    dims = [image.get(k, 1) for k in ("LINES", "LINE_SAMPLES", "BANDS", "SAMPLE_BITS")]
    if not all(isinstance(d, int) for d in dims):
        return Extent(None)
    lines, samples, bands, bits = dims
    prefix = image.get("LINE_PREFIX_BYTES", 0) + image.get("LINE_SUFFIX_BYTES", 0)
    total = offset + lines * bands * (samples * bits // 8 + prefix)
    return Extent(total, f"{total} ({obj} at byte {offset})")


def pds4_extent(root: Any, name: str) -> Extent:
    """The ``Extent`` a parsed PDS4 label gives its data file ``name``: at least the end of the
    furthest data object (arrays, headers, tables) of its ``File_Area_Observational``."""
    ns = f"{{{PDS4_NS}}}"
    best, what = None, ""
    for area in root.iter(f"{ns}File_Area_Observational"):
        if (area.findtext(f"{ns}File/{ns}file_name") or "").strip() != name:
            continue
        for obj in area:
            if not isinstance(obj.tag, str):
                continue
            local = obj.tag.removeprefix(ns)
            offset = _int_text(obj.findtext(f"{ns}offset"))
            if offset is None:
                continue
            length = _pds4_object_bytes(obj, local, ns)
            if length is not None and (best is None or offset + length > best):
                best, what = offset + length, f"{offset + length} ({local} at byte {offset})"
    return Extent(best, what)


def _pds4_object_bytes(obj: Any, local: str, ns: str) -> int | None:
    if local.startswith("Array"):
        dtype = (obj.findtext(f"{ns}Element_Array/{ns}data_type") or "").strip()
        width = _pds4_type_bytes(dtype)
        axes = [_int_text(a.findtext(f"{ns}elements")) for a in obj.iter(f"{ns}Axis_Array")]
        counts = [a for a in axes if a is not None]
        if width is None or not axes or len(counts) < len(axes):
            return None
        return width * math.prod(counts)
    if local in ("Header", "Table_Delimited", "Stream_Text", "Encoded_Image"):
        return _int_text(obj.findtext(f"{ns}object_length"))
    if local in ("Table_Binary", "Table_Character"):
        records = _int_text(obj.findtext(f"{ns}records"))
        length = _int_text(obj.findtext(f"{ns}Record_Binary/{ns}record_length"))
        length = length or _int_text(obj.findtext(f"{ns}Record_Character/{ns}record_length"))
        return records * length if records is not None and length is not None else None
    return None


def _pds4_type_bytes(dtype: str) -> int | None:
    """Bytes of one element of a PDS4 ``data_type`` (SignedMSB2 -> 2, IEEE754LSBDouble -> 8)."""
    if dtype in ("SignedByte", "UnsignedByte"):
        return 1
    if dtype.endswith("Single"):
        return 4
    if dtype.endswith("Double"):
        return 8
    m = _PDS4_BYTES.search(dtype)
    return int(m[1]) if m else None


def _int_text(text: str | None) -> int | None:
    text = (text or "").strip()
    return int(text) if text.isdigit() else None


# -- images and rasters --------------------------------------------------------------------
def _picture(path: Path, kind: str, where: object) -> None:
    from mars_pairs.pipeline.sample.ground import decoded_size

    data = path.read_bytes()
    magic = b"\xff\xd8" if kind == "jpeg" else b"\x89PNG\r\n\x1a\n"
    if not data.startswith(magic):
        raise ContentError(where, f"not a {kind.upper()} (starts {_show(data[:32])})")
    try:
        decoded_size(data, Path(str(where)))
    except ImageError as exc:
        raise ContentError(where, str(exc).split(": ", 1)[-1]) from None


def _jpeg(path: Path, label: Path | None, where: object) -> None:
    _picture(path, "jpeg", where)


def _png(path: Path, label: Path | None, where: object) -> None:
    _picture(path, "png", where)


def _geotiff(path: Path, label: Path | None, where: object) -> None:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            for band in ds.indexes:
                for _, window in ds.block_windows(band):
                    ds.read(band, window=window)
    except (RasterioError, OSError) as exc:
        raise ContentError(where, f"not a readable GeoTIFF: {_first_line(exc)}") from None


def _nothing(path: Path, label: Path | None, where: object) -> None:
    return None


_CHECKS = {
    "pds3_label": _pds3_label,
    "pds4_label": _pds4_label,
    "places": _places,
    "inventory": _inventory,
    "csv": _csv,
    "pds3_table": _pds3_table,
    "jpeg": _jpeg,
    "png": _png,
    "img": _img,
    "geotiff": _geotiff,
    "html": _nothing,
    "data": _nothing,
}


def path_name(path: Path) -> str:
    """The archive file name of a cache file or of its ``.part`` (``X.IMG.part`` -> X.IMG)."""
    return path.name.removesuffix(".part")


def _show(data: bytes | Path) -> str:
    if isinstance(data, Path):
        with open(data, "rb") as fh:
            data = fh.read(60)
    text = data[:40].decode("ascii", "replace").replace("\r", "").replace("\n", " ")
    return repr(text)


def _first_line(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text[:200]
