"""Synthetic Perseverance PDS4 labels (geom frames, derived geometry, array axes), with the
camera as geom:CAHV_Model, CAHVOR_Model or CAHVORE_Model, optionally with the ``.IMG`` beside
(a VICAR-style header, then the array named by the product's local_identifier)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from lxml import etree

from mars_pairs.errors import ArgumentError
from mars_pairs.observation import Observation
from mars_pairs.pds.xml import NS, q
from mars_pairs.synth.labels.format import iso_time, pointer_name, real_text, rover_angles

_LID_PREFIX = "urn:nasa:pds:mars2020_mastcamz_ops_calibrated:data:"


def write_pds4_label(
    obs: Observation, path: str | os.PathLike[str], pixels: np.ndarray | None = None
) -> Path:
    """Write ``obs`` as a Mars 2020-style PDS4 label at ``path``; returns the path.

    With ``pixels`` (uint8 or uint16, (H, W) or (H, W, 3)) the data file the label points to
    is written beside it too: a 64-byte VICAR-style header, then the array (band sequential,
    MSB first), described by an Array_2D_Image / Array_3D_Image with that offset.
    """
    path = Path(path)
    if pixels is not None:
        pixels = _check_pixels(obs, pixels)
    nsmap: dict[str | None, str] = {None: NS["pds"], **{k: v for k, v in NS.items() if k != "pds"}}
    root = etree.Element(q("pds", "Product_Observational"), nsmap=nsmap)
    _pds4_identification(root, obs)
    area = _el(root, "pds", "Observation_Area")
    _pds4_context(area, obs)
    discipline = _el(area, "pds", "Discipline_Area")
    lander = _el(_el(discipline, "geom", "Geometry"), "geom", "Geometry_Lander")
    _el(lander, "geom", "geometry_state", "Telemetry")
    _pds4_camera(lander, obs)
    _pds4_frames(lander, obs)
    _pds4_derived(lander, obs)
    _pds4_counter(lander, obs)
    _pds4_imaging(discipline, obs)
    _pds4_file_area(root, obs, path, pixels)
    if pixels is not None:
        _write_img(path.parent / pointer_name(obs, path, ".IMG"), pixels)
    etree.ElementTree(root).write(
        str(path), xml_declaration=True, encoding="UTF-8", pretty_print=True
    )
    return path


def _el(
    parent: etree._Element, prefix: str, local: str, text: str | None = None, **attrib: str
) -> etree._Element:
    """Append a child element ``prefix:local`` with optional text and attributes."""
    child = etree.SubElement(parent, q(prefix, local), attrib)
    if text is not None:
        child.text = text
    return child


def _frame_id(frame: str, obs: Observation) -> str:
    """A local_identifier as the real labels name frames: FRAME_SITE_DRIVE_POSE."""
    pose = 0 if obs.rmc.pose is None else obs.rmc.pose
    return f"{frame}_{obs.rmc.site}_{obs.rmc.drive}_{pose}"


def _pds4_identification(root: etree._Element, obs: Observation) -> None:
    """Identification_Area: logical identifier and the VICAR PRODUCT_ID alias."""
    ident = _el(root, "pds", "Identification_Area")
    lid = re.sub(r"[^a-z0-9_.-]", "_", obs.product_id.lower())
    _el(ident, "pds", "logical_identifier", _LID_PREFIX + lid)
    _el(ident, "pds", "version_id", "1.0")
    _el(ident, "pds", "title", f"Mars2020 {obs.instrument} Observational Product (synthetic)")
    _el(ident, "pds", "information_model_version", "1.16.0.0")
    _el(ident, "pds", "product_class", "Product_Observational")
    alias = _el(_el(ident, "pds", "Alias_List"), "pds", "Alias")
    _el(alias, "pds", "alternate_id", obs.product_id)
    _el(alias, "pds", "comment", "VICAR PRODUCT_ID")


def _pds4_context(area: etree._Element, obs: Observation) -> None:
    """Time, investigation, observing system, target and the mission's sol."""
    if obs.start_time is not None:
        times = _el(area, "pds", "Time_Coordinates")
        _el(times, "pds", "start_date_time", iso_time(obs.start_time) + "Z")
        _el(times, "pds", "stop_date_time", iso_time(obs.start_time) + "Z")
    inv = _el(area, "pds", "Investigation_Area")
    _el(inv, "pds", "name", "Mars2020")
    _el(inv, "pds", "type", "Mission")
    system = _el(area, "pds", "Observing_System")
    for name, kind in (("Mars 2020", "Host"), (_instrument_name(obs.instrument), "Instrument")):
        comp = _el(system, "pds", "Observing_System_Component")
        _el(comp, "pds", "name", name)
        _el(comp, "pds", "type", kind)
    target = _el(area, "pds", "Target_Identification")
    _el(target, "pds", "name", "Mars")
    _el(target, "pds", "type", "Planet")
    params = _el(_el(area, "pds", "Mission_Area"), "mars2020", "Mars2020_Parameters")
    info = _el(params, "mars2020", "Observation_Information")
    _el(info, "mars2020", "sol_number", str(obs.sol))


def _instrument_name(instrument: str) -> str:
    """Observing_System_Component name of a Mastcam-Z or Navcam eye."""
    side = "Right" if "RIGHT" in instrument.upper() else "Left"
    if instrument.upper().startswith("NAVCAM"):
        return f"Navigation Camera {side}"
    return f"Mast Camera Zoom {side}"


def _xyz(
    parent: etree._Element, local: str, values: np.ndarray, kind: str, unit: str | None
) -> etree._Element:
    """A geom vector element with x_<kind>, y_<kind>, z_<kind> children."""
    vec = _el(parent, "geom", local)
    for axis, value in zip("xyz", values, strict=True):
        attrib = {"unit": unit} if unit else {}
        _el(vec, "geom", f"{axis}_{kind}", real_text(value), **attrib)
    return vec


def _indexed(parent: etree._Element, wrapper: str, frame: str, indices: dict[str, int]) -> None:
    """A Coordinate_Space_Reference/Present holding Coordinate_Space_Indexed."""
    indexed = _el(_el(parent, "geom", wrapper), "geom", "Coordinate_Space_Indexed")
    _el(indexed, "geom", "coordinate_space_frame_type", frame)
    for name, value in indices.items():
        entry = _el(indexed, "geom", "Coordinate_Space_Index")
        _el(entry, "geom", "index_id", name)
        _el(entry, "geom", "index_value_number", str(value))


def _linked(parent: etree._Element, target_id: str) -> None:
    """A Coordinate_Space_Reference by Local_Internal_Reference to a frame's identifier."""
    link = _el(_el(parent, "geom", "Coordinate_Space_Reference"), "pds", "Local_Internal_Reference")
    _el(link, "pds", "local_identifier_reference", target_id)
    _el(link, "pds", "local_reference_type", "to_reference_coordinate_space")


def _rmc_indices(obs: Observation) -> dict[str, int]:
    """SITE, DRIVE (and POSE) of the motion counter."""
    out = {"SITE": obs.rmc.site, "DRIVE": obs.rmc.drive}
    if obs.rmc.pose is not None:
        out["POSE"] = obs.rmc.pose
    return out


def _pds4_camera(lander: etree._Element, obs: Observation) -> None:
    """geom:Camera_Model_Parameters with the CAHV(OR) model in the camera's frame."""
    cam = obs.camera
    params = _el(lander, "geom", "Camera_Model_Parameters")
    _el(params, "geom", "model_type", cam.model_type)
    _el(params, "geom", "calibration_source_id", "1")
    model = _el(params, "geom", f"{cam.model_type}_Model")
    _xyz(model, "Vector_Center", cam.c, "position", "m")
    _xyz(model, "Vector_Axis", cam.a, "unit", None)
    _xyz(model, "Vector_Horizontal", cam.h, "pixel", None)
    _xyz(model, "Vector_Vertical", cam.v, "pixel", None)
    if cam.model_type in ("CAHVOR", "CAHVORE"):
        assert cam.o is not None and cam.r is not None
        _xyz(model, "Vector_Optical", cam.o, "unit", None)
        for local, values in (("Radial_Terms", cam.r), ("Entrance_Terms", cam.e)):
            if local == "Entrance_Terms" and cam.model_type != "CAHVORE":
                continue
            assert values is not None
            terms = _el(model, "geom", local)
            for name, value in zip(("c0", "c1", "c2"), values, strict=True):
                _el(terms, "geom", name, real_text(value))
    if cam.model_type == "CAHVORE":
        assert cam.mtype is not None and cam.mparm is not None
        _el(model, "geom", "cahvore_model_type", str(cam.mtype))
        _el(model, "geom", "cahvore_model_parameter", real_text(cam.mparm))
    _indexed(params, "Coordinate_Space_Reference", cam.frame, _rmc_indices(obs))


def _pds4_frames(lander: etree._Element, obs: Observation) -> None:
    """Coordinate_Space_Definition blocks: ROVER_NAV_FRAME in SITE_FRAME, then RSM_HEAD_FRAME."""
    rover_id = _frame_id("ROVER_NAV_FRAME", obs)
    if obs.rover_offset_m is not None and obs.rover_quaternion is not None:
        defn = _el(lander, "geom", "Coordinate_Space_Definition")
        _el(defn, "pds", "local_identifier", rover_id)
        _indexed(defn, "Coordinate_Space_Present", "ROVER_NAV_FRAME", _rmc_indices(obs))
        _xyz(defn, "Vector_Origin_Offset", obs.rover_offset_m, "position", "m")
        _quaternion(defn, obs.rover_quaternion)
        _indexed(defn, "Coordinate_Space_Reference", "SITE_FRAME", {"SITE": obs.rmc.site})
    head = _el(lander, "geom", "Coordinate_Space_Definition")
    head.append(etree.Comment(" synthetic: RSM head placed at the camera centre "))
    _el(head, "pds", "local_identifier", _frame_id("RSM_HEAD_FRAME", obs))
    _indexed(head, "Coordinate_Space_Present", "RSM_HEAD_FRAME", _rmc_indices(obs))
    _xyz(head, "Vector_Origin_Offset", obs.camera.c, "position", "m")
    _quaternion(head, np.array([1.0, 0.0, 0.0, 0.0]))
    _linked(head, rover_id)


def _quaternion(parent: etree._Element, quat: np.ndarray) -> None:
    """geom:Quaternion_Plus_Direction (qcos, qsin1..3)."""
    el = _el(parent, "geom", "Quaternion_Plus_Direction")
    for name, value in zip(("qcos", "qsin1", "qsin2", "qsin3"), quat, strict=True):
        _el(el, "geom", name, real_text(value))
    _el(el, "geom", "rotation_direction", "Forward")


def _pds4_derived(lander: etree._Element, obs: Observation) -> None:
    """Derived_Geometry: rover-frame pointing (from the model axis), then the site-frame one."""
    if obs.camera.frame.upper() == "ROVER_NAV_FRAME":
        az, el = rover_angles(obs.camera.a)
        block = _el(lander, "geom", "Derived_Geometry")
        _el(block, "geom", "instrument_azimuth", real_text(az), unit="deg")
        _el(block, "geom", "instrument_elevation", real_text(el), unit="deg")
        _linked(block, _frame_id("ROVER_NAV_FRAME", obs))
    if obs.azimuth_deg is not None or obs.elevation_deg is not None:
        block = _el(lander, "geom", "Derived_Geometry")
        if obs.azimuth_deg is not None:
            _el(block, "geom", "instrument_azimuth", real_text(obs.azimuth_deg), unit="deg")
        if obs.elevation_deg is not None:
            _el(block, "geom", "instrument_elevation", real_text(obs.elevation_deg), unit="deg")
        _indexed(block, "Coordinate_Space_Reference", "SITE_FRAME", {"SITE": obs.rmc.site})


def _pds4_counter(lander: etree._Element, obs: Observation) -> None:
    """geom:Motion_Counter (RMC) with SITE, DRIVE (and POSE) indices."""
    counter = _el(lander, "geom", "Motion_Counter")
    _el(counter, "geom", "name", "RMC")
    for name, value in _rmc_indices(obs).items():
        entry = _el(counter, "geom", "Motion_Counter_Index")
        _el(entry, "geom", "index_id", name)
        _el(entry, "geom", "index_value_number", str(value))


def _pds4_imaging(discipline: etree._Element, obs: Observation) -> None:
    """img:Imaging (detector size, FOV) and img_surface instrument key."""
    imaging = _el(discipline, "img", "Imaging")
    detector = _el(imaging, "img", "Detector")
    _el(detector, "img", "lines", str(obs.height))
    _el(detector, "img", "samples", str(obs.width))
    if obs.hfov_deg is not None or obs.vfov_deg is not None:
        sub = _el(imaging, "img", "Subframe")
        if obs.vfov_deg is not None:
            _el(sub, "img", "line_fov", real_text(obs.vfov_deg), unit="deg")
        if obs.hfov_deg is not None:
            _el(sub, "img", "sample_fov", real_text(obs.hfov_deg), unit="deg")
    surface = _el(discipline, "img_surface", "Surface_Imaging")
    info = _el(surface, "img_surface", "Instrument_Information")
    _el(info, "img_surface", "ops_instrument_key", obs.instrument)


_HEADER_BYTES = 64


def _check_pixels(obs: Observation, pixels: np.ndarray) -> np.ndarray:
    pixels = np.asarray(pixels)
    if pixels.dtype not in (np.uint8, np.uint16) or pixels.ndim not in (2, 3):
        raise ArgumentError(f"pixels must be uint8/uint16 (H, W[, 3]), got {pixels.dtype}")
    if pixels.shape[:2] != (obs.height, obs.width):
        raise ArgumentError(
            f"pixels are {pixels.shape[:2]}, the label says {(obs.height, obs.width)}"
        )
    return pixels


def _write_img(path: Path, pixels: np.ndarray) -> None:
    """The data file: a VICAR-style text header of _HEADER_BYTES, then band-sequential data."""
    bands = 1 if pixels.ndim == 2 else pixels.shape[2]
    kind = "BYTE" if pixels.dtype == np.uint8 else "HALF"
    header = f"LBLSIZE={_HEADER_BYTES} FORMAT='{kind}' NB={bands}".encode("ascii")
    data = np.moveaxis(pixels.reshape(*pixels.shape[:2], bands), -1, 0)
    body = data.astype(">u2" if pixels.dtype == np.uint16 else "u1").tobytes()
    path.write_bytes(header.ljust(_HEADER_BYTES, b" ") + body)


def _pds4_file_area(
    root: etree._Element, obs: Observation, path: Path, pixels: np.ndarray | None = None
) -> None:
    """File_Area_Observational: the data file, its header and the image array's axes.

    Without pixels the array is described as the 3-band 8-bit product at offset 0 (the
    data file itself is not written)."""
    area = _el(root, "pds", "File_Area_Observational")
    _el(_el(area, "pds", "File"), "pds", "file_name", pointer_name(obs, path, ".IMG"))
    bands, bits, offset = 3, 8, 0
    if pixels is not None:
        bands = 1 if pixels.ndim == 2 else pixels.shape[2]
        bits, offset = 8 * pixels.itemsize, _HEADER_BYTES
        header = _el(area, "pds", "Header")
        _el(header, "pds", "local_identifier", "VICAR_Header")
        _el(header, "pds", "offset", "0", unit="byte")
        _el(header, "pds", "object_length", str(_HEADER_BYTES), unit="byte")
        _el(header, "pds", "parsing_standard_id", "VICAR2")
    three_d = bands != 1
    array = _el(area, "pds", "Array_3D_Image" if three_d else "Array_2D_Image")
    _el(array, "pds", "local_identifier", obs.product_id.lower())
    _el(array, "pds", "offset", str(offset), unit="byte")
    _el(array, "pds", "axes", "3" if three_d else "2")
    _el(array, "pds", "axis_index_order", "Last Index Fastest")
    kind = "UnsignedByte" if bits == 8 else "UnsignedMSB2"
    _el(_el(array, "pds", "Element_Array"), "pds", "data_type", kind)
    axes = [("Line", obs.height), ("Sample", obs.width)]
    if three_d:
        axes.insert(0, ("Band", bands))
    for seq, (name, count) in enumerate(axes):
        axis = _el(array, "pds", "Axis_Array")
        _el(axis, "pds", "axis_name", name)
        _el(axis, "pds", "elements", str(count))
        _el(axis, "pds", "sequence_number", str(seq + 1))
