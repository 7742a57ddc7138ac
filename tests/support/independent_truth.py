"""Independent geometry truth for mars-pairs tests: label fields, CAHV/CAHVOR, rays on a DEM.

This module shares NO code with the ``mars_pairs`` package (it never imports it). It uses only
numpy, pyproj, rasterio, lxml (PDS4) and pvl (PDS3), so a frame-convention error inside the
project makes the two disagree.

Frames (metres unless stated):

- ROVER_NAV_FRAME: x forward, y right, z down; origin on the ground under the rover. The
  camera model vectors of the samples are in this frame.
- SITE_FRAME: x north, y east, z down (NED), the tangent plane at the site origin. The label /
  PLACES quaternion q = (s, v1, v2, v3) (unit, Hamilton) rotates rover -> site:
  ``v_site = q * v_rover * conj(q)``.
- ECEF: planet-fixed Cartesian of the Mars sphere (R = 3 396 190 m; the DEM CRS's sphere).
- ENU: East-North-Up tangent frame at the rover origin (defined below); the working frame of
  the ray march.
- map: the DEM's projected CRS: x, y in its units (metres), z = elevation above the sphere
  (areoid) in metres, up.
- pixels: (sample, line) = (x, y); the centre of the first pixel is (0, 0) (JPL CAHV
  convention), so the image covers [-0.5, w - 0.5) x [-0.5, h - 0.5) to pixel edges.

Anchoring (the truth's placement of the rover on the DEM): the rover origin's horizontal
position is the PLACES row's planetocentric latitude / longitude (not its easting/northing,
whose CRS depends on the table); its height is REPLACED by the DEM's bilinear elevation at the
rover origin's map (x, y), i.e. the whole rover is shifted vertically by
DEM(rover x, y) - PLACES elevation. The camera centre is the rover origin + R(q) C (C from the
label, in ROVER_NAV_FRAME).

Rotation ROVER_NAV -> ENU: ``M = B_enu(rover) @ B_ned(tangent)^T @ R(q)`` where ``B_ned`` has
rows north, east, down (ECEF) at the SITE origin (``tangent="site"``, the default, as the
quaternion is relative to SITE_FRAME) or at the rover (``tangent="rover"``); the difference is
(rover-site distance) / R radians, ~1e-5 rad for 50 m.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pvl
import rasterio
from lxml import etree
from numpy.typing import ArrayLike, NDArray
from pyproj import CRS, Transformer

F64 = NDArray[np.float64]
MARS_RADIUS_M = 3_396_190.0
PLACES_MISSING = -9999.0

_NS = {
    "pds": "http://pds.nasa.gov/pds4/pds/v1",
    "geom": "http://pds.nasa.gov/pds4/geom/v1",
    "img": "http://pds.nasa.gov/pds4/img/v1",
}


# ------------------------------------------------------------------------------------------------
# labels
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LabelFields:
    """The geometry fields of one mast-camera label.

    ``c, a, h, v, o, r``: camera model vectors in ``model_frame`` (C in metres, A and O unit,
    H and V in pixels, R dimensionless); ``o`` and ``r`` are None for CAHV.
    ``rover_quaternion``: (s, v1, v2, v3), ROVER_NAV_FRAME -> ``rover_reference_frame``
    (SITE_FRAME). ``rover_offset_m``: rover origin in the site frame (NED metres).
    ``motion_counter``: name -> value (SITE, DRIVE, POSE, ...). ``azimuth_deg`` /
    ``elevation_deg``: the label's own derived pointing in ``pointing_frame`` (SITE_FRAME where
    the label has it; degrees, azimuth clockwise from north, elevation up). FOVs in degrees.
    """

    path: Path
    kind: Literal["PDS3", "PDS4"]
    width: int
    height: int
    model_type: str
    c: F64
    a: F64
    h: F64
    v: F64
    o: F64 | None
    r: F64 | None
    model_frame: str
    rover_quaternion: F64 | None
    rover_offset_m: F64 | None
    rover_reference_frame: str | None
    motion_counter: dict[str, int] = field(default_factory=dict)
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    pointing_frame: str | None = None
    hfov_deg: float | None = None
    vfov_deg: float | None = None

    @property
    def site(self) -> int:
        """SITE motion counter."""
        return self.motion_counter["SITE"]

    @property
    def drive(self) -> int:
        """DRIVE motion counter."""
        return self.motion_counter["DRIVE"]


def read_label_fields(path: str | Path) -> LabelFields:
    """Read a PDS4 XML (Mars 2020 Mastcam-Z style) or PDS3 (Curiosity Mastcam style) label."""
    p = Path(path)
    head = p.read_bytes()[:200].lstrip()
    if head.startswith(b"<"):
        return _read_pds4(p)
    return _read_pds3(p)


def _vec3(el: etree._Element | None, names: tuple[str, str, str]) -> F64 | None:
    if el is None:
        return None
    out = []
    for n in names:
        child = el.find(f"geom:{n}", _NS)
        if child is None or child.text is None:
            return None
        out.append(float(child.text))
    return np.array(out, dtype=np.float64)


def _frame_of(ref: etree._Element | None) -> str | None:
    """The frame named by a ``geom:Coordinate_Space_Reference`` (indexed or by local id)."""
    if ref is None:
        return None
    ft = ref.find(".//geom:coordinate_space_frame_type", _NS)
    if ft is not None and ft.text:
        return ft.text.strip()
    lid = ref.find(".//pds:local_identifier_reference", _NS)
    if lid is not None and lid.text:
        # e.g. ROVER_NAV_FRAME_3_0_0 -> ROVER_NAV_FRAME
        text = lid.text.strip()
        for known in ("ROVER_NAV_FRAME", "SITE_FRAME", "RSM_HEAD_FRAME", "LOCAL_LEVEL_FRAME"):
            if text.upper().startswith(known):
                return known
        return text
    return None


def _read_pds4(p: Path) -> LabelFields:
    root = etree.parse(str(p)).getroot()
    # image size: the image array's Line / Sample axes first, else img:lines / img:samples
    width = height = None
    for arr in root.iter(f"{{{_NS['pds']}}}Array_2D_Image", f"{{{_NS['pds']}}}Array_3D_Image",
                         f"{{{_NS['pds']}}}Array_2D", f"{{{_NS['pds']}}}Array_3D"):  # fmt: skip
        for ax in arr.findall("pds:Axis_Array", _NS):
            name = (ax.findtext("pds:axis_name", "", _NS) or "").strip().lower()
            n = int(ax.findtext("pds:elements", "0", _NS))
            if name == "line":
                height = n
            elif name == "sample":
                width = n
        if width and height:
            break
    if not (width and height):
        height = int(root.findtext(".//img:lines", "0", _NS))
        width = int(root.findtext(".//img:samples", "0", _NS))
    cmp_ = root.find(".//geom:Camera_Model_Parameters", _NS)
    if cmp_ is None:
        raise ValueError(f"{p}: no geom:Camera_Model_Parameters")
    model = None
    for tag in ("CAHVOR_Model", "CAHV_Model", "CAHVORE_Model"):
        model = cmp_.find(f"geom:{tag}", _NS)
        if model is not None:
            break
    if model is None:
        raise ValueError(f"{p}: no CAHV/CAHVOR model")
    mtype = model.tag.split("}")[1].replace("_Model", "")
    pos, unit, pix = ("x_position", "y_position", "z_position"), ("x_unit", "y_unit", "z_unit"), (
        "x_pixel", "y_pixel", "z_pixel")  # fmt: skip
    c = _vec3(model.find("geom:Vector_Center", _NS), pos)
    a = _vec3(model.find("geom:Vector_Axis", _NS), unit)
    h = _vec3(model.find("geom:Vector_Horizontal", _NS), pix)
    v = _vec3(model.find("geom:Vector_Vertical", _NS), pix)
    o = _vec3(model.find("geom:Vector_Optical", _NS), unit)
    r = _vec3(model.find("geom:Radial_Terms", _NS), ("c0", "c1", "c2"))
    if c is None or a is None or h is None or v is None:
        raise ValueError(f"{p}: incomplete camera model")
    if mtype == "CAHV":
        o = r = None
    model_frame = _frame_of(cmp_.find("geom:Coordinate_Space_Reference", _NS)) or "UNKNOWN"
    # the ROVER_NAV_FRAME definition relative to SITE_FRAME
    q = off = None
    qref = None
    for csd in root.iter(f"{{{_NS['geom']}}}Coordinate_Space_Definition"):
        present = csd.find("geom:Coordinate_Space_Present", _NS)
        if _frame_of(present) != "ROVER_NAV_FRAME":
            continue
        ref = _frame_of(csd.find("geom:Coordinate_Space_Reference", _NS))
        qel = csd.find("geom:Quaternion_Plus_Direction", _NS)
        if qel is None:
            continue
        q = np.array([float(qel.findtext(f"geom:{k}", "nan", _NS))
                      for k in ("qcos", "qsin1", "qsin2", "qsin3")])  # fmt: skip
        off = _vec3(csd.find("geom:Vector_Origin_Offset", _NS), pos)
        qref = ref
        if ref == "SITE_FRAME":
            break
    mc: dict[str, int] = {}
    mcel = root.find(".//geom:Motion_Counter", _NS)
    if mcel is not None:
        for idx in mcel.findall("geom:Motion_Counter_Index", _NS):
            key = (idx.findtext("geom:index_id", "", _NS) or "").strip().upper()
            val = idx.findtext("geom:index_value_number", None, _NS)
            if key and val is not None:
                mc[key] = int(float(val))
    az = el = None
    pframe = None
    for dg in root.iter(f"{{{_NS['geom']}}}Derived_Geometry"):
        fr = _frame_of(dg.find("geom:Coordinate_Space_Reference", _NS))
        a_txt = dg.findtext("geom:instrument_azimuth", None, _NS)
        e_txt = dg.findtext("geom:instrument_elevation", None, _NS)
        if a_txt is None or e_txt is None:
            continue
        if fr == "SITE_FRAME" or az is None:
            az, el, pframe = float(a_txt), float(e_txt), fr
        if fr == "SITE_FRAME":
            break
    sfov = root.findtext(".//img:sample_fov", None, _NS)
    lfov = root.findtext(".//img:line_fov", None, _NS)
    return LabelFields(
        path=p, kind="PDS4", width=int(width), height=int(height), model_type=mtype,
        c=c, a=a, h=h, v=v, o=o, r=r, model_frame=model_frame,
        rover_quaternion=q, rover_offset_m=off, rover_reference_frame=qref,
        motion_counter=mc, azimuth_deg=az, elevation_deg=el, pointing_frame=pframe,
        hfov_deg=None if sfov is None else float(sfov),
        vfov_deg=None if lfov is None else float(lfov),
    )  # fmt: skip


def _pv(x: object) -> object:
    """A pvl value without its unit."""
    return getattr(x, "value", x)


def _pvec(x: object) -> F64:
    return np.array([float(_pv(t)) for t in x], dtype=np.float64)  # type: ignore[attr-defined]


def _read_pds3(p: Path) -> LabelFields:
    lab = pvl.load(str(p))
    img = lab.get("IMAGE")
    if img is None or "LINES" not in img:
        raise ValueError(f"{p}: no IMAGE object with LINES / LINE_SAMPLES")
    height, width = int(img["LINES"]), int(img["LINE_SAMPLES"])
    cam = lab.get("GEOMETRIC_CAMERA_MODEL_PARMS") or lab.get("GEOMETRIC_CAMERA_MODEL")
    if cam is None:
        raise ValueError(f"{p}: no GEOMETRIC_CAMERA_MODEL(_PARMS) group")
    mtype = str(cam["MODEL_TYPE"]).strip().upper()
    ids = [str(s).upper() for s in cam.get("MODEL_COMPONENT_ID", ["C", "A", "H", "V", "O", "R"])]
    comp: dict[str, F64] = {}
    for k, name in enumerate(ids, start=1):
        key = f"MODEL_COMPONENT_{k}"
        if key in cam:
            comp[name] = _pvec(cam[key])
    model_frame = str(cam.get("REFERENCE_COORD_SYSTEM_NAME", "UNKNOWN"))
    rov = lab.get("ROVER_COORDINATE_SYSTEM_PARMS")
    q = off = None
    qref = None
    if rov is not None:
        q = _pvec(rov["ORIGIN_ROTATION_QUATERNION"])
        off = _pvec(rov["ORIGIN_OFFSET_VECTOR"])
        qref = str(rov.get("REFERENCE_COORD_SYSTEM_NAME", "SITE_FRAME"))
    names = [str(s).upper() for s in lab.get("ROVER_MOTION_COUNTER_NAME", [])]
    values = [int(_pv(s)) for s in lab.get("ROVER_MOTION_COUNTER", [])]  # type: ignore[arg-type]
    mc = dict(zip(names, values, strict=False))
    der = lab.get("DERIVED_IMAGE_PARMS") or {}
    az = der.get("FIXED_INSTRUMENT_AZIMUTH")
    el = der.get("FIXED_INSTRUMENT_ELEVATION")
    ist = lab.get("INSTRUMENT_STATE_PARMS") or {}
    hf, vf = ist.get("HORIZONTAL_FOV"), ist.get("VERTICAL_FOV")
    is_or = mtype.startswith("CAHVOR")
    return LabelFields(
        path=p, kind="PDS3", width=width, height=height, model_type=mtype,
        c=comp["C"], a=comp["A"], h=comp["H"], v=comp["V"],
        o=comp.get("O") if is_or else None, r=comp.get("R") if is_or else None,
        model_frame=model_frame, rover_quaternion=q, rover_offset_m=off,
        rover_reference_frame=qref, motion_counter=mc,
        azimuth_deg=None if az is None else float(_pv(az)),  # type: ignore[arg-type]
        elevation_deg=None if el is None else float(_pv(el)),  # type: ignore[arg-type]
        pointing_frame="SITE_FRAME" if az is not None else None,
        hfov_deg=None if hf is None else float(_pv(hf)),  # type: ignore[arg-type]
        vfov_deg=None if vf is None else float(_pv(vf)),  # type: ignore[arg-type]
    )  # fmt: skip


# ------------------------------------------------------------------------------------------------
# CAHV / CAHVOR (Yakimovsky & Cunningham 1978; Gennery 2001)
# ------------------------------------------------------------------------------------------------
def project(lab: LabelFields, points: ArrayLike) -> F64:
    """Points (..., 3) in the camera model's frame (metres) -> pixels (..., 2) (sample, line).

    CAHVOR first moves the point radially about the optical axis O: with d = P - C,
    zeta = d.O, lam = d - zeta O, tau = |lam|^2 / zeta^2, mu = r0 + r1 tau + r2 tau^2,
    d' = d + mu lam; then CAHV: x = d'.H / d'.A, y = d'.V / d'.A. NaN where d'.A <= 0 or
    zeta <= 0 (behind the camera).
    """
    d = np.asarray(points, dtype=np.float64) - lab.c
    bad = np.zeros(d.shape[:-1], dtype=bool)
    if lab.o is not None and lab.r is not None:
        zeta = d @ lab.o
        bad |= zeta <= 0
        lam = d - zeta[..., None] * lab.o
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = np.einsum("...i,...i->...", lam, lam) / (zeta * zeta)
        mu = lab.r[0] + lab.r[1] * tau + lab.r[2] * tau * tau
        d = d + mu[..., None] * lam
    den = d @ lab.a
    bad |= ~(den > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.stack([(d @ lab.h) / den, (d @ lab.v) / den], axis=-1)
    out[bad] = np.nan
    return out


def unproject(lab: LabelFields, pixels: ArrayLike) -> F64:
    """Pixels (..., 2) (sample, line) -> unit ray directions (..., 3) in the model's frame.

    The ray starts at C. CAHV: u = (V - y A) x (H - x A), normalised, sign so that u.A > 0.
    CAHVOR: that u is the distorted direction; write it as omega O + w (w perpendicular to O),
    t = |w| / omega; the undistorted tangent s solves t = s (1 + r0 + r1 s^2 + r2 s^4)
    (Newton), and the ray is omega O + w s / t.
    """
    px = np.asarray(pixels, dtype=np.float64)
    x, y = px[..., 0:1], px[..., 1:2]
    u = np.cross(lab.v - y * lab.a, lab.h - x * lab.a)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    u *= np.sign(u @ lab.a)[..., None]
    if lab.o is None or lab.r is None:
        return u
    r0, r1, r2 = lab.r
    omega = u @ lab.o
    w = u - omega[..., None] * lab.o
    t = np.linalg.norm(w, axis=-1) / omega
    s = t.copy()
    for _ in range(50):
        s2 = s * s
        f = s * (1 + r0 + r1 * s2 + r2 * s2 * s2) - t
        df = 1 + r0 + 3 * r1 * s2 + 5 * r2 * s2 * s2
        step = f / df
        s = s - step
        if np.all(np.abs(step) < 1e-15):
            break
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(t > 1e-15, s / t, 1.0 / (1.0 + r0))
    ray = omega[..., None] * lab.o + w * k[..., None]
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def pixel_grid(width: int, height: int, stride: int) -> F64:
    """Pixel centres (N, 2) (sample, line) of every ``stride``-th column and row, line-major."""
    gx, gy = np.meshgrid(np.arange(0, width, stride, dtype=np.float64),
                         np.arange(0, height, stride, dtype=np.float64))  # fmt: skip
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


# ------------------------------------------------------------------------------------------------
# rotations and the sphere
# ------------------------------------------------------------------------------------------------
def _qmul(p: F64, q: F64) -> F64:
    """Hamilton product of quaternions (s, x, y, z)."""
    ps, pv = p[0], p[1:]
    qs, qv = q[0], q[1:]
    return np.concatenate([[ps * qs - pv @ qv], ps * qv + qs * pv + np.cross(pv, qv)])


def quaternion_matrix(q: ArrayLike) -> F64:
    """3x3 matrix of v -> q v conj(q) (q = (s, v1, v2, v3), normalised), column by column."""
    qq = np.asarray(q, dtype=np.float64)
    qq = qq / np.linalg.norm(qq)
    qc = qq * np.array([1.0, -1.0, -1.0, -1.0])
    cols = [_qmul(_qmul(qq, np.concatenate([[0.0], e])), qc)[1:] for e in np.eye(3)]
    return np.stack(cols, axis=1)


def ned_basis(lon_deg: float, lat_deg: float) -> F64:
    """Rows: north, east, down unit vectors (ECEF) at a planetocentric lon/lat on the sphere."""
    lo, la = math.radians(lon_deg), math.radians(lat_deg)
    up = np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    north = np.cross(up, east)
    return np.stack([north, east, -up])


@dataclass(frozen=True)
class Geo:
    """pyproj transformers between the DEM's map CRS, its sphere's lon/lat/h, and ECEF."""

    crs: CRS
    radius_m: float
    map_to_lonlat: Transformer
    lonlat_to_map: Transformer
    lonlat_to_ecef: Transformer
    ecef_to_lonlat: Transformer

    @classmethod
    def from_crs(cls, crs_in: object) -> Geo:
        """Build from the DEM's CRS (text or rasterio/pyproj CRS); it must be on a sphere."""
        crs = CRS.from_user_input(crs_in.to_wkt() if hasattr(crs_in, "to_wkt") else crs_in)
        ell = crs.ellipsoid
        if ell is None or abs(ell.semi_major_metre - ell.semi_minor_metre) > 1e-6:
            raise ValueError(f"DEM CRS is not on a sphere: {ell}")
        radius = float(ell.semi_major_metre)
        geo = crs.geodetic_crs.to_3d()  # type: ignore[union-attr]
        ecef = CRS.from_proj4(f"+proj=geocent +R={radius} +units=m +no_defs")
        return cls(
            crs=crs, radius_m=radius,
            map_to_lonlat=Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True),
            lonlat_to_map=Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True),
            lonlat_to_ecef=Transformer.from_crs(geo, ecef, always_xy=True),
            ecef_to_lonlat=Transformer.from_crs(ecef, geo, always_xy=True),
        )  # fmt: skip


@dataclass(frozen=True)
class EnuFrame:
    """East-North-Up frame at a point (lon, lat deg; h metres above the sphere) of the sphere."""

    geo: Geo
    lon_deg: float
    lat_deg: float
    h_m: float

    @property
    def basis(self) -> F64:
        """Rows: east, north, up unit vectors in ECEF."""
        ned = ned_basis(self.lon_deg, self.lat_deg)
        return np.stack([ned[1], ned[0], -ned[2]])

    @property
    def origin_ecef(self) -> F64:
        """Origin in ECEF metres (pyproj)."""
        x, y, z = self.geo.lonlat_to_ecef.transform(self.lon_deg, self.lat_deg, self.h_m)
        return np.array([x, y, z], dtype=np.float64)

    def to_map(self, enu: ArrayLike) -> F64:
        """ENU metres (..., 3) -> map (x, y, elevation m) (..., 3), through ECEF and lon/lat."""
        e = np.asarray(enu, dtype=np.float64)
        ecef = self.origin_ecef + e @ self.basis
        lon, lat, h = self.geo.ecef_to_lonlat.transform(ecef[..., 0], ecef[..., 1], ecef[..., 2])
        mx, my = self.geo.lonlat_to_map.transform(lon, lat)
        return np.stack([np.asarray(mx), np.asarray(my), np.asarray(h)], axis=-1)

    def from_map(self, xyz: ArrayLike) -> F64:
        """Map (x, y, elevation m) (..., 3) -> ENU metres (..., 3)."""
        m = np.asarray(xyz, dtype=np.float64)
        lon, lat = self.geo.map_to_lonlat.transform(m[..., 0], m[..., 1])
        ex, ey, ez = self.geo.lonlat_to_ecef.transform(lon, lat, m[..., 2])
        ecef = np.stack([np.asarray(ex), np.asarray(ey), np.asarray(ez)], axis=-1)
        return (ecef - self.origin_ecef) @ self.basis.T


# ------------------------------------------------------------------------------------------------
# DEM and PLACES
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Dem:
    """A DEM band (NaN = nodata; row 0 at the top) with its affine transform and CRS.

    Cell (row i, col j) has its centre at x = c + a (j + 0.5), y = f + e (i + 0.5); the
    surface is bilinear between cell centres. Elevations in metres above the areoid/sphere.
    """

    z: F64
    a: float
    c: float
    e: float
    f: float
    crs: object

    @classmethod
    def open(cls, path: str | Path) -> Dem:
        """Read band 1 of a GeoTIFF (north-up, no rotation)."""
        with rasterio.open(path) as ds:
            z = ds.read(1).astype(np.float64)
            if ds.nodata is not None:
                z[z == ds.nodata] = np.nan
            z[~np.isfinite(z)] = np.nan
            t = ds.transform
            if t.b != 0 or t.d != 0:
                raise ValueError("rotated DEM transforms are not supported")
            return cls(z, t.a, t.c, t.e, t.f, ds.crs)

    def bilinear(self, x: ArrayLike, y: ArrayLike) -> F64:
        """Bilinear elevation at map (x, y); NaN outside the cell-centre grid or near nodata."""
        u = (np.asarray(x, dtype=np.float64) - self.c) / self.a - 0.5
        v = (np.asarray(y, dtype=np.float64) - self.f) / self.e - 0.5
        rows, cols = self.z.shape
        ok = (u >= 0) & (u <= cols - 1) & (v >= 0) & (v <= rows - 1)
        j = np.clip(np.floor(np.where(ok, u, 0)).astype(np.int64), 0, cols - 2)
        i = np.clip(np.floor(np.where(ok, v, 0)).astype(np.int64), 0, rows - 2)
        s, t = np.where(ok, u, 0) - j, np.where(ok, v, 0) - i
        z = self.z
        out = (z[i, j] * (1 - s) + z[i, j + 1] * s) * (1 - t) + (
            z[i + 1, j] * (1 - s) + z[i + 1, j + 1] * s
        ) * t
        return np.where(ok, out, np.nan)


@dataclass(frozen=True)
class PlacesRow:
    """One PLACES row: planetocentric lat / east lon (degrees), elevation (m), quaternion."""

    frame: str
    site: int
    drive: int
    lat_deg: float
    lon_deg: float
    elevation_m: float
    easting: float
    northing: float
    quaternion: F64 | None  # rover -> site, (s, v1, v2, v3); None when unknown (-9999)


def _f(row: dict[str, str], key: str) -> float:
    v = float(row[key])
    return math.nan if v == PLACES_MISSING else v


def read_places(path: str | Path) -> list[PlacesRow]:
    """All rows of a PLACES CSV (best_interp.csv / localized_interp.csv), read by header name."""
    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            q = np.array([_f(row, k) for k in ("quat_s", "quat_v1", "quat_v2", "quat_v3")])
            qok = bool(np.all(np.isfinite(q))) and abs(np.linalg.norm(q) - 1) < 1e-3
            out.append(PlacesRow(
                frame=row["frame"].strip().upper(), site=int(float(row["site"])),
                drive=int(float(row["drive"])),
                lat_deg=_f(row, "planetocentric_latitude"), lon_deg=_f(row, "longitude"),
                elevation_m=_f(row, "elevation"), easting=_f(row, "easting"),
                northing=_f(row, "northing"), quaternion=q if qok else None,
            ))  # fmt: skip
    return out


# ------------------------------------------------------------------------------------------------
# the placed camera
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlacedCamera:
    """A label's camera placed on the DEM (see the module docstring for the anchoring).

    ``rot``: ROVER_NAV_FRAME (model frame) -> ENU at the rover origin. ``centre_enu``: camera
    centre in that ENU frame (metres). ``rover_map``: rover origin in map (x, y, z) with
    z = DEM(x, y). ``places_elevation_m``: the replaced PLACES height. ``source``: "places"
    (ROVER row) or "label+site" (label offset from the SITE origin).
    """

    lab: LabelFields
    dem: Dem
    enu: EnuFrame
    rot: F64
    centre_enu: F64
    rover_map: F64
    places_elevation_m: float
    source: str
    attitude: str

    def world_to_model(self, enu: ArrayLike) -> F64:
        """ENU metres (..., 3) -> camera-model frame (ROVER_NAV_FRAME) metres."""
        return np.asarray(enu, dtype=np.float64) @ self.rot  # rot^T applied to rows

    def rays_enu(self, pixels: ArrayLike) -> F64:
        """Unit ray directions (..., 3) in ENU through pixels (sample, line)."""
        return unproject(self.lab, pixels) @ self.rot.T


def place_camera(
    lab: LabelFields,
    places_csv: str | Path,
    dem_tif: str | Path | Dem,
    *,
    tangent: Literal["site", "rover"] = "site",
    attitude: Literal["places", "label"] = "places",
) -> PlacedCamera:
    """Place ``lab``'s camera on the DEM with the PLACES row for its (SITE, DRIVE).

    Rover origin: the ROVER row's lat/lon; without one, the label's rover offset (SITE_FRAME
    NED metres) from the SITE row's origin. Height: DEM bilinear at the rover origin.
    Attitude: the PLACES row's quaternion (``attitude="places"``, falls back to the label's
    when the row has -9999) or the label's.
    """
    dem = dem_tif if isinstance(dem_tif, Dem) else Dem.open(dem_tif)
    geo = Geo.from_crs(dem.crs)
    rows = read_places(places_csv)
    site, drive = lab.site, lab.drive
    rover = next((r for r in rows if r.frame == "ROVER" and (r.site, r.drive) == (site, drive)),
                 None)  # fmt: skip
    site_row = next((r for r in rows if r.frame == "SITE" and r.site == site), None)
    if rover is not None and math.isfinite(rover.lat_deg):
        lon, lat, h_places, source = rover.lon_deg, rover.lat_deg, rover.elevation_m, "places"
    elif site_row is not None and lab.rover_offset_m is not None:
        o = np.array(geo.lonlat_to_ecef.transform(site_row.lon_deg, site_row.lat_deg,
                                                  site_row.elevation_m))  # fmt: skip
        p = o + lab.rover_offset_m @ ned_basis(site_row.lon_deg, site_row.lat_deg)
        lon, lat, h_places = geo.ecef_to_lonlat.transform(*p)
        source = "label+site"
    else:
        raise ValueError(f"{lab.path}: no PLACES position for site {site} drive {drive}")
    q = rover.quaternion if (rover is not None and attitude == "places") else None
    att = "places"
    if q is None:
        q, att = lab.rover_quaternion, "label"
    if q is None:
        raise ValueError(f"{lab.path}: no rover attitude")
    mx, my = geo.lonlat_to_map.transform(lon, lat)
    z0 = float(dem.bilinear(np.array([mx]), np.array([my]))[0])
    if not math.isfinite(z0):
        raise ValueError(f"{lab.path}: DEM has no elevation at the rover")
    enu = EnuFrame(geo, float(lon), float(lat), z0)
    if lab.model_frame not in ("ROVER_NAV_FRAME", "SITE_FRAME"):
        raise ValueError(f"{lab.path}: camera model in unsupported frame {lab.model_frame}")
    t_lon, t_lat = (site_row.lon_deg, site_row.lat_deg) if (
        tangent == "site" and site_row is not None) else (lon, lat)  # fmt: skip
    site_to_enu = enu.basis @ ned_basis(t_lon, t_lat).T
    rq = quaternion_matrix(q) if lab.model_frame == "ROVER_NAV_FRAME" else np.eye(3)
    # a SITE_FRAME model is site-framed but its C is relative to the site origin: not handled
    if lab.model_frame == "SITE_FRAME":
        raise ValueError(f"{lab.path}: SITE_FRAME camera models are not supported here")
    rot = site_to_enu @ rq
    return PlacedCamera(
        lab=lab, dem=dem, enu=enu, rot=rot, centre_enu=rot @ lab.c,
        rover_map=np.array([float(mx), float(my), z0]), places_elevation_m=float(h_places),
        source=source, attitude=att,
    )  # fmt: skip


def _height_above(cam: PlacedCamera, enu: F64) -> tuple[F64, F64]:
    """(height of ENU points above the DEM surface, their map xyz); NaN where no DEM."""
    m = cam.enu.to_map(enu)
    return m[..., 2] - cam.dem.bilinear(m[..., 0], m[..., 1]), m


def ground_hits(
    label: str | Path | LabelFields,
    places_csv: str | Path,
    dem_tif: str | Path | Dem,
    stride: int = 8,
    *,
    radius_m: float = 1000.0,
    step_m: float = 0.25,
    min_range_m: float = 0.2,
    pixels: ArrayLike | None = None,
    tangent: Literal["site", "rover"] = "site",
    attitude: Literal["places", "label"] = "places",
    chunk: int = 512,
) -> F64:
    """First terrain hit of every ``stride``-th pixel's ray: (N, 3) map x, y, z (NaN = none).

    Pixels: ``pixel_grid(width, height, stride)`` order (line-major, centres at integers), or
    the given ``pixels`` (N, 2). Anchoring: the rover origin stands at DEM(rover x, y) (the
    PLACES elevation is replaced by the DEM elevation at the rover origin); the camera centre
    is at R C from it. Rays start at the camera centre in the ENU frame at the rover and are
    sampled every ``step_m`` metres of range from ``min_range_m``; each sample goes ENU ->
    ECEF (numpy) -> lon/lat/height (pyproj) -> map x, y (pyproj) and is compared with the
    DEM's bilinear elevation. The first above -> at-or-below change is refined by bisection
    (to 1e-4 m of range). A ray gets NaN when no crossing lies within ``radius_m`` metres of
    horizontal (ENU east/north) distance from the camera centre, or the DEM has no data where
    it would be. z is the DEM elevation at the hit (metres above the areoid).
    """
    lab = label if isinstance(label, LabelFields) else read_label_fields(label)
    cam = place_camera(lab, places_csv, dem_tif, tangent=tangent, attitude=attitude)
    px = pixel_grid(lab.width, lab.height, stride) if pixels is None else np.asarray(pixels)
    dirs = cam.rays_enu(px)
    out = np.full((len(px), 3), np.nan)
    for k0 in range(0, len(px), chunk):
        out[k0 : k0 + chunk] = _march(cam, dirs[k0 : k0 + chunk], radius_m, step_m, min_range_m)
    return out


def _march(cam: PlacedCamera, dirs: F64, radius_m: float, step_m: float, t0: float) -> F64:
    n = len(dirs)
    c = cam.centre_enu
    horiz = np.linalg.norm(dirs[:, :2], axis=1)
    with np.errstate(divide="ignore"):
        t_max = np.where(horiz > 1e-12, radius_m / np.maximum(horiz, 1e-12), np.inf)
    # a ray pointing up leaves the DEM's elevation range; cap its range
    zmax = float(np.nanmax(cam.dem.z)) - cam.rover_map[2] + 10.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t_up = np.where(dirs[:, 2] > 0, (zmax - c[2]) / dirs[:, 2], np.inf)
    t_max = np.minimum(t_max, np.maximum(t_up, t0))
    lo = np.full(n, np.nan)
    hi = np.full(n, np.nan)
    active = np.arange(n)
    prev_t = np.full(n, t0)
    prev_f, _ = _height_above(cam, c + t0 * dirs)
    seg = 256
    t_start = t0
    while active.size:
        ts = t_start + step_m * np.arange(1, seg + 1)
        d = dirs[active]
        pts = c + ts[None, :, None] * d[:, None, :]
        f, _ = _height_above(cam, pts)
        f = np.where(ts[None, :] <= t_max[active, None] + step_m, f, np.nan)
        pf = np.concatenate([prev_f[active, None], f[:, :-1]], axis=1)
        cross = (pf > 0) & (f <= 0)
        got = cross.any(axis=1)
        first = np.argmax(cross, axis=1)
        idx = active[got]
        hi[idx] = ts[first[got]]
        lo[idx] = np.where(first[got] == 0, prev_t[idx], ts[first[got] - 1])
        prev_f[active] = f[:, -1]
        prev_t[active] = ts[-1]
        t_start = ts[-1]
        still = ~got & (ts[-1] < t_max[active])
        active = active[still]
    ok = np.isfinite(hi)
    if not ok.any():
        return np.full((n, 3), np.nan)
    a, b = lo[ok], hi[ok]
    d = dirs[ok]
    while np.max(b - a) > 1e-4:
        mid = 0.5 * (a + b)
        fm, _ = _height_above(cam, c + mid[:, None] * d)
        above = fm > 0
        a = np.where(above, mid, a)
        b = np.where(above, b, mid)
    t_hit = 0.5 * (a + b)
    hit_enu = c + t_hit[:, None] * d
    # the horizontal radius test on the refined point
    inside = np.linalg.norm(hit_enu[:, :2] - c[:2], axis=1) <= radius_m
    m = cam.enu.to_map(hit_enu)
    m[:, 2] = cam.dem.bilinear(m[:, 0], m[:, 1])
    m[~inside] = np.nan
    out = np.full((n, 3), np.nan)
    out[ok] = m
    return out


def project_map_points(cam: PlacedCamera, xyz_map: ArrayLike) -> tuple[F64, NDArray[np.bool_]]:
    """Map points (N, 3) (x, y, elevation) -> (pixels (N, 2), in front of the camera)."""
    enu = cam.enu.from_map(xyz_map)
    model = cam.world_to_model(enu)
    d = model - cam.lab.c
    front = d @ cam.lab.a > 0
    if cam.lab.o is not None:
        front &= d @ cam.lab.o > 0
    return project(cam.lab, model), front


def fraction_inside_image(
    label: str | Path | LabelFields,
    places_csv: str | Path,
    dem_tif: str | Path | Dem,
    cell_xy_map: ArrayLike,
    *,
    lo: float = 0.0,
    tangent: Literal["site", "rover"] = "site",
    attitude: Literal["places", "label"] = "places",
) -> float:
    """Fraction of DEM points (map x, y; height = DEM bilinear there) that the camera images.

    A point counts when it is in front of the camera (d.A > 0 and, for CAHVOR, d.O > 0, with
    d = P - C in the model frame) and projects into [lo, width + lo) x [lo, height + lo)
    (``lo = 0`` as in the brief; ``lo = -0.5`` gives pixel edges, the project's convention).
    No occlusion test. Points without DEM data count as outside.
    """
    lab = label if isinstance(label, LabelFields) else read_label_fields(label)
    cam = place_camera(lab, places_csv, dem_tif, tangent=tangent, attitude=attitude)
    xy = np.asarray(cell_xy_map, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return math.nan
    z = cam.dem.bilinear(xy[:, 0], xy[:, 1])
    px, front = project_map_points(cam, np.column_stack([xy, z]))
    with np.errstate(invalid="ignore"):
        inside = (
            front & np.isfinite(z)
            & (px[:, 0] >= lo) & (px[:, 0] < lab.width + lo)
            & (px[:, 1] >= lo) & (px[:, 1] < lab.height + lo)
        )  # fmt: skip
    return float(inside.mean())


def pointing_site_deg(lab: LabelFields, pixel: ArrayLike | None = None) -> tuple[float, float]:
    """Azimuth (clockwise from north) and elevation (up), degrees, in SITE_FRAME.

    Of the camera axis A (``pixel=None``) or of the ray through ``pixel``; uses the label's
    own rover quaternion (the frame of the label's derived pointing).
    """
    if lab.rover_quaternion is None:
        raise ValueError("label has no rover quaternion")
    v = lab.a if pixel is None else unproject(lab, np.asarray(pixel, dtype=np.float64))
    n, e, d = quaternion_matrix(lab.rover_quaternion) @ np.asarray(v).reshape(3)
    return math.degrees(math.atan2(e, n)) % 360.0, math.degrees(math.atan2(-d, math.hypot(n, e)))
