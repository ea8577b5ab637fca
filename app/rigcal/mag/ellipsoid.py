"""The closed-form start: an algebraic ellipsoid fit to raw readings (the onboard
calibrators' method), and the coverage check that says which directions a recording lacks.

The readings m (N, 3) of a constant-magnitude field lie on the ellipsoid
(m - h)^T A^T A (m - h) = F^2. A general quadric is fitted by linear least squares (the
right singular vector of the design matrix of least singular value, on centred and scaled
data); it is an ellipsoid when its 3x3 part is definite. A is the symmetric square root of
that part: any rotation belongs to R_body_mag, which the ellipsoid cannot see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.errors import CalibrationError

COVERAGE_DEG = 50.0  # each of the 6 axis directions needs a reading within this angle
AXIS_NAMES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class EllipsoidFit:
    """hard_iron (3,) uT, soft_iron (3, 3) symmetric positive definite, field_uT: the fitted
    radius in A's scale (det A = 1 unless a site field was given)."""

    hard_iron: np.ndarray
    soft_iron: np.ndarray
    field_uT: float


def fit_ellipsoid(m: np.ndarray, field_uT: float | None = None, label: str = "magnetometer") -> EllipsoidFit:
    """Closed-form ellipsoid through raw readings m (N, 3). field_uT given: A scales so the
    calibrated field has that magnitude; else det A = 1. CalibrationError (naming the missing
    directions) when the readings do not determine an ellipsoid."""
    m = np.asarray(m, float)
    mu = m.mean(axis=0)
    s = np.sqrt(((m - mu) ** 2).sum(axis=1).mean())
    x, y, z = ((m - mu) / s).T
    D = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z, np.ones_like(x)])
    v = np.linalg.svd(D, full_matrices=False)[2][-1]
    Q = np.array([[v[0], v[5], v[4]], [v[5], v[1], v[3]], [v[4], v[3], v[2]]])
    n = v[6:9]
    try:
        c = -np.linalg.solve(Q, n)
    except np.linalg.LinAlgError:
        c = None
    if c is not None:
        k = c @ Q @ c - v[9]
        M = Q / k if k != 0 else Q * np.nan
        ev = np.linalg.eigvalsh(M) if np.all(np.isfinite(M)) else np.array([-1.0])
    if c is None or ev.min() <= 0:
        missing = missing_directions(m, 0.5 * (m.min(axis=0) + m.max(axis=0)), np.eye(3))
        raise CalibrationError(f"{label}: the readings do not lie on an ellipsoid" + _coverage_hint(missing))
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    S = (V * np.sqrt(lam)) @ V.T / s  # the symmetric square root of M; |S (m - h)| = 1 in raw units
    S = 0.5 * (S + S.T)
    h = mu + s * c
    if field_uT is not None:
        return EllipsoidFit(h, S * field_uT, float(field_uT))
    scale = np.linalg.det(S) ** (-1.0 / 3.0)
    return EllipsoidFit(h, S * scale, float(scale))


def missing_directions(m: np.ndarray, hard_iron: np.ndarray, soft_iron: np.ndarray,
                       limit_deg: float = COVERAGE_DEG) -> list[str]:
    """The magnetometer axis directions (+x .. -z) that no calibrated reading comes within
    limit_deg of: the orientations the recording lacks."""
    u = (np.asarray(m) - hard_iron) @ soft_iron.T
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    best = np.concatenate([u.max(axis=0), -u.min(axis=0)])[[0, 3, 1, 4, 2, 5]]
    return [name for name, b in zip(AXIS_NAMES, best) if b < np.cos(np.radians(limit_deg))]


def _coverage_hint(missing: list[str]) -> str:
    if not missing:
        return " (a magnetic disturbance, or readings that are not a magnetometer's?)"
    return (f": no reading with the field within {COVERAGE_DEG:g} deg of the magnetometer's "
            f"{', '.join(missing)} axis; turn the rig through every orientation (nose down, on each side, "
            f"upside down), away from steel and cars")


def check_coverage(m: np.ndarray, fit: EllipsoidFit, label: str) -> None:
    """CalibrationError naming the directions a recording lacks (coverage too poor to separate
    hard and soft iron)."""
    missing = missing_directions(m, fit.hard_iron, fit.soft_iron)
    if missing:
        raise CalibrationError(f"{label}: the orientations do not cover the sphere" + _coverage_hint(missing))
