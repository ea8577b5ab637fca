"""The magnetometer model and the quantities derived from it.

Conventions: world ENU (z up), north along +y, gravity g_world = [0, 0, -g]; body FLU.
A raw reading m (uT, magnetometer axes) of the field b_body (body axes) is

    m = inv(A) @ R_body_mag.T @ b_body + h + noise

h the hard iron (uT), A the soft-iron correction (3x3 symmetric positive definite),
R_body_mag the chip's orientation. The calibrated field is b_body = R_body_mag @ A @ (m - h).
The Earth's field in the world is F [0, cos I, -sin I]: magnitude F, inclination I (below the
horizontal, positive where the field points down), declination 0 (not observable without an
absolute heading). Without a declared site field, A is normalised to determinant 1.
"""

from __future__ import annotations

import numpy as np

SYM_INDEX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # the 6 free elements of a symmetric 3x3


def field_world(field_uT: float, inclination_rad: float) -> np.ndarray:
    """The Earth's field (3,) in ENU with declination 0 (north = +y)."""
    return field_uT * np.array([0.0, np.cos(inclination_rad), -np.sin(inclination_rad)])


def sym_from_vec(v: np.ndarray) -> np.ndarray:
    """6-vector [a11, a22, a33, a12, a13, a23] -> symmetric 3x3."""
    A = np.empty((3, 3))
    for k, (i, j) in enumerate(SYM_INDEX):
        A[i, j] = A[j, i] = v[k]
    return A


def vec_from_sym(A: np.ndarray) -> np.ndarray:
    return np.array([A[i, j] for i, j in SYM_INDEX])


def readings(b_body: np.ndarray, hard_iron: np.ndarray, soft_iron: np.ndarray, R_body_mag: np.ndarray
             ) -> np.ndarray:
    """Noise-free raw readings (N, 3) of the body-axes fields b_body (N, 3)."""
    M = np.linalg.inv(soft_iron) @ R_body_mag.T
    return b_body @ M.T + hard_iron


def calibrated(m: np.ndarray, hard_iron: np.ndarray, soft_iron: np.ndarray, R_body_mag: np.ndarray) -> np.ndarray:
    """Body-axes fields (N, 3) of raw readings m (N, 3): R_body_mag @ A @ (m - h)."""
    return (m - hard_iron) @ (R_body_mag @ soft_iron).T


def normalise(soft_iron: np.ndarray, field_uT: float) -> tuple[np.ndarray, float]:
    """(A, F) rescaled so that det A = 1 (the readings they predict are unchanged)."""
    s = np.linalg.det(soft_iron) ** (-1.0 / 3.0)
    return soft_iron * s, field_uT * s


def level_headings(step_deg: float = 10.0) -> np.ndarray:
    """Headings (rad) at which heading errors are evaluated, body level."""
    return np.radians(np.arange(0.0, 360.0, step_deg))


def level_fields(field_uT: float, inclination_rad: float, heading_rad: np.ndarray) -> np.ndarray:
    """Body-axes fields (N, 3) of a level body at ENU yaws heading_rad (0 = facing east)."""
    b = field_world(field_uT, inclination_rad)
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    # R_world_body = Rz(psi); b_body = Rz(psi).T b
    return np.stack([c * b[0] + s * b[1], -s * b[0] + c * b[1], np.full_like(c, b[2])], axis=1)


def heading_of(b_body: np.ndarray) -> np.ndarray:
    """ENU yaw (rad) of a level body from its body-axes field (declination 0): atan2(b_x, b_y),
    the inverse of level_fields."""
    return np.arctan2(b_body[:, 0], b_body[:, 1])


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def heading_errors(m: np.ndarray, heading_rad: np.ndarray, hard_iron: np.ndarray, soft_iron: np.ndarray,
                   R_body_mag: np.ndarray) -> np.ndarray:
    """Heading errors (rad) a calibration leaves on readings m (N, 3) taken level at heading_rad."""
    return wrap(heading_of(calibrated(m, hard_iron, soft_iron, R_body_mag)) - heading_rad)
