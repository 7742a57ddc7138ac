"""CAHVORE (Gennery 2006): the CAHVOR model with a moving entrance pupil and a linearity.

Frame and units: C, A, H, V, O, R, E as in :mod:`mars_pairs.geometry.camera` (model frame,
metres for C and E, pixels for H and V). For a point P, let p = P - C, zeta = p . O and
lambda = |p - zeta O|. The ray's off-axis angle theta is measured from an entrance pupil that
slides along O by

    shift(theta) = (theta / sin(theta) - 1) (e0 + e1 theta^2 + e2 theta^4),

so theta solves  zeta sin(theta) - lambda cos(theta) - (theta - sin(theta)) E(theta) = 0.
The linearity L maps theta to chi: tan(L theta) / L (L > 0), theta (L = 0, fish-eye),
sin(L theta) / L (L < 0); the radial terms then act on chi as in CAHVOR,
mu = r0 + r1 chi^2 + r2 chi^4, and the point is projected by the CAHV part from C along

    w = (lambda / chi) O + (1 + mu) (p - zeta O).

Model types (PDS3 MODEL_COMPONENT_8, PDS4 geom:cahvore_model_type): 1 perspective (L = 1),
2 fish-eye (L = 0), 3 general (L = MODEL_COMPONENT_9 / geom:cahvore_model_parameter).

O is used normalised: labels print it to 6 digits (|O| = 1.000008 on a real Navcam label),
enough to leave 2e-4 px round-trip errors if taken as it is.

Both directions are solved with a safeguarded Newton iteration (Newton inside a bracket that
always holds a root, bisection when a step leaves it), vectorised over all points, so they
converge wherever the model is defined; outside that domain (beyond |L| theta = 90 degrees,
or past the radial terms' turning point) the result is NaN.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from mars_pairs.errors import ArgumentError

FloatArray = NDArray[np.float64]
_ITERATIONS = 200
_TOL = 1e-15
_SMALL = 1e-12  # below this off-axis tangent the ray is the optical axis


def linearity(mtype: int, mparm: float) -> float:
    """The linearity L of a CAHVORE model type (1, 2 or 3) and parameter."""
    if mtype == 1:
        return 1.0
    if mtype == 2:
        return 0.0
    if mtype == 3:
        return float(mparm)
    raise ArgumentError(f"CAHVORE model type must be 1, 2 or 3, got {mtype}")


def theta_limit(lin: float) -> float:
    """The largest off-axis angle (radians) the linearity allows: pi / (2 |L|), at most pi."""
    return np.pi if abs(lin) < 0.5 else np.pi / (2.0 * abs(lin))


def chi_of_theta(theta: FloatArray, lin: float) -> FloatArray:
    """chi(theta) of the linearity equation."""
    if lin > 1e-15:
        return np.tan(lin * theta) / lin
    if lin < -1e-15:
        return np.sin(lin * theta) / lin
    return theta


def theta_of_chi(chi: FloatArray, lin: float) -> FloatArray:
    """theta(chi), the inverse of :func:`chi_of_theta` (NaN where it has none)."""
    if lin > 1e-15:
        return np.arctan(lin * chi) / lin
    if lin < -1e-15:
        with np.errstate(invalid="ignore"):
            return np.arcsin(lin * chi) / lin
    return chi


def pupil_shift(theta: FloatArray, e: FloatArray) -> FloatArray:
    """Entrance-pupil shift along O (metres) for off-axis angles theta (radians)."""
    t2 = theta * theta
    poly = e[0] + (e[1] + e[2] * t2) * t2
    safe = np.where(theta > 1e-8, theta, 1.0)
    ratio = np.where(theta > 1e-8, safe / np.sin(safe) - 1.0, t2 / 6.0)
    shift: FloatArray = ratio * poly
    return shift


def distort(p: FloatArray, o: FloatArray, r: FloatArray, e: FloatArray, lin: float) -> FloatArray:
    """The direction w (..., 3) projected by the CAHV part, for p = P - C (..., 3)."""
    o = o / np.linalg.norm(o)
    zeta = p @ o
    lam_vec = p - zeta[..., None] * o
    lam = np.linalg.norm(lam_vec, axis=-1)
    theta = _solve_theta(zeta, lam, e, lin)
    chi = chi_of_theta(theta, lin)
    mu = r[0] + (r[1] + r[2] * chi * chi) * chi * chi
    on_axis = ~(lam > _SMALL * np.abs(zeta)) & (zeta > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        along = np.where(on_axis, zeta, lam / np.where(chi > 0, chi, np.nan))
    w = along[..., None] * o + (1.0 + mu)[..., None] * lam_vec
    return np.where(np.isfinite(theta)[..., None] | on_axis[..., None], w, np.nan)


def undistort(
    rr: FloatArray, c: FloatArray, o: FloatArray, r: FloatArray, e: FloatArray, lin: float
) -> tuple[FloatArray, FloatArray]:
    """Ray origins (entrance pupil, ..., 3) and unit directions for CAHV rays rr (..., 3)."""
    o = o / np.linalg.norm(o)
    omega = rr @ o
    lam_vec = rr - omega[..., None] * o
    lam = np.linalg.norm(lam_vec, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        observed = lam / omega  # chi (1 + mu(chi))
    chi = _solve_chi(np.where(omega > 0, observed, np.nan), r)
    theta = theta_of_chi(chi, lin)
    theta = np.where(theta <= theta_limit(lin) + 1e-12, theta, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        unit_lam = lam_vec / np.where(lam > 0, lam, 1.0)[..., None]
    ray = np.cos(theta)[..., None] * o + np.sin(theta)[..., None] * unit_lam
    origin = c + pupil_shift(np.nan_to_num(theta), e)[..., None] * o
    origin = np.where(np.isfinite(theta)[..., None], origin, np.nan)
    return origin, ray


def _solve_theta(zeta: FloatArray, lam: FloatArray, e: FloatArray, lin: float) -> FloatArray:
    """theta in [0, limit] with zeta sin - lam cos - (theta - sin) E(theta) = 0 (NaN if none)."""

    def f(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        s, co = np.sin(t), np.cos(t)
        t2 = t * t
        poly = e[0] + (e[1] + e[2] * t2) * t2
        dpoly = (2.0 * e[1] + 4.0 * e[2] * t2) * t
        value = zeta * s - lam * co - (t - s) * poly
        slope = zeta * co + lam * s - (1.0 - co) * poly - (t - s) * dpoly
        return value, slope

    start = np.arctan2(lam, zeta)
    hi = np.broadcast_to(np.minimum(theta_limit(lin), start + np.pi / 2.0), start.shape).copy()
    # near the camera, E's polynomial can outgrow the range at large angles: pull the upper
    # end of the bracket back towards the pinhole angle until it holds a sign change
    width = hi - start
    for _ in range(40):
        with np.errstate(invalid="ignore", over="ignore"):
            value, _ = f(hi)
        short = value < 0
        if not np.any(short):
            break
        width = np.where(short, 0.5 * width, width)
        hi = np.where(short, np.minimum(start + width, hi), hi)
    return _safeguarded(f, np.zeros_like(start), hi, start)


def _solve_chi(observed: FloatArray, r: FloatArray) -> FloatArray:
    """chi >= 0 with chi (1 + r0 + r1 chi^2 + r2 chi^4) = observed, on the increasing branch."""

    def f(k: FloatArray) -> tuple[FloatArray, FloatArray]:
        k2 = k * k
        value = k * (1.0 + r[0] + (r[1] + r[2] * k2) * k2) - observed
        slope = 1.0 + r[0] + (3.0 * r[1] + 5.0 * r[2] * k2) * k2
        return value, slope

    k_max = _first_turning_point(r)
    if np.isfinite(k_max):
        hi = np.full_like(observed, k_max)
    else:  # increasing for ever: double until past the root
        hi = np.where(np.isfinite(observed), np.abs(observed) + 1.0, np.nan)
        for _ in range(64):
            value, _ = f(hi)
            grow = value < 0
            if not np.any(grow):
                break
            hi = np.where(grow, 2.0 * hi, hi)
    return _safeguarded(f, np.zeros_like(observed), hi, observed / (1.0 + r[0]))


def _first_turning_point(r: FloatArray) -> float:
    """The smallest chi > 0 where d/dchi chi (1 + mu) = 0 (inf if it keeps increasing)."""
    roots = np.roots([5.0 * r[2], 3.0 * r[1], 1.0 + r[0]])  # in chi^2
    real = [x.real for x in np.atleast_1d(roots) if abs(x.imag) < 1e-12 and x.real > 0]
    return float(np.sqrt(min(real))) if real else float("inf")


def _safeguarded(
    f: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
    lo: FloatArray,
    hi: FloatArray,
    x: FloatArray,
) -> FloatArray:
    """Root of increasing f in [lo, hi] (f(lo) <= 0 <= f(hi)), NaN where there is none."""
    lo, hi = np.asarray(lo, dtype=np.float64).copy(), np.asarray(hi, dtype=np.float64).copy()
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        f_hi, _ = f(hi)
        valid = np.isfinite(lo) & np.isfinite(hi) & (f_hi >= 0)
        x = np.where(valid & (x > lo) & (x < hi), x, 0.5 * (lo + hi))
        for _ in range(_ITERATIONS):
            value, slope = f(x)
            done = np.abs(value) <= _TOL * (1.0 + np.abs(x)) * np.maximum(np.abs(slope), 1.0)
            lo = np.where(value < 0, x, lo)
            hi = np.where(value > 0, x, hi)
            step = x - value / slope
            inside = np.isfinite(step) & (step > lo) & (step < hi)
            new = np.where(inside, step, 0.5 * (lo + hi))
            settled = done | (hi - lo <= 4e-16 * np.maximum(np.abs(x), 1e-300)) | ~valid
            if np.all(settled):
                break
            x = np.where(settled, x, new)
    return np.where(valid, x, np.nan)
