"""PDS4 XML access: safe parsing, elements by namespace and local name, frame references.

Elements are found by namespace and local name, never by position. Frames are identified by
``geom:coordinate_space_frame_type`` or, for ``Local_Internal_Reference`` links, by the
referenced ``local_identifier`` (e.g. ``ROVER_NAV_FRAME_3_1950_4_...``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from lxml import etree

from mars_pairs.errors import LabelError
from mars_pairs.pds.common import Fields

NS = {
    "pds": "http://pds.nasa.gov/pds4/pds/v1",
    "geom": "http://pds.nasa.gov/pds4/geom/v1",
    "img": "http://pds.nasa.gov/pds4/img/v1",
    "img_surface": "http://pds.nasa.gov/pds4/img_surface/v1",
    "mars2020": "http://pds.nasa.gov/pds4/mission/mars2020/v1",
    "msn": "http://pds.nasa.gov/pds4/msn/v1",
}
_FRAME_ID_RE = re.compile(r"([A-Z0-9_]*?_FRAME)(?:_|$)")
#: Most markup characters ("<": tags, comments, declarations) a label may hold. The real
#: Mastcam-Z labels in ../shared/pds-samples/m2020 (87 KB) hold 2,328, in 1,158 elements of
#: depth at most 9; 1,000,000 empty elements (4 MB) parse in ~0.4 s into ~126 MB of tree.
#: Depth is bounded by libxml2 itself at 256 while ``huge_tree`` is off, as is the size of one
#: text node (10 MB, beyond the 4 MiB file limit).
MAX_XML_MARKUP = 100_000


def q(prefix: str, local: str) -> str:
    """Clark notation ``{namespace}local`` for a prefix of ``NS``."""
    return f"{{{NS[prefix]}}}{local}"


def name_of(prefix: str, local: str) -> str:
    """The element's name as written in labels (core PDS elements without prefix)."""
    return local if prefix == "pds" else f"{prefix}:{local}"


def load_xml(data: bytes, path: Path) -> etree._Element:
    """Parse the XML (no network, no entities, libxml2's default depth and text limits, at most
    ``MAX_XML_MARKUP`` tags); any failure is a LabelError."""
    markup = data.count(b"<")
    if markup > MAX_XML_MARKUP:
        reason = f"{markup:,} tags (at most {MAX_XML_MARKUP:,}): not a label"
        raise LabelError(path, None, reason)
    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        remove_comments=True,
        remove_pis=True,
        huge_tree=False,
    )
    try:
        root = etree.fromstring(data, parser)
    except Exception as exc:  # lxml raises XMLSyntaxError, ValueError, ... on bad input
        reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise LabelError(path, None, f"not a readable PDS4 label: {reason}") from exc
    docinfo = root.getroottree().docinfo if root is not None else None
    if docinfo is not None and (docinfo.doctype or docinfo.internalDTD is not None):
        # PDS4 labels have no DOCTYPE; one here can only declare entities (external files,
        # billion laughs): none is resolved or expanded, and the label is refused
        raise LabelError(path, None, "not a PDS4 label: XML with a DOCTYPE / entity declarations")
    if root is None or not isinstance(root.tag, str) or not root.tag.startswith(f"{{{NS['pds']}}}"):
        raise LabelError(path, None, "not a PDS4 product (root is not in the PDS4 namespace)")
    return root


class XmlLabel:
    """Element and frame access on one parsed PDS4 label."""

    def __init__(self, root: etree._Element, path: Path) -> None:
        self.root = root
        self.path = path
        self.f = Fields(path)
        self.frames_by_id = self._definition_ids()

    # -- element access -------------------------------------------------------------------------
    def all(
        self, prefix: str, local: str, under: etree._Element | None = None
    ) -> list[etree._Element]:
        """Every element ``prefix:local`` under ``under`` (default: the whole label)."""
        return list((self.root if under is None else under).iter(q(prefix, local)))

    def first(
        self, prefix: str, local: str, under: etree._Element | None = None
    ) -> etree._Element | None:
        """The first such element outside commanded parameters, or None."""
        for el in (self.root if under is None else under).iter(q(prefix, local)):
            if not is_commanded(el):
                return el
        return None

    def child(self, el: etree._Element, prefix: str, local: str) -> etree._Element | None:
        """The direct child ``prefix:local`` of ``el``, or None; LabelError when two such
        values (leaf elements) disagree: which one is meant cannot be told."""
        found = el.findall(q(prefix, local))
        if len(found) > 1 and len(found[0]) == 0:
            texts = {self.text(x) for x in found}
            if len(texts) > 1:
                shown = ", ".join(sorted(texts))[:80]
                self.f.fail(
                    name_of(prefix, local),
                    f"given {len(found)} times with different values ({shown})",
                )
        return found[0] if found else None

    def need(
        self, el: etree._Element | None, prefix: str, local: str, where: str = ""
    ) -> etree._Element:
        """The element itself, or a LabelError saying it is missing."""
        if el is None:
            suffix = f" in {where}" if where else ""
            self.f.fail(name_of(prefix, local), f"required element missing{suffix}")
        return el

    def text(self, el: etree._Element) -> str:
        """The element's own text, stripped."""
        return (el.text or "").strip()

    def number(self, el: etree._Element, prefix: str, local: str) -> float:
        """A required finite number."""
        return self.f.number(self.text(el), name_of(prefix, local))

    def xyz(self, vector: etree._Element, prefix: str, local: str) -> np.ndarray:
        """The x_*, y_*, z_* children of a geom vector element."""
        values = []
        named = [(local_name(c), c) for c in vector if isinstance(c.tag, str)]
        for axis in ("x", "y", "z"):
            found = [c for name, c in named if name.startswith(f"{axis}_")]
            if len(found) != 1:
                self.f.fail(
                    name_of(prefix, local), f"expected one {axis}_* component, got {len(found)}"
                )
            values.append(self.f.number(self.text(found[0]), f"geom:{local_name(found[0])}"))
        return np.array(values, dtype=np.float64)

    # -- frames -----------------------------------------------------------------------------
    def _definition_ids(self) -> dict[str, str]:
        """local_identifier -> frame name of every Coordinate_Space_Definition."""
        ids: dict[str, str] = {}
        for defn in self.all("geom", "Coordinate_Space_Definition"):
            frame = self.definition_frame(defn)
            for ident in defn.findall(q("pds", "local_identifier")):
                if frame and self.text(ident):
                    ids[self.text(ident)] = frame
        return ids

    def definition_frame(self, defn: etree._Element) -> str | None:
        """The frame a Coordinate_Space_Definition defines (its Coordinate_Space_Present)."""
        present = self.child(defn, "geom", "Coordinate_Space_Present")
        if present is not None:
            kind = self.first("geom", "coordinate_space_frame_type", present)
            if kind is not None and self.text(kind):
                return self.text(kind).upper()
        for ident in defn.findall(q("pds", "local_identifier")):
            frame = frame_from_identifier(self.text(ident))
            if frame:
                return frame
        return None

    def reference_frame(self, owner: etree._Element) -> str | None:
        """The frame named by the direct Coordinate_Space_Reference child of ``owner``."""
        ref = self.child(owner, "geom", "Coordinate_Space_Reference")
        if ref is None:
            return None
        kind = self.first("geom", "coordinate_space_frame_type", ref)
        if kind is not None and self.text(kind):
            return self.text(kind).upper()
        link = self.first("pds", "local_identifier_reference", ref)
        if link is not None and self.text(link):
            target = self.text(link)
            return self.frames_by_id.get(target) or frame_from_identifier(target)
        return None


def local_name(el: etree._Element) -> str:
    """The element's local name."""
    return etree.QName(el).localname


def is_commanded(el: etree._Element) -> bool:
    """True if ``el`` sits inside commanded (requested, not actual) parameters."""
    return next(el.iterancestors("{*}Commanded_Parameters"), None) is not None


def frame_from_identifier(ident: str) -> str | None:
    """'ROVER_NAV_FRAME_3_1950_4_...' -> 'ROVER_NAV_FRAME'; None if no *_FRAME prefix."""
    match = _FRAME_ID_RE.match(ident.strip().upper())
    return match.group(1) if match else None
