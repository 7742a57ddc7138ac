"""CAHV, CAHVOR and CAHVORE camera models: projection and ray unprojection, vectorised.

Frame and units: the vectors C, A, H, V, O are expressed in the model's reference frame
(``CameraModel.frame``, ROVER_NAV_FRAME for the mast cameras: x forward, y right, z down, metres).
Image coordinates are (sample, line) = (x, y) in pixels of the product's own grid, with the
centre of the first pixel at (0, 0) as in the JPL convention.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mars_pairs.errors import ArgumentError
from mars_pairs.geometry import cahvore

FloatArray = NDArray[np.float64]

SUPPORTED_MODELS = ("CAHV", "CAHVOR", "CAHVORE")
_NEWTON_STEPS = 60
_NEWTON_TOL = 1e-14


@dataclass(frozen=True)
class CameraModel:
    """A JPL CAHV-family camera model.

    ``model_type`` is "CAHV", "CAHVOR" (Mastcam, Mastcam-Z) or "CAHVORE" (Navcam, Hazcam).
    ``c`` is the camera centre (metres), ``a`` the unit axis, ``h`` and ``v`` the horizontal
    and vertical vectors (pixels), ``o`` the optical axis and ``r`` the radial terms (r0, r1,
    r2) of CAHVOR and CAHVORE; CAHVORE adds the entrance-pupil terms ``e`` (e0 metres, e1, e2
    metres per radian^2 and ^4), its model type ``mtype`` (1 perspective, 2 fish-eye, 3
    general) and parameter ``mparm`` (the linearity of type 3). ``frame`` names the
    reference frame of the vectors.
    """

    model_type: str
    c: FloatArray
    a: FloatArray
    h: FloatArray
    v: FloatArray
    o: FloatArray | None = None
    r: FloatArray | None = None
    frame: str = "ROVER_NAV_FRAME"
    e: FloatArray | None = None
    mtype: int | None = None
    mparm: float | None = None

    def __post_init__(self) -> None:
        for name in ("c", "a", "h", "v", "o", "r", "e"):
            value = getattr(self, name)
            if value is not None:
                arr = np.asarray(value, dtype=np.float64).reshape(3)
                object.__setattr__(self, name, arr)
        kind = self.model_type.upper()
        object.__setattr__(self, "model_type", kind)
        if kind not in SUPPORTED_MODELS:
            raise ArgumentError(f"unsupported camera model type {self.model_type!r}")
        if kind in ("CAHVOR", "CAHVORE") and (self.o is None or self.r is None):
            raise ArgumentError(f"{kind} model needs O and R")
        if kind == "CAHVORE":
            if self.e is None or self.mtype is None:
                raise ArgumentError("CAHVORE model needs E and its model type")
            mparm = 0.0 if self.mparm is None else float(self.mparm)
            cahvore.linearity(int(self.mtype), mparm)  # checks the type
            if not np.isfinite(mparm):
                raise ArgumentError(f"CAHVORE model parameter must be finite, got {mparm}")
            object.__setattr__(self, "mtype", int(self.mtype))
            object.__setattr__(self, "mparm", mparm)
        for name in ("c", "a", "h", "v", "o", "r", "e"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise ArgumentError(f"{name.upper()} has non-finite components")

    @property
    def linearity(self) -> float | None:
        """CAHVORE's linearity L (1 perspective, 0 fish-eye); None for CAHV and CAHVOR."""
        if self.model_type != "CAHVORE":
            return None
        assert self.mtype is not None and self.mparm is not None
        return cahvore.linearity(self.mtype, self.mparm)

    # -- intrinsic quantities (derived from the vectors) -------------------------------------
    @property
    def hs(self) -> float:
        """Horizontal scale (focal length in pixels): |A x H|."""
        return float(np.linalg.norm(cross3(self.a, self.h)))

    @property
    def vs(self) -> float:
        """Vertical scale (focal length in pixels): |A x V|."""
        return float(np.linalg.norm(cross3(self.a, self.v)))

    @property
    def hc(self) -> float:
        """Horizontal image centre (sample, pixels): A . H."""
        return float(self.a @ self.h)

    @property
    def vc(self) -> float:
        """Vertical image centre (line, pixels): A . V."""
        return float(self.a @ self.v)

    # -- projection ---------------------------------------------------------------------------
    def project(self, points: ArrayLike) -> FloatArray:
        """Project points (..., 3) in the model frame (metres) to pixels (..., 2) as (x, y).

        Points behind the camera give NaN.
        """
        p = np.asarray(points, dtype=np.float64) - self.c
        if self.model_type == "CAHVOR":
            p = _cahvor_distort(self, p)
        elif self.model_type == "CAHVORE":
            lin = self.linearity
            assert self.o is not None and self.r is not None and self.e is not None
            assert lin is not None
            p = cahvore.distort(p, self.o, self.r, self.e, lin)
        denom = p @ self.a
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (p @ self.h) / denom
            y = (p @ self.v) / denom
        behind = ~(denom > 0)
        x = np.where(behind, np.nan, x)
        y = np.where(behind, np.nan, y)
        return np.stack([x, y], axis=-1)

    def unproject(self, pixels: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Rays through pixels (..., 2) as (x, y): returns (origins (..., 3), unit directions).

        Origins are the camera centre for CAHV and CAHVOR (a fixed entrance pupil) and the
        entrance pupil of each ray for CAHVORE; both are in the model frame, metres. Pixels
        outside the model's domain give NaN.
        """
        xy = np.asarray(pixels, dtype=np.float64)
        u = _cahv_ray(self, xy[..., 0], xy[..., 1])
        if self.model_type == "CAHVORE":
            lin = self.linearity
            assert self.o is not None and self.r is not None and self.e is not None
            assert lin is not None
            return cahvore.undistort(u, self.c, self.o, self.r, self.e, lin)
        if self.model_type == "CAHVOR":
            u = _cahvor_undistort(self, u)
        origin = np.broadcast_to(self.c, u.shape).copy()
        return origin, u

    def fov_deg(self, width: int, height: int) -> tuple[float, float]:
        """Horizontal and vertical field of view (degrees) across the image edges.

        Measured as the angle between the rays through the middles of opposite edges, using
        pixel-edge coordinates (-0.5 and size - 0.5).
        """
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        pts = np.array(
            [[-0.5, cy], [width - 0.5, cy], [cx, -0.5], [cx, height - 0.5]], dtype=np.float64
        )
        _, rays = self.unproject(pts)
        hfov = np.degrees(np.arccos(np.clip(rays[0] @ rays[1], -1.0, 1.0)))
        vfov = np.degrees(np.arccos(np.clip(rays[2] @ rays[3], -1.0, 1.0)))
        return float(hfov), float(vfov)

    def transformed(self, rotation: ArrayLike, translation: ArrayLike, frame: str) -> CameraModel:
        """The same camera with vectors moved to another frame: v' = R v (+ t for C)."""
        rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        t = np.asarray(translation, dtype=np.float64).reshape(3)

        def turn(vec: FloatArray | None) -> FloatArray | None:
            return None if vec is None else rot @ vec

        return replace(
            self,
            c=rot @ self.c + t,
            a=rot @ self.a,
            h=rot @ self.h,
            v=rot @ self.v,
            o=turn(self.o),
            frame=frame,
        )

    def scaled(self, sx: float, sy: float) -> CameraModel:
        """The model for an image resampled by factors (sx, sy) (new pixels per old pixel).

        Pixel-centre convention: x' = sx * (x + 0.5) - 0.5.
        """
        ox, oy = 0.5 * sx - 0.5, 0.5 * sy - 0.5
        h = sx * self.h + ox * self.a
        v = sy * self.v + oy * self.a
        return replace(self, h=h, v=v)


# -- CAHV --------------------------------------------------------------------------------------
def _cahv_ray(cam: CameraModel, x: FloatArray, y: FloatArray) -> FloatArray:
    """Unit ray of the pinhole CAHV part: u = (V - yA) x (H - xA), oriented so u.A > 0."""
    f = cam.v[None, :] - np.reshape(y, (-1, 1)) * cam.a[None, :]
    g = cam.h[None, :] - np.reshape(x, (-1, 1)) * cam.a[None, :]
    u = cross3(f, g)
    u /= np.sqrt(u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] + u[:, 2] * u[:, 2])[:, None]
    u *= np.sign(u @ cam.a)[:, None]
    return u.reshape((*np.shape(x), 3))


def cross3(f: FloatArray, g: FloatArray) -> FloatArray:
    """Cross product of 3-vectors along the last axis (broadcast), the same operations in the
    same order as ``np.cross`` (so the same bits) without its axis handling: 5 us against
    25 us for one vector, which the per-image camera maths calls thousands of times."""
    f0, f1, f2 = f[..., 0], f[..., 1], f[..., 2]
    g0, g1, g2 = g[..., 0], g[..., 1], g[..., 2]
    return np.stack([f1 * g2 - f2 * g1, f2 * g0 - f0 * g2, f0 * g1 - f1 * g0], axis=-1)


# -- CAHVOR ------------------------------------------------------------------------------------
def _cahvor_distort(cam: CameraModel, p: FloatArray) -> FloatArray:
    """Apply CAHVOR radial distortion to vectors p = P - C (JPL cmod_cahvor_3d_to_2d)."""
    assert cam.o is not None and cam.r is not None
    zeta = p @ cam.o
    lam = p - zeta[..., None] * cam.o
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.einsum("...i,...i->...", lam, lam) / (zeta * zeta)
    mu = cam.r[0] + cam.r[1] * tau + cam.r[2] * tau * tau
    distorted: FloatArray = p + mu[..., None] * lam
    return distorted


def _cahvor_undistort(cam: CameraModel, rr: FloatArray) -> FloatArray:
    """Remove CAHVOR radial distortion from observed unit rays (Newton on the radial factor).

    With rr = omega O + lambda, the true ray is omega O + u lambda where
    u (1 + r0 + r1 tau u^2 + r2 tau^2 u^4) = 1 and tau = |lambda|^2 / omega^2.
    """
    assert cam.o is not None and cam.r is not None
    omega = rr @ cam.o
    wo = omega[..., None] * cam.o
    lam = rr - wo
    tau = np.einsum("...i,...i->...", lam, lam) / (omega * omega)
    k1 = 1.0 + cam.r[0]
    k3 = cam.r[1] * tau
    k5 = cam.r[2] * tau * tau
    u = np.ones_like(tau)
    for _ in range(_NEWTON_STEPS):
        u2 = u * u
        poly = ((k5 * u2 + k3) * u2 + k1) * u - 1.0
        deriv = (5.0 * k5 * u2 + 3.0 * k3) * u2 + k1
        du = poly / deriv
        u = u - du
        if np.all(np.abs(du) < _NEWTON_TOL):
            break
    out = wo + u[..., None] * lam
    unit: FloatArray = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return unit
