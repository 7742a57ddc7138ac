"""Perseverance Mastcam-Z PDS4 labels (XML) -> Observation, parsed with ``lxml``.

Elements are found by namespace and local name, never by position. Frames are identified by
``geom:coordinate_space_frame_type`` or, for ``Local_Internal_Reference`` links, by the
referenced ``local_identifier`` (e.g. ``ROVER_NAV_FRAME_3_1950_4_...``). Required: the product
id, instrument, sol, SITE/DRIVE motion counter, image size and the camera model; optional
fields (rover pose, SITE_FRAME pointing, FOV, time) are None when absent and a LabelError when
present but malformed.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from lxml import etree

from mars_pairs.errors import LabelError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.pds.common import PathLike, image_beside, read_bytes
from mars_pairs.pds.xml import (
    XmlLabel,
    load_xml,
    local_name,
    name_of,
)

MISSION = "m2020"
ROVER_FRAME = "ROVER_NAV_FRAME"
SITE_FRAME = "SITE_FRAME"
_MODELS = {"CAHVORE_Model": "CAHVORE", "CAHVOR_Model": "CAHVOR", "CAHV_Model": "CAHV"}
_VECTORS = {
    "c": "Vector_Center",
    "a": "Vector_Axis",
    "h": "Vector_Horizontal",
    "v": "Vector_Vertical",
    "o": "Vector_Optical",
}
_PRODUCT_PREFIX_INSTRUMENT = {  # product id prefixes of the Mars 2020 mast and body cameras
    "ZL": "MCZ_LEFT", "ZR": "MCZ_RIGHT", "NL": "NAVCAM_LEFT", "NR": "NAVCAM_RIGHT",
    "FL": "FRONT_HAZCAM_LEFT", "FR": "FRONT_HAZCAM_RIGHT",
    "RL": "REAR_HAZCAM_LEFT", "RR": "REAR_HAZCAM_RIGHT",
}  # fmt: skip


def read_pds4(path: PathLike) -> Observation:
    """Read a Perseverance Mastcam-Z PDS4 label into an Observation (LabelError on any fault)."""
    label_path = Path(path)
    data, longer = read_bytes(label_path)
    if longer:
        raise LabelError(label_path, None, f"larger than {len(data)} bytes: not a label")
    return parse_pds4(data, label_path)


def parse_pds4(data: bytes, path: Path) -> Observation:
    """Parse the bytes of the PDS4 label at ``path``."""
    reader = _Reader(load_xml(data, path), path)
    return reader.observation()


class _Reader(XmlLabel):
    """Field extraction from one parsed Mastcam-Z PDS4 label."""

    # -- fields -----------------------------------------------------------------------------
    def observation(self) -> Observation:
        """All fields, required ones first."""
        product_id = self.product_id()
        camera_params = self.need(
            self.first("geom", "Camera_Model_Parameters"), "geom", "Camera_Model_Parameters"
        )
        rmc = self.motion_counter(camera_params)
        width, height = self.image_size()
        offset, quaternion = self.rover_pose(rmc)
        azimuth, elevation = self.pointing()
        return Observation(
            label_path=self.path,
            mission=MISSION,
            product_id=product_id,
            instrument=self.instrument(product_id),
            sol=self.sol(),
            rmc=rmc,
            width=width,
            height=height,
            camera=self.camera(camera_params),
            rover_offset_m=offset,
            rover_quaternion=quaternion,
            azimuth_deg=azimuth,
            elevation_deg=elevation,
            hfov_deg=self.optional_angle("img", "sample_fov", 1e-9, 180.0),
            vfov_deg=self.optional_angle("img", "line_fov", 1e-9, 180.0),
            start_time=self.start_time(),
            image_path=image_beside(self.path, self.file_name()),
            lmst=self.lmst(),
        )

    def product_id(self) -> str:
        """The VICAR PRODUCT_ID alias, else the file stem if it is this product, else the LID."""
        for alias in self.all("pds", "Alias"):
            alt, comment = (
                self.child(alias, "pds", "alternate_id"),
                self.child(alias, "pds", "comment"),
            )
            if (
                alt is not None
                and comment is not None
                and "PRODUCT_ID" in self.text(comment).upper()
            ):
                return self.f.identifier(self.text(alt), "alternate_id")
        lid_el = self.need(self.first("pds", "logical_identifier"), "pds", "logical_identifier")
        lid = self.f.text(self.text(lid_el), "logical_identifier").rsplit(":", 1)[-1]
        if not lid:
            self.f.fail("logical_identifier", "no product part after the last ':'")
        stem = self.path.stem
        found = stem.upper() if stem.lower().startswith(lid.lower()) else lid.upper()
        return self.f.identifier(found, "logical_identifier")

    def instrument(self, product_id: str) -> str:
        """img_surface:ops_instrument_key (MCZ_LEFT / MCZ_RIGHT), else from the product id."""
        key = self.first("img_surface", "ops_instrument_key")
        if key is not None:
            return self.f.identifier(self.text(key), "img_surface:ops_instrument_key").upper()
        by_prefix = _PRODUCT_PREFIX_INSTRUMENT.get(product_id[:2].upper())
        if by_prefix:
            return by_prefix
        for comp in self.all("pds", "Observing_System_Component"):
            kind, name = self.child(comp, "pds", "type"), self.child(comp, "pds", "name")
            if kind is not None and name is not None and self.text(kind).lower() == "instrument":
                return self.f.text(self.text(name), "Observing_System_Component")
        self.f.fail("img_surface:ops_instrument_key", "no instrument named in the label")

    def sol(self) -> int:
        """mars2020:sol_number, else msn:start_sol_number."""
        for prefix, local in (("mars2020", "sol_number"), ("msn", "start_sol_number")):
            el = self.first(prefix, local)
            if el is not None:
                return self.f.integer(self.text(el), name_of(prefix, local))
        self.f.fail("mars2020:sol_number", "required element missing")

    def motion_counter(self, camera_params: etree._Element) -> MotionCounter:
        """geom:Motion_Counter, else the camera model's or ROVER_NAV_FRAME's frame indices."""
        counter = self.first("geom", "Motion_Counter")
        if counter is not None:
            return self._counter(
                self._indices(counter, "Motion_Counter_Index"), "geom:Motion_Counter"
            )
        sources = [self.child(camera_params, "geom", "Coordinate_Space_Reference")]
        sources += [
            self.child(d, "geom", "Coordinate_Space_Present")
            for d in self.all("geom", "Coordinate_Space_Definition")
            if self.definition_frame(d) == ROVER_FRAME
        ]
        for source in sources:
            if (
                source is not None
                and self.first("geom", "Coordinate_Space_Index", source) is not None
            ):
                return self._counter(
                    self._indices(source, "Coordinate_Space_Index"), "geom:Coordinate_Space_Index"
                )
        self.f.fail("geom:Motion_Counter", "required element missing (no motion counter anywhere)")

    def _indices(self, container: etree._Element, entry: str) -> dict[str, str]:
        """index_id -> index_value_number text of the entries under ``container``."""
        out: dict[str, str] = {}
        for item in self.all("geom", entry, container):
            ident = self.child(item, "geom", "index_id")
            value = self.child(item, "geom", "index_value_number")
            if ident is not None and self.text(ident).upper() not in out:
                out[self.text(ident).upper()] = "" if value is None else self.text(value)
        return out

    def _counter(self, index: dict[str, str], field: str) -> MotionCounter:
        """SITE, DRIVE (required) and POSE (optional) from an index map."""
        for needed in ("SITE", "DRIVE"):
            if needed not in index:
                self.f.fail(field, f"no {needed} index")
        pose = index.get("POSE")
        return MotionCounter(
            site=self.f.integer(index["SITE"], "geom:index_value_number"),
            drive=self.f.integer(index["DRIVE"], "geom:index_value_number"),
            pose=None if pose is None else self.f.integer(pose, "geom:index_value_number"),
        )

    def image_size(self) -> tuple[int, int]:
        """(width, height): the image array's Sample/Line axes, else img:samples / img:lines."""
        for array in (*self.all("pds", "Array_3D_Image"), *self.all("pds", "Array_2D_Image")):
            axes: dict[str, str] = {}
            for axis in self.all("pds", "Axis_Array", array):
                name = self.child(axis, "pds", "axis_name")
                count = self.child(axis, "pds", "elements")
                if name is not None and count is not None:
                    axes.setdefault(self.text(name).lower(), self.text(count))
            if "line" in axes and "sample" in axes:
                width = self.f.image_side(axes["sample"], "elements")
                return width, self.f.image_side(axes["line"], "elements")
        for scope in (self.first("img", "Subframe"), None):
            lines = self.first("img", "lines", scope)
            samples = self.first("img", "samples", scope)
            if lines is not None and samples is not None:
                width = self.f.image_side(self.text(samples), "img:samples")
                return width, self.f.image_side(self.text(lines), "img:lines")
        self.f.fail("Axis_Array", "no Line/Sample image axes and no img:lines/img:samples")

    def camera(self, params: etree._Element) -> CameraModel:
        """The geom:CAHVORE_Model / CAHVOR_Model / CAHV_Model with the frame of its reference."""
        model = self._model_element(params)
        kind = _MODELS[local_name(model)]
        declared = self.child(params, "geom", "model_type")
        if declared is not None and self.text(declared).upper() != kind:
            reason = f"says {self.text(declared)!r} but the model is geom:{local_name(model)}"
            self.f.fail("geom:model_type", reason)
        frame = self.reference_frame(params)
        if not frame:
            self.f.fail("geom:Coordinate_Space_Reference", "camera model names no frame")
        vectors = self._model_vectors(model, kind)
        return self.f.camera("geom:Camera_Model_Parameters", kind, vectors, frame)

    def _model_element(self, params: etree._Element) -> etree._Element:
        """The CAHVORE_Model, CAHVOR_Model or CAHV_Model child of Camera_Model_Parameters."""
        for local in _MODELS:
            model = self.child(params, "geom", local)
            if model is not None:
                return model
        declared = self.child(params, "geom", "model_type")
        kind = self.text(declared) if declared is not None else "none"
        reason = f"no geom:CAHVORE_Model, CAHVOR_Model or CAHV_Model (model_type {kind!r})"
        self.f.fail("geom:Camera_Model_Parameters", reason)

    def _model_vectors(self, model: etree._Element, kind: str) -> dict[str, Any]:
        """C, A, H, V (O, R for CAHVOR; and E, type, parameter for CAHVORE) of a model."""
        where = f"geom:{local_name(model)}"
        vectors: dict[str, Any] = {}
        for letter in "cahv" if kind == "CAHV" else "cahvo":
            local = _VECTORS[letter]
            vectors[letter] = self.xyz(
                self.need(self.child(model, "geom", local), "geom", local, where), "geom", local
            )
        if kind != "CAHV":
            vectors["r"] = self._terms(model, "Radial_Terms")
        if kind == "CAHVORE":
            vectors["e"] = self._terms(model, "Entrance_Terms")
            code = self.need(self.child(model, "geom", "cahvore_model_type"), "geom",
                             "cahvore_model_type", where)  # fmt: skip
            vectors["mtype"] = self.f.model_type_code(self.text(code), "geom:cahvore_model_type")
            parm = self.child(model, "geom", "cahvore_model_parameter")
            vectors["mparm"] = (
                0.0 if parm is None else self.number(parm, "geom", "cahvore_model_parameter")
            )
            if vectors["mtype"] == 3 and parm is None:
                self.f.fail("geom:cahvore_model_parameter", "required for model type 3")
        return vectors

    def _terms(self, model: etree._Element, local: str) -> np.ndarray:
        """The c0, c1, c2 children of geom:Radial_Terms / geom:Entrance_Terms."""
        block = self.need(self.child(model, "geom", local), "geom", local)
        terms = [self.need(self.child(block, "geom", c), "geom", c) for c in ("c0", "c1", "c2")]
        return np.array([self.number(t, "geom", f"c{i}") for i, t in enumerate(terms)])

    def rover_pose(self, rmc: MotionCounter) -> tuple[np.ndarray | None, np.ndarray | None]:
        """ROVER_NAV_FRAME origin and quaternion relative to SITE_FRAME (None if absent)."""
        candidates = [
            d for d in self.all("geom", "Coordinate_Space_Definition")
            if self.definition_frame(d) == ROVER_FRAME and self.reference_frame(d) == SITE_FRAME
        ]  # fmt: skip
        if not candidates:
            return None, None
        same = [d for d in candidates if self._matches(d, rmc)]
        defn = (same or candidates)[0]
        offset = self.child(defn, "geom", "Vector_Origin_Offset")
        quat = self.child(defn, "geom", "Quaternion_Plus_Direction")
        if offset is None or quat is None:
            return None, None
        parts = [
            self.number(self.need(self.child(quat, "geom", n), "geom", n), "geom", n)
            for n in ("qcos", "qsin1", "qsin2", "qsin3")
        ]
        q_site = self.f.quaternion(parts, "geom:Quaternion_Plus_Direction")
        field = "geom:Vector_Origin_Offset"
        return self.f.offset_m(self.xyz(offset, "geom", "Vector_Origin_Offset"), field), q_site

    def _matches(self, defn: etree._Element, rmc: MotionCounter) -> bool:
        """True if the definition's SITE/DRIVE indices equal the motion counter's."""
        present = self.child(defn, "geom", "Coordinate_Space_Present")
        if present is None:
            return False
        index = self._indices(present, "Coordinate_Space_Index")
        return index.get("SITE") == str(rmc.site) and index.get("DRIVE") == str(rmc.drive)

    def pointing(self) -> tuple[float | None, float | None]:
        """Instrument azimuth/elevation of the Derived_Geometry relative to SITE_FRAME."""
        for block in self.all("geom", "Derived_Geometry"):
            if self.reference_frame(block) != SITE_FRAME:
                continue
            az = self.first("geom", "instrument_azimuth", block)
            el = self.first("geom", "instrument_elevation", block)
            return (
                None
                if az is None
                else self.f.angle(self.text(az), "geom:instrument_azimuth", -360.0, 720.0),
                None
                if el is None
                else self.f.angle(self.text(el), "geom:instrument_elevation", -90.0, 90.0),
            )
        return None, None

    def optional_angle(self, prefix: str, local: str, lo: float, hi: float) -> float | None:
        """An optional angle element (None if absent)."""
        el = self.first(prefix, local)
        return None if el is None else self.f.angle(self.text(el), name_of(prefix, local), lo, hi)

    def start_time(self) -> datetime | None:
        """Time_Coordinates/start_date_time as UTC (None if absent)."""
        el = self.first("pds", "start_date_time")
        return None if el is None else self.f.time(self.text(el), "start_date_time")

    def lmst(self) -> str | None:
        """Time_Coordinates/local_mean_solar_time, else msn:start_local_mean_solar_time, else
        mars2020:start_local_mean_solar_time ("Sol-NNNNNM" before the time), as
        "HH:MM:SS[.fff]" (None if absent)."""
        for prefix, local in (
            ("pds", "local_mean_solar_time"),
            ("msn", "start_local_mean_solar_time"),
            ("mars2020", "start_local_mean_solar_time"),
        ):
            el = self.first(prefix, local)
            if el is not None and self.text(el):
                return self.f.local_time(self.text(el), name_of(prefix, local), self.sol())
        return None

    def file_name(self) -> str | None:
        """The data file named in File_Area_Observational, if any."""
        for area in self.all("pds", "File_Area_Observational"):
            el = self.first("pds", "file_name", area)
            if el is not None and self.text(el):
                return self.text(el)
        return None
