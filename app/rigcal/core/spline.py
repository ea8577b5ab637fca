"""Continuous-time trajectories: uniform cumulative cubic B-splines on SO(3) x R^3.

The camera-IMU calibration (docs/formats.md#motion-datasets) needs the body pose, its
angular velocity and its acceleration at any instant: at each image's capture time
(shifted by the camera's clock offset, per row for a rolling shutter) and at each IMU
sample. A spline gives all three analytically from a few control poses, as in Kalibr
and basalt. Rotation and position are split (basalt's choice): the rotation spline is
cumulative on SO(3) (Kim et al. 1995), the position spline the ordinary cubic B-spline.

Time `t` lies in segment i = floor((t - t0) / dt) with u = (t - t0) / dt - i in [0, 1);
segment i is shaped by control points i .. i+3, so a spline of N control points covers
[t0, t0 + (N - 3) dt]. With the cumulative basis B~_j(u) (j = 0..3, B~_0 = 1):

    p(t)         = p_i + sum_j B~_j(u) (p_{i+j} - p_{i+j-1})
    R_world_body = R_i  prod_j Exp(B~_j(u) phi_j),   phi_j = Log(R_{i+j-1}^T R_{i+j})

Angular velocity and acceleration are in the body frame (R^T dR/dt = [omega]x), by the
recursion of Sommer et al. 2020 ("Efficient derivative computation for cumulative
B-splines on Lie groups"): with A_j = Exp(B~_j phi_j),

    omega_{j+1} = A_j^T omega_j + B~'_j phi_j
    alpha_{j+1} = A_j^T alpha_j + B~''_j phi_j + (A_j^T omega_j) x (B~'_j phi_j)

Everything is vectorised over the query times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from rigcal.core import geometry as geo

# Cumulative basis of the uniform cubic B-spline: B~(u) = C @ [1, u, u^2, u^3].
_C = np.array([[6.0, 0.0, 0.0, 0.0],
               [5.0, 3.0, -3.0, 1.0],
               [1.0, 3.0, 3.0, -2.0],
               [0.0, 0.0, 0.0, 1.0]]) / 6.0
ORDER = 4  # control points per segment


@dataclass(frozen=True, eq=False)
class Spline:
    """A trajectory T_world_body(t): control rotations R (N, 3, 3) and positions p (N, 3),
    knots every `dt` seconds from `t0` (seconds, any clock)."""

    t0: float
    dt: float
    R: np.ndarray
    p: np.ndarray

    @property
    def t_end(self) -> float:
        """The last instant the spline covers."""
        return self.t0 + (len(self.p) - ORDER + 1) * self.dt


@dataclass(frozen=True, eq=False)
class Motion:
    """The body's motion at N times t (N,): R_world_body (N, 3, 3), p_world (N, 3) the body
    origin, v_world and a_world (N, 3) its velocity and acceleration in the world frame,
    omega_body and alpha_body (N, 3) the angular velocity and acceleration in body axes.
    What a spline gives at any instant and what an IMU measures (rigcal.sim.imu_model)."""

    t: np.ndarray
    R_world_body: np.ndarray
    p_world: np.ndarray
    v_world: np.ndarray
    a_world: np.ndarray
    omega_body: np.ndarray
    alpha_body: np.ndarray

    @property
    def T_world_body(self) -> np.ndarray:
        """(N, 4, 4)."""
        T = np.zeros((len(self.t), 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = self.R_world_body, self.p_world, 1.0
        return T


def segment(spline: Spline, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(i (M,) int, u (M,)) of times t (M,); raises ValueError for a time outside the spline
    (NaN included: it would pass the range test and index garbage)."""
    t = np.asarray(t, dtype=float)
    s = (t - spline.t0) / spline.dt
    n_seg = len(spline.p) - ORDER + 1
    if not np.all(np.isfinite(s)) or np.any(s < -1e-9) or np.any(s > n_seg + 1e-9):
        raise ValueError(f"time outside the spline [{spline.t0}, {spline.t_end}]")
    i = np.clip(np.floor(s).astype(int), 0, n_seg - 1)
    return i, s - i


def basis(u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cumulative basis values, first and second time derivatives, each (M, 4)."""
    z, o = np.zeros_like(u), np.ones_like(u)
    b = np.stack([o, u, u * u, u**3], axis=1) @ _C.T
    db = np.stack([z, o, 2 * u, 3 * u * u], axis=1) @ _C.T / dt
    ddb = np.stack([z, z, 2 * o, 6 * u], axis=1) @ _C.T / dt**2
    return b, db, ddb


def evaluate(spline: Spline, t: np.ndarray) -> Motion:
    """The pose and its derivatives at times t (M,)."""
    i, u = segment(spline, t)
    idx = i[:, None] + np.arange(ORDER)  # (M, 4) control points of each time
    return motion_from_controls(np.asarray(t, dtype=float), u, spline.R[idx], spline.p[idx], spline.dt)


def motion_from_controls(t: np.ndarray, u: np.ndarray, Rc: np.ndarray, P: np.ndarray, dt: float) -> Motion:
    """The motion at times t (M,) at segment fractions u (M,) from each time's own four control
    rotations Rc (M, 4, 3, 3) and positions P (M, 4, 3): what residual Jacobians perturb
    (rigcal.imucal.residuals), one row at a time."""
    b, db, ddb = basis(u, dt)
    d = np.diff(P, axis=1)  # (M, 3, 3): p_{i+j} - p_{i+j-1}, j = 1..3
    p = P[:, 0] + np.einsum("mj,mjk->mk", b[:, 1:], d)
    v = np.einsum("mj,mjk->mk", db[:, 1:], d)
    a = np.einsum("mj,mjk->mk", ddb[:, 1:], d)
    R, omega, alpha = rotation_chain(Rc[:, 0], *segment_rotations(Rc, b), db, ddb)
    return Motion(t, R, p, v, a, omega, alpha)


def segment_rotations(Rc: np.ndarray, b: np.ndarray) -> tuple[list, list]:
    """([phi_j], [A_j]), j = 1..3: the relative rotations phi_j = Log(R_{j-1}^T R_j) between
    consecutive control rotations Rc (M, 4, 3, 3) and A_j = Exp(B~_j(u) phi_j) for the
    cumulative basis b (M, 4)."""
    phi = [geo.rotvecs_from_R(np.swapaxes(Rc[:, j - 1], 1, 2) @ Rc[:, j]) for j in range(1, ORDER)]
    return phi, [geo.R_from_rotvec(b[:, j, None] * phi[j - 1]) for j in range(1, ORDER)]


def rotation_chain(R0: np.ndarray, phi: list, A: list, db: np.ndarray, ddb: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R_world_body, omega_body, alpha_body) of the cumulative spline from the first control
    rotation R0 (M, 3, 3) and segment_rotations' phi_j, A_j."""
    R = R0.copy()
    omega = np.zeros((len(R0), 3))
    alpha = np.zeros((len(R0), 3))
    for j in range(1, ORDER):
        At = np.swapaxes(A[j - 1], 1, 2)
        w_rot = np.einsum("mij,mj->mi", At, omega)
        dphi = db[:, j, None] * phi[j - 1]
        alpha = np.einsum("mij,mj->mi", At, alpha) + ddb[:, j, None] * phi[j - 1] + np.cross(w_rot, dphi)
        omega = w_rot + dphi
        R = R @ A[j - 1]
    return R, omega, alpha


def knots_for(t_start: float, t_end: float, dt: float) -> tuple[float, int]:
    """(t0, N): the first knot and the number of control points of a spline with knots every
    dt that covers [t_start, t_end]."""
    n_seg = max(int(np.ceil((t_end - t_start) / dt - 1e-9)), 1)
    return t_start, n_seg + ORDER - 1


def _pose_rows(spline_n: int, i: np.ndarray) -> sp.csr_matrix:
    """Sparsity of residuals that each depend on control points i .. i+3 (3 rows, 3 columns
    per control point)."""
    rows = np.repeat(np.arange(3 * len(i)), 3 * ORDER)
    cols = (3 * (np.repeat(i, 3)[:, None] + np.arange(ORDER)[None, :]))[:, :, None] + np.arange(3)
    cols = cols.reshape(len(i) * 3, 3 * ORDER).ravel()
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * len(i), 3 * spline_n))


def fit(t: np.ndarray, R_world_body: np.ndarray, p_world: np.ndarray, dt: float) -> Spline:
    """The spline with knots every dt closest (least squares) to sampled poses: positions
    by one sparse linear solve, rotations by Gauss-Newton on Log(R_sample^T R(t)) from
    control rotations taken at the nearest samples. A start for the joint estimation,
    which then refines it; there must be samples in every segment."""
    t = np.asarray(t, dtype=float)
    t0, n = knots_for(t.min(), t.max(), dt)
    probe = Spline(t0, dt, np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.zeros((n, 3)))
    i, u = segment(probe, t)
    if len(np.unique(i)) < n - ORDER + 1:
        raise ValueError("fit: a spline segment has no sample; use a longer dt")
    b = basis(u, dt)[0]
    # position: p(t) = sum_k w_k p_{i+k} with w = cumulative differences of b
    w = b - np.concatenate([b[:, 1:], np.zeros((len(b), 1))], axis=1)
    W = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(len(t)), ORDER), (i[:, None] + np.arange(ORDER)).ravel())),
                      shape=(len(t), n))
    p = sp.linalg.spsolve((W.T @ W).tocsc(), W.T @ p_world)
    p = np.asarray(p).reshape(n, 3)
    # rotation: start from the sample nearest each control point's knot, then refine
    knot_t = t0 + (np.arange(n) - 1) * dt
    near = np.clip(np.searchsorted(t, knot_t), 0, len(t) - 1)
    R0 = R_world_body[near]

    def residual(x: np.ndarray) -> np.ndarray:
        Rc = geo.R_from_rotvec(x.reshape(n, 3)) @ R0
        Rt = evaluate(Spline(t0, dt, Rc, p), t).R_world_body
        return geo.rotvecs_from_R(np.swapaxes(R_world_body, 1, 2) @ Rt).ravel()

    sol = least_squares(residual, np.zeros(3 * n), jac_sparsity=_pose_rows(n, i), method="trf", x_scale=1.0,
                        xtol=1e-12, ftol=1e-12)
    return Spline(t0, dt, geo.R_from_rotvec(sol.x.reshape(n, 3)) @ R0, p)
