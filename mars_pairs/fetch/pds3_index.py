"""Curiosity PDS3 volumes: ``<volume>/INDEX/RDRINDEX.TAB`` (or EDRINDEX) read through its label.

pdr reads the index label and its table; columns are found by the names the label gives them
(``PATH_NAME``, ``FILE_NAME``, ``PRODUCT_ID``, ``PLANET_DAY_NUMBER``, ``INSTRUMENT_ID``, ...),
never by position, so a volume whose index orders or sizes its columns differently reads the
same. A column the filters need and the index lacks is left unknown (site/drive are then read
from each product's label).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from mars_pairs.errors import FetchError, LabelError
from mars_pairs.fetch.cache import archive_path, join_url
from mars_pairs.fetch.download import Downloader, RemoteFile
from mars_pairs.fetch.products import Failure, Listing, Product, mmm_version
from mars_pairs.fetch.validate import label_fault, read_pds3_label

# field -> index column names that carry it, in order of preference
COLUMNS: dict[str, tuple[str, ...]] = {
    "path": ("PATH_NAME",),
    "file": ("FILE_NAME",),
    "spec": ("FILE_SPECIFICATION_NAME",),
    "product_id": ("PRODUCT_ID",),
    "sol": ("PLANET_DAY_NUMBER", "SOL_NUMBER", "SOL"),
    "instrument": ("INSTRUMENT_ID",),
    "product_type": ("PRODUCT_TYPE",),
    "site": ("ROVER_MOTION_COUNTER_SITE", "SITE_NUMBER", "SITE"),
    "drive": ("ROVER_MOTION_COUNTER_DRIVE", "DRIVE_NUMBER", "DRIVE"),
}


def index_files(volume: str, index: str = "RDRINDEX") -> tuple[PurePosixPath, PurePosixPath]:
    """Archive paths of a volume's index label and table."""
    vol = archive_path(volume, where="fetch.products.volumes")
    return vol / "INDEX" / f"{index}.LBL", vol / "INDEX" / f"{index}.TAB"


@dataclass(frozen=True)
class VolumeIndex:
    """A volume's index as fetched: the table, its label in the cache and the table's URL."""

    table: Any  # a pandas DataFrame
    label: Path
    url: str


def fetch_index(dl: Downloader, archive: str, volume: str, index: str = "RDRINDEX") -> VolumeIndex:
    """Fetch a volume's index label and table into ``dl``'s cache and read the table.

    Both are mutable archive tables (revalidated on every fetch: a re-released index replaces
    the cached one); the table is checked against its label (``validate``: exactly offset +
    ROWS x ROW_BYTES bytes) before it is kept. ``archive``: the root URL of the volumes.
    Raises ``FetchError`` naming the file."""
    lbl, tab = index_files(volume, index)
    url = join_url(archive, tab)
    dl.fetch(RemoteFile(lbl, join_url(archive, lbl), mutable=True))
    label = dl.cache.path(lbl)
    dl.fetch(RemoteFile(tab, url, mutable=True, label=label))
    return VolumeIndex(read_index_table(label), label, url)


def read_index_table(label_path: Path) -> Any:
    """The index table (a pandas DataFrame) that ``label_path`` describes, read by pdr.

    The label passes the bounded label loader (``validate.read_pds3_label``) before pdr is
    given it, so an oversized or pathological label is a ``FetchError`` naming it, not a hang.
    """
    import pdr

    try:
        read_pds3_label(label_path)
    except LabelError as exc:
        raise FetchError(label_path, f"unreadable index label: {label_fault(exc)}") from None
    try:
        data = pdr.read(str(label_path))
        keys = list(data.keys())
        names = [k for k in keys if k.endswith("TABLE")] or [k for k in keys if k != "LABEL"]
        for name in names:
            table = data[name]
            if hasattr(table, "columns"):
                return table
    except Exception as exc:  # pdr raises many types on damaged tables
        raise FetchError(label_path, f"unreadable index: {type(exc).__name__}: {exc}") from None
    raise FetchError(label_path, "no TABLE object in the index label")


def _column(table: Any, field: str) -> str | None:
    for name in COLUMNS[field]:
        if name in table.columns:
            return name
    return None


def _text(value: Any) -> str:
    return str(value).strip().strip('"').strip()


def _int(value: Any) -> int | None:
    try:
        return int(str(value).strip())
    except (TypeError, ValueError):
        return None


def products_from_index(
    table: Any,
    volume: str,
    archive_root: str,
    where: str,
    mission: str = "msl",
    index_url: str | None = None,
) -> Listing:
    """One Product per row; label paths are relative to the volume (``<volume>/<PATH><FILE>``).

    A row whose path escapes the archive (``..``, a backslash, an absolute path) or is empty
    is a ``Failure`` (stage ``index``) naming the row number and path; the other rows go on.
    The version of an MMM product id (``...E01_DRCL``: 1) is the product's ``version``."""
    cols = {f: _column(table, f) for f in COLUMNS}
    if not (cols["path"] and cols["file"]) and not cols["spec"]:
        raise FetchError(
            where,
            f"no PATH_NAME + FILE_NAME (or FILE_SPECIFICATION_NAME) column: {list(table.columns)}",
        )
    url = index_url or where
    vol = archive_path(volume, where=where)
    out = Listing()
    for number, row in enumerate(table.to_dict("records"), 1):
        if cols["spec"] and not (cols["path"] and cols["file"]):
            inside = _text(row[cols["spec"]])
        else:
            inside = _text(row[cols["path"]]).rstrip("/") + "/" + _text(row[cols["file"]])
        product_id = _text(row[cols["product_id"]]) if cols["product_id"] else ""
        try:
            rel = vol / archive_path(inside, where=f"{url}: row {number}")
        except FetchError as exc:
            out.failures.append(
                Failure(product_id or inside, url, "index", "FetchError", f"row {number}: "
                        + exc.reason)
            )  # fmt: skip
            continue
        product_id = product_id or rel.stem
        ptype = _text(row[cols["product_type"]]) if cols["product_type"] else None
        if not ptype and "_" in product_id:
            ptype = product_id.rsplit("_", 1)[1]  # 1429MR..._DRCL -> DRCL
        parsed = mmm_version(product_id)
        out.products.append(
            Product(
                mission=mission,
                product_id=product_id,
                label=RemoteFile(rel, join_url(archive_root, rel)),
                sol=_int(row[cols["sol"]]) if cols["sol"] else None,
                instrument=_text(row[cols["instrument"]]).upper() if cols["instrument"] else None,
                product_type=ptype.upper() if ptype else None,
                site=_int(row[cols["site"]]) if cols["site"] else None,
                drive=_int(row[cols["drive"]]) if cols["drive"] else None,
                version=parsed[1] if parsed else None,
                volume=volume,
            )
        )
    return out
