"""Rigid-body geometry: poses, rotations, frames.

Conventions (also in README "Conventions"):

* ``T_a_b`` is a 4x4 homogeneous pose of frame b expressed in frame a. It maps
  points from b to a: ``p_a = R_a_b @ p_b + t_a_b``. Chains read as products:
  ``T_nav_cam = T_nav_body @ T_body_cam``.
* ``R_a_b`` is its 3x3 rotation (columns = b's axes in a's terms), ``t_a_b`` its
  translation (b's origin in a).
* ``rt_a_b`` is the 6-vector ``[rotation vector (rad), translation]`` used inside
  the optimiser (OpenCV's rvec, tvec renamed at the boundary).
* body frame FLU (x forward, y left, z up); navigation ENU (x east, y north, z up);
  camera OpenCV (x right, y down, z forward into the scene).
* Units: metres and radians inside; degrees only in files and reports.
* Quaternions are ``[w, x, y, z]`` (Hamilton, scalar first).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

# Body (FLU) unit vectors by token; negations are derived.
BODY_AXES = {"F": (1.0, 0.0, 0.0), "L": (0.0, 1.0, 0.0), "U": (0.0, 0.0, 1.0)}
# Navigation (ENU) unit vectors by token (used by `rigcal project --axes`).
NAV_AXES = {"E": (1.0, 0.0, 0.0), "N": (0.0, 1.0, 0.0), "U": (0.0, 0.0, 1.0)}

# `look:` shorthand -> camera x, y, z axes in body terms (docs/formats.md#rig-yaml).
LOOK_AXES = {
    "forward": ("-L", "-U", "F"),
    "backward": ("L", "-U", "-F"),
    "left": ("F", "-U", "L"),
    "right": ("-F", "-U", "-L"),
    "down": ("-L", "-F", "-U"),
    "up": ("L", "-F", "U"),
}

ORTHONORMAL_TOL = 1e-6


def make_T(R: np.ndarray, t: Sequence[float]) -> np.ndarray:
    """4x4 pose from R (3, 3) and t (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def inv_T(T_a_b: np.ndarray) -> np.ndarray:
    """T_b_a from T_a_b, using R^T rather than a general inverse."""
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., :3, 3]
    out = np.zeros_like(T_a_b, dtype=float)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def transform(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """p_a = R_a_b p_b + t_a_b for p_b of shape (3,) or (N, 3)."""
    p_b = np.asarray(p_b, dtype=float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def token_vector(token: object, table: dict[str, tuple[float, float, float]]) -> np.ndarray:
    """'F', '-L', ... or a 3-vector -> a unit 3-vector. Raises ValueError with what was expected."""
    if isinstance(token, str):
        name = token.strip()
        sign = 1.0
        if name.startswith("-"):
            sign, name = -1.0, name[1:]
        elif name.startswith("+"):
            name = name[1:]
        if name not in table:
            allowed = ", ".join(s + k for k in table for s in ("", "-"))
            raise ValueError(f"{token!r} is not one of {allowed} or a 3-vector")
        return sign * np.array(table[name])
    try:
        v = np.asarray(token, dtype=float) if _is_number_list(token) else None
    except OverflowError:
        v = None  # an integer too large for a float
    if v is None or v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{token!r} is not an axis name or a finite 3-vector")
    big = np.abs(v).max()
    if big < 1e-12:
        raise ValueError(f"{token!r} is a zero vector")
    v = v / big  # first, so that squaring cannot overflow for huge entries
    return v / np.linalg.norm(v)


def _is_number_list(x: object) -> bool:
    return isinstance(x, (list, tuple, np.ndarray)) and all(
        isinstance(e, (int, float, np.floating, np.integer)) and not isinstance(e, bool) for e in x
    )


def R_from_axes(axes: Sequence[object], table: dict = BODY_AXES) -> np.ndarray:
    """Rotation whose columns are the given x, y, z axes (tokens or vectors).

    Raises ValueError unless they form a right-handed orthonormal frame within
    ORTHONORMAL_TOL after normalising (this is GTSAM's Rot3(x, y, z) as data).
    """
    if not isinstance(axes, (list, tuple)) or len(axes) != 3:
        raise ValueError(f"expected three axes [X, Y, Z], got {axes!r}")
    cols = [token_vector(a, table) for a in axes]
    R = np.column_stack(cols)
    if np.abs(R.T @ R - np.eye(3)).max() > ORTHONORMAL_TOL:
        raise ValueError(f"{_fmt_axes(axes)} is not an orthonormal frame")
    if np.linalg.det(R) < 0:
        raise ValueError(f"{_fmt_axes(axes)} is not a right-handed frame")
    return R


def _fmt_axes(axes: Sequence[object]) -> str:
    return "[" + ", ".join(str(a) for a in axes) + "]"


def R_from_look(look: str) -> np.ndarray:
    """Camera axes for `look: forward|backward|left|right|up|down`."""
    if look not in LOOK_AXES:
        raise ValueError(f"{look!r} is not one of {', '.join(LOOK_AXES)}")
    return R_from_axes(LOOK_AXES[look])


def check_rotation(R: np.ndarray, tol: float = ORTHONORMAL_TOL) -> np.ndarray:
    """Validate a 3x3 rotation matrix; returns it as float array."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError("expected a finite 3x3 matrix")
    if np.abs(R.T @ R - np.eye(3)).max() > tol:
        raise ValueError("is not orthonormal (R^T R != I)")
    if np.linalg.det(R) < 0:
        raise ValueError("has determinant -1 (a reflection, not a rotation)")
    return R


def R_from_quat(q: Sequence[float], tol: float = 1e-6) -> np.ndarray:
    """[w, x, y, z] unit quaternion -> R. Raises ValueError if |q| differs from 1 by more than tol."""
    q = np.asarray(q, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError("expected four finite numbers [w, x, y, z]")
    n = np.linalg.norm(q)
    if abs(n - 1.0) > tol:
        raise ValueError(f"is not a unit quaternion (norm {n:.9g})")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_R(R: np.ndarray) -> np.ndarray:
    """R -> [w, x, y, z] with w >= 0 (Shepperd's method, stable for all angles)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    cand = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(cand))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif i == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif i == 2:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def R_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (..., 3) -> (..., 3, 3). Exact near zero (Taylor)."""
    r = np.asarray(r, dtype=float)
    th2 = np.sum(r * r, axis=-1)[..., None, None]
    th = np.sqrt(th2)
    small = th2 < 1e-12
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(safe) / safe)
    # (1 - cos th) / th^2 written with the half angle: no cancellation for small th.
    half = np.sin(0.5 * safe) / safe
    b = np.where(small, 0.5 - th2 / 24.0, 2.0 * half * half)
    K = skew(r)
    return np.eye(3) + a * K + b * (K @ K)


def rotvec_from_R(R: np.ndarray) -> np.ndarray:
    """Inverse of R_from_rotvec for a single rotation, stable at 0 and pi."""
    q = quat_from_R(R)  # w >= 0 so the angle lies in [0, pi]
    w, v = q[0], q[1:]
    s = np.linalg.norm(v)
    if s < 1e-12:
        return 2.0 * v  # first order; exact limit
    angle = 2.0 * np.arctan2(s, w)
    return v / s * angle


def rt_from_T(T_a_b: np.ndarray) -> np.ndarray:
    """4x4 -> 6-vector [rotvec, t]."""
    return np.concatenate([rotvec_from_R(T_a_b[:3, :3]), T_a_b[:3, 3]])


def T_from_rt(rt: np.ndarray) -> np.ndarray:
    """6-vector(s) [rotvec, t] -> 4x4 pose(s); works on (..., 6)."""
    rt = np.asarray(rt, dtype=float)
    T = np.zeros(rt.shape[:-1] + (4, 4))
    T[..., :3, :3] = R_from_rotvec(rt[..., :3])
    T[..., :3, 3] = rt[..., 3:]
    T[..., 3, 3] = 1.0
    return T


def _axis_part(Rs: np.ndarray) -> np.ndarray:
    """(N, 3) vee(R - R^T) of rotations (N, 3, 3): 2 sin(angle) times the unit axis."""
    return np.stack([Rs[:, 2, 1] - Rs[:, 1, 2], Rs[:, 0, 2] - Rs[:, 2, 0], Rs[:, 1, 0] - Rs[:, 0, 1]], axis=1)


def rotation_angles(Rs: np.ndarray) -> np.ndarray:
    """Angles (rad) of rotations (N, 3, 3), vectorised: atan2(|axis part|, trace part) is
    accurate at 0 and pi alike, unlike arccos of the trace."""
    tr = np.trace(Rs, axis1=1, axis2=2)
    return np.arctan2(0.5 * np.linalg.norm(_axis_part(Rs), axis=1), 0.5 * (tr - 1.0))


def rotvecs_from_R(Rs: np.ndarray) -> np.ndarray:
    """rotvec_from_R for rotations (N, 3, 3), vectorised from the axis part; within 10
    degrees of pi, where that part vanishes, each rotation takes rotvec_from_R."""
    ang = rotation_angles(Rs)
    s = np.sin(ang)
    scale = np.where(s > 1e-9, ang / np.where(s > 1e-9, s, 1.0), 1.0)
    out = 0.5 * _axis_part(Rs) * scale[:, None]
    for k in np.flatnonzero(ang > np.deg2rad(170.0)):
        out[k] = rotvec_from_R(Rs[k])
    return out


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation in degrees (robust near 0 via the quaternion)."""
    return float(np.degrees(np.linalg.norm(rotvec_from_R(R))))


def T_nav_body_from_heading(position: Sequence[float], heading_deg: float) -> np.ndarray:
    """Level body pose in ENU: heading in degrees clockwise from north (0 = flying north)."""
    h = np.radians(heading_deg)
    F = np.array([np.sin(h), np.cos(h), 0.0])
    L = np.array([-np.cos(h), np.sin(h), 0.0])  # U x F
    U = np.array([0.0, 0.0, 1.0])
    return make_T(np.column_stack([F, L, U]), position)


def T_nav_body_from_axes(position: Sequence[float], axes: Sequence[object]) -> np.ndarray:
    """Body pose in ENU from the body F, L, U axes written in ENU terms (e.g. ['N', '-E', 'U'])."""
    return make_T(R_from_axes(axes, NAV_AXES), position)


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation(s) nearest M (..., 3, 3) in the Frobenius norm: SVD with the determinant
    fixed to +1 (the step shared by the chordal mean, Kabsch and the rigid fit)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.ones(U.shape[:-1])
    d[..., 2] = np.linalg.det(U @ Vt)
    return (U * d[..., None, :]) @ Vt


def mean_rotation(Rs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Chordal L2 mean of rotations (N, 3, 3): the rotation nearest the weighted sum (SVD)."""
    Rs = np.asarray(Rs, dtype=float)
    w = np.ones(len(Rs)) if weights is None else np.asarray(weights, dtype=float)
    return nearest_rotation(np.einsum("n,nij->ij", w, Rs))


def robust_mean_pose(Ts: np.ndarray, iters: int = 3) -> np.ndarray:
    """Robust average of poses (N, 4, 4): rotation by iteratively reweighted chordal mean
    (weights fall off past 3x the median angular residual), translation by the
    element-wise median of the views the rotation kept. Used to average one graph edge
    over many observations; robust_mean_poses is the one implementation."""
    return robust_mean_poses(np.asarray(Ts, dtype=float)[None], iters)[0]


def robust_mean_poses(Ts: np.ndarray, iters: int = 3) -> np.ndarray:
    """robust_mean_pose of each group of poses Ts (G, N, 4, 4) (N the same for every
    group): (G, 4, 4), batched over the groups (the pose graph averages hundreds of frames
    of 2-3 views each, where a call per frame cost more than its arithmetic). Two views:
    their residual angles are equal, so every weight is, and the plain means are the answer."""
    Ts = np.asarray(Ts, dtype=float)
    G, n = Ts.shape[:2]
    if n == 1:
        return Ts[:, 0].copy()
    Rs = Ts[:, :, :3, :3]
    R = nearest_rotation(np.einsum("n,gnij->gij", np.ones(n), Rs))
    out = np.zeros((G, 4, 4))
    out[:, 3, 3] = 1.0
    if n == 2:
        out[:, :3, :3] = R
        out[:, :3, 3] = Ts[:, :, :3, 3].mean(axis=1)
        return out
    w = np.ones((G, n))
    for _ in range(iters):
        ang = rotation_angles(np.einsum("gji,gnjk->gnik", R, Rs).reshape(-1, 3, 3)).reshape(G, n)
        scale = 3.0 * np.maximum(np.median(ang, axis=1), 1e-4)[:, None]
        w = 1.0 / (1.0 + (ang / scale) ** 2)
        w[ang > 3 * scale] = 0.0
        w[w.sum(axis=1) == 0] = 1.0
        R = nearest_rotation(np.einsum("gn,gnij->gij", w, Rs))
    out[:, :3, :3] = R
    t = Ts[:, :, :3, 3]
    keep = w > 0
    if keep.all():
        out[:, :3, 3] = np.median(t, axis=1)
    else:
        out[:, :3, 3] = [np.median(tg[k], axis=0) for tg, k in zip(t, keep)]
    return out


def fit_rigid_to(S: np.ndarray, D: np.ndarray) -> np.ndarray:
    """The rigid T minimising sum ||R R_S - R_D||^2 + ||R (t_S - c_S) - (t_D - c_D)||^2 over
    poses S, D (N, 4, 4): rotation by the polar decomposition of the summed rotation and
    centred-position correlations, translation from the centroids. T @ S_i ~ D_i."""
    tD, tS = D[:, :3, 3], S[:, :3, 3]
    cD, cS = tD.mean(0), tS.mean(0)
    M = np.einsum("nij,nkj->ik", D[:, :3, :3], S[:, :3, :3]) + (tD - cD).T @ (tS - cS)
    R = nearest_rotation(M)
    return make_T(R, cD - R @ cS)
