"""Camera models: pinhole with OpenCV distortion, and fisheye (equidistant, Kannala-Brandt).

Pixel convention (OpenCV's): integer pixel coordinates are pixel *centres*; (0, 0)
is the centre of the top-left pixel, u grows right, v grows down. The image covers
u in [-0.5, width - 0.5], v in [-0.5, height - 0.5].

The core functions are pure and broadcast: the distortion coefficients may be one
vector for all points or one row per point, which is how the bundle adjustment
evaluates every observation at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache

import numpy as np

PINHOLE_DIST_LENGTHS = (2, 4, 5, 8, 12)
FISHEYE_DIST_LENGTH = 4
MODELS = ("pinhole", "fisheye")

# Distortion model names used by --distortion and in reports, by coefficient count.
PINHOLE_MODEL_NAMES = {2: "radial2", 4: "radtan4", 5: "radtan5", 8: "rational8", 12: "thinprism12"}


def pad12(dist: np.ndarray) -> np.ndarray:
    """OpenCV pinhole coefficients (..., k) with k in 2,4,5,8,12 -> (..., 12), zeros appended."""
    dist = np.asarray(dist, dtype=float)
    out = np.zeros(dist.shape[:-1] + (12,))  # np.pad costs 10x this in the solver's inner loop
    out[..., : dist.shape[-1]] = dist
    return out


def distort_pinhole(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Normalised undistorted (..., 2) -> normalised distorted (..., 2), OpenCV's formula:
    radial (1+k1 r2+k2 r4+k3 r6)/(1+k4 r2+k5 r4+k6 r6), tangential p1 p2, thin prism s1..s4."""
    d = pad12(dist)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = (d[..., i] for i in range(12))
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xy = x * y
    xd = x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * xy + s3 * r2 + s4 * r4
    return np.stack([xd, yd], axis=-1)


def fisheye_theta_d(theta: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Equidistant model: theta_d = theta (1 + k1 th^2 + k2 th^4 + k3 th^6 + k4 th^8)."""
    d = np.asarray(dist, dtype=float)
    t2 = theta * theta
    return theta * (1 + t2 * (d[..., 0] + t2 * (d[..., 1] + t2 * (d[..., 2] + t2 * d[..., 3]))))


def distort_fisheye(p_cam: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Camera-frame points (..., 3) -> normalised distorted (..., 2).

    Uses theta = atan2(rho, z) rather than atan(rho / z) so that points at or past
    90 degrees (wide fisheye) map continuously; identical to OpenCV for z > 0."""
    x, y, z = p_cam[..., 0], p_cam[..., 1], p_cam[..., 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    theta_d = fisheye_theta_d(theta, dist)
    safe = np.where(rho > 0, rho, 1.0)
    scale = np.where(rho > 0, theta_d / safe, 0.0)
    # On the axis theta_d/rho -> 1/z; keep the exact limit.
    scale = np.where(rho > 0, scale, 1.0 / np.where(z != 0, z, 1.0))
    return np.stack([x * scale, y * scale], axis=-1)


def max_valid_radius_pinhole(dist: np.ndarray, r_limit: float = 20.0) -> float:
    """Largest undistorted normalised radius over which the radial map r -> r*radial(r)
    is still increasing. Past it the model folds back and a pixel would be a lie."""
    return _max_valid_radius_pinhole(tuple(float(x) for x in np.ravel(dist)), float(r_limit))


@lru_cache(maxsize=256)
def _max_valid_radius_pinhole(dist: tuple, r_limit: float) -> float:
    # Cached: the calibration asks this of the same coefficients once per view.
    d = pad12(np.array(dist))
    r = np.linspace(0.0, r_limit, 20001)[1:]
    rd = r * (1 + d[0] * r**2 + d[1] * r**4 + d[4] * r**6) / (1 + d[5] * r**2 + d[6] * r**4 + d[7] * r**6)
    bad = np.nonzero(np.diff(rd) <= 0)[0]
    denom = 1 + d[5] * r**2 + d[6] * r**4 + d[7] * r**6
    bad_den = np.nonzero(denom <= 1e-9)[0]
    # The turning point lies within one sample of r[bad[0]]; stay on the safe side of it.
    cut = min([r_limit] + ([r[max(bad[0] - 1, 0)]] if len(bad) else [])
              + ([r[max(bad_den[0] - 1, 0)]] if len(bad_den) else []))
    return float(cut)


def max_valid_theta_fisheye(dist: np.ndarray, theta_limit: float = np.pi) -> float:
    """Largest angle from the optical axis over which theta_d(theta) is increasing."""
    return _max_valid_theta_fisheye(tuple(float(x) for x in np.ravel(dist)), float(theta_limit))


@lru_cache(maxsize=256)
def _max_valid_theta_fisheye(dist: tuple, theta_limit: float) -> float:
    th = np.linspace(0.0, theta_limit, 20001)[1:]
    td = fisheye_theta_d(th, np.array(dist))
    bad = np.nonzero(np.diff(td) <= 0)[0]
    return float(th[max(bad[0] - 1, 0)]) if len(bad) else float(theta_limit)


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera. `dist` is OpenCV's order (docs/formats.md#rig-yaml)."""

    model: str  # "pinhole" | "fisheye"
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        return np.array(self.dist, dtype=float)

    @property
    def resolution(self) -> tuple[int, int]:
        return (self.width, self.height)

    @cached_property
    def _valid_limit(self) -> float:
        if self.model == "fisheye":
            # Beyond ~ 110 deg the equidistant polynomial is extrapolating; no real lens here.
            return min(max_valid_theta_fisheye(self.D), np.radians(110.0))
        return max_valid_radius_pinhole(self.D)

    def with_(self, **changes) -> "CameraModel":
        return replace(self, **changes)

    def with_values(self, values) -> "CameraModel":
        """The same model and size with [fx, fy, cx, cy, dist...] from an optimiser vector
        (solve.Intrinsics.values)."""
        v = [float(x) for x in values]
        return replace(self, fx=v[0], fy=v[1], cx=v[2], cy=v[3], dist=tuple(v[4:]))

    def project(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """p_cam (N, 3) -> (uv (N, 2), valid (N,)).

        Invalid points (behind a pinhole camera, past a fisheye's field of view, or
        where the distortion model folds back) get NaN pixels, never a number."""
        p = np.atleast_2d(np.asarray(p_cam, dtype=float))
        if self.model == "fisheye":
            xd = distort_fisheye(p, self.D)
            rho = np.hypot(p[:, 0], p[:, 1])
            theta = np.arctan2(rho, p[:, 2])
            # the pinhole itself has no direction, so no pixel
            valid = (theta < self._valid_limit) & (np.hypot(rho, p[:, 2]) > 1e-12)
        else:
            z = p[:, 2]
            valid = z > 1e-12
            zs = np.where(valid, z, 1.0)
            xn = p[:, :2] / zs[:, None]
            valid &= np.hypot(xn[:, 0], xn[:, 1]) < self._valid_limit
            xd = distort_pinhole(xn, self.D)
        valid &= np.all(np.isfinite(xd), axis=1)
        uv = np.column_stack([self.fx * xd[:, 0] + self.cx, self.fy * xd[:, 1] + self.cy])
        uv[~valid] = np.nan
        return uv, valid

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """True where a pixel lies inside the image (pixel-centre convention), less a margin."""
        uv = np.atleast_2d(uv)
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin)
                & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin)
                & (uv[:, 1] <= self.height - 0.5 - margin)
            )

    def unproject(self, uv: np.ndarray, iters: int = 30) -> np.ndarray:
        """Pixels (N, 2) -> unit rays (N, 3) in the camera frame (Newton on the distortion).

        A pixel with no preimage inside the model's valid field (past the radius or
        angle where the distortion folds back) gets a NaN ray, never a wrong one."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        xd = np.column_stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy])
        with np.errstate(all="ignore"):
            if self.model == "fisheye":
                rays, theta, resid = _undistort_fisheye(xd, self.D, iters)
                ok = (resid < UNDISTORT_TOL) & (theta >= 0) & (theta < self._valid_limit)
            else:
                xn, resid = _undistort_pinhole(xd, self.D, iters, self._valid_limit)
                rays = np.column_stack([xn, np.ones(len(xn))])
                ok = (resid < UNDISTORT_TOL) & (np.hypot(xn[:, 0], xn[:, 1]) < self._valid_limit)
            rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        rays[~ok] = np.nan
        return rays


# Newton's residual (normalised image units) under which an undistortion counts as solved.
UNDISTORT_TOL = 1e-10


def _radial_start(xd: np.ndarray, dist: np.ndarray, r_max: float) -> np.ndarray:
    """Starting points (N, 2) for Newton: invert the radial part alone by bisection on
    [0, r_max], where it is increasing. Starting at xd itself, a point far off-axis can
    take dozens of Newton steps or land on another preimage."""
    d = pad12(dist)
    rd = np.hypot(xd[:, 0], xd[:, 1])
    lo, hi = np.zeros_like(rd), np.full_like(rd, r_max)
    for _ in range(40):  # a bracket of r_max * 2^-40; Newton polishes the rest
        r = 0.5 * (lo + hi)
        r2 = r * r
        g = r * (1 + r2 * (d[..., 0] + r2 * (d[..., 1] + r2 * d[..., 4]))) / (
            1 + r2 * (d[..., 5] + r2 * (d[..., 6] + r2 * d[..., 7])))
        below = g < rd
        lo, hi = np.where(below, r, lo), np.where(below, hi, r)
    scale = np.where(rd > 0, 0.5 * (lo + hi) / np.where(rd > 0, rd, 1.0), 1.0)
    return xd * scale[:, None]


def _undistort_pinhole(xd: np.ndarray, dist: np.ndarray, iters: int, r_max: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """Solve distort(x) = xd (N, 2) by Newton with a finite-difference 2x2 Jacobian,
    vectorised over the points still moving. Returns x (N, 2) and the final residual (N,)."""
    x = _radial_start(xd, dist, r_max)
    h = 1e-7
    # Converged once the residual is at rounding level for the point's size.
    tol = 1e-15 * (1.0 + np.abs(xd).max(axis=1))
    active = np.arange(len(xd))
    for _ in range(iters):
        f = distort_pinhole(x[active], dist) - xd[active]
        moving = (np.abs(f) > tol[active, None]).any(axis=1)  # NaN stops: the residual test rejects it
        active, f = active[moving], f[moving]
        if not len(active):
            break
        xa = x[active]
        fx = (distort_pinhole(xa + [h, 0.0], dist) - distort_pinhole(xa - [h, 0.0], dist)) / (2 * h)
        fy = (distort_pinhole(xa + [0.0, h], dist) - distort_pinhole(xa - [0.0, h], dist)) / (2 * h)
        # Explicit 2x2 inverse: a singular Jacobian at one point must not stop the others.
        det = fx[:, 0] * fy[:, 1] - fy[:, 0] * fx[:, 1]
        det = np.where(det != 0, det, np.nan)
        x[active] = xa - np.column_stack([fy[:, 1] * f[:, 0] - fy[:, 0] * f[:, 1],
                                          fx[:, 0] * f[:, 1] - fx[:, 1] * f[:, 0]]) / det[:, None]
    resid = np.abs(distort_pinhole(x, dist) - xd).max(axis=1)
    return x, np.where(np.isfinite(resid), resid, np.inf)


def _undistort_fisheye(xd: np.ndarray, dist: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Invert theta_d(theta) by Newton, then rebuild the ray at angle theta from the axis.
    Returns rays (N, 3) (not yet normalised), theta (N,) and the final residual (N,)."""
    theta_d = np.hypot(xd[:, 0], xd[:, 1])
    th = theta_d.copy()
    d = np.asarray(dist, dtype=float)
    for _ in range(iters):
        t2 = th * th
        f = fisheye_theta_d(th, d) - theta_d
        df = 1 + 3 * d[0] * t2 + 5 * d[1] * t2**2 + 7 * d[2] * t2**3 + 9 * d[3] * t2**4
        step = f / df
        th = th - step
        if not (np.abs(step) >= 1e-15).any():
            break
    resid = np.abs(fisheye_theta_d(th, d) - theta_d)
    safe = np.where(theta_d > 0, theta_d, 1.0)
    dirx = np.where(theta_d > 0, xd[:, 0] / safe, 0.0)
    diry = np.where(theta_d > 0, xd[:, 1] / safe, 0.0)
    s = np.sin(th)
    rays = np.column_stack([dirx * s, diry * s, np.cos(th)])
    return rays, th, np.where(np.isfinite(resid), resid, np.inf)
