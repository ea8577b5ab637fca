"""Residual blocks of the camera-IMU calibration (docs/formats.md#motion-datasets).

Each block is a pure vectorised function of the estimation state returning a `Block`:
weighted residuals r (M, D), their Jacobian J (M, D, K) with respect to the K local
parameters each row touches, and the global column of each (M, K) in a `Layout`
(-1 for a parameter held fixed), so a sparse solver assembles them (`assemble`).

State and perturbations (all rotations perturbed on the left, R <- Exp(d) R):
- the body trajectory T_world_body(t): a rigcal.core.spline.Spline on the IMU clock;
- T_body_imu (the reference IMU; normally held: it defines the body frame);
- T_body_cam, time_offset_s and line_delay_s per camera (t_imu = t_cam + time_offset_s
  + row * line_delay_s);
- T_world_board per board: board 0 is held (it fixes the world frame, in which gravity's
  direction is estimated), every other board's pose is estimated (static boards);
- optionally every camera's intrinsics (rigcal.camcal.solve.Intrinsics: the parameters the
  camera-only calibration estimated, its focal tie and held principal point kept);
- gyroscope and accelerometer biases, piecewise linear between knots every bias_dt;
- gravity g_world = R_grav @ [0, 0, -|g|], two tangent degrees of freedom;
- the IMU model (`--imu-model`): each sensor reads M @ (its ideal reading) + bias with
  M = I + L, L lower-triangular (`scale-misalignment`: 3 scale factors on the diagonal,
  3 misalignments below it, per sensor; `calibrated`: M = I, the group held). A general
  small M - I is a lower-triangular matrix plus a small rotation; that rotation of the
  sensor axes is a rotation of the IMU frame, which every camera's rotation (and the
  trajectory) absorbs, so it is not estimated.

Jacobians: the spline's rotation, angular velocity and angular acceleration are
differentiated by forward differences over each row's own four control rotations,
vectorised over the rows (12 evaluations, each over all rows: motion_jacobian); everything
else is chained analytically, and the corner block differentiates the spline once per
distinct time. The spline derivatives with respect to control rotations have closed forms
(Sommer et al. 2020) but long ones; local differences of an exact evaluation are accurate
to ~1e-9 relative and cannot disagree with the residual they differentiate. Tests check
every block against differences of the whole problem (global state perturbed through
`retract`, spline re-evaluated).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.camcal.solve import project_obs, projection_jacobians
from rigcal.core.spline import (ORDER, Motion, Spline, basis, evaluate, motion_from_controls, rotation_chain, segment,
                                segment_rotations)

GRAVITY = 9.80665
STEP = 1e-6  # central-difference step (radians, metres, seconds, bias units)
MOTION_STEP = 1e-8  # motion_jacobian's forward-difference step (radians)
EPS_GRAM = 1e-12  # normal_rows: relative jitter on each group's Gram diagonal
CHUNK_CORNERS = 20_000  # reprojection_rows: corners per chunk (its arrays ~10 MB)
JOBS_THREADS = 2  # reprojection_rows: threads building the chunks (1: in turn)
# the 6 parameters of L in M = I + L, in this order: the scales (diagonal), then the
# misalignments below it ((1, 0), (2, 0), (2, 1))
SCALE_ROWS = np.array([0, 1, 2, 1, 2, 2])
SCALE_COLS = np.array([0, 1, 2, 0, 0, 1])


@dataclass(frozen=True, eq=False)
class State:
    """Everything the estimator moves. T_body_cam (C, 4, 4), time_offset_s and line_delay_s
    (C,), biases (K, 3) at knots bias_t0 + k * bias_dt, R_grav (3, 3), T_body_imu (4, 4),
    T_world_board (B, 4, 4) with board 0 held (it fixes the world frame)."""

    spline: Spline
    T_body_imu: np.ndarray
    T_body_cam: np.ndarray
    time_offset_s: np.ndarray
    line_delay_s: np.ndarray
    bias_t0: float
    bias_dt: float
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    R_grav: np.ndarray
    gravity: float = GRAVITY
    M_gyro: np.ndarray = field(default_factory=lambda: np.eye(3))  # gyro = M_gyro omega_imu + b_g
    M_accel: np.ndarray = field(default_factory=lambda: np.eye(3))  # accel = M_accel f_imu + b_a
    # (B, 4, 4); board 0 is held (it fixes the world frame), the others are estimated
    T_world_board: np.ndarray = field(default_factory=lambda: np.eye(4)[None])
    # per camera rigcal.camcal.solve.Intrinsics, when the estimate may move them (empty: the
    # reprojection block's `cameras` are the intrinsics, held)
    intrinsics: tuple = ()

    @property
    def g_world(self) -> np.ndarray:
        return self.R_grav @ np.array([0.0, 0.0, -self.gravity])


@dataclass(frozen=True)
class Layout:
    """Column offsets of each parameter group in the global vector; `held` names groups
    kept fixed (their columns are -1): any of 'imu_rot', 'imu_pos', 'cam', 'offset',
    'line_delay' (held by default: estimated only for a declared rolling shutter), 'scale'
    (the 12 parameters of M_gyro and M_accel; held by default: the `calibrated` model).
    `bias_knot0` and `knots_per_bias`: where the bias knots fall among the spline's control
    points (bias knot j at control bias_knot0 + j knots_per_bias; 0: not known), for the
    solver's column order (imu_calib.band_order). `n_board`: the boards whose pose is
    estimated (every board but board 0, which fixes the world; 'board' in `held` holds them all).
    `n_intr`: per camera the number of its intrinsic parameters in the state (empty: no
    intrinsics in the state); the group 'intrinsics'."""

    n_ctrl: int
    n_cam: int
    n_bias: int
    held: frozenset = frozenset({"imu_rot", "imu_pos", "line_delay", "scale"})
    bias_knot0: float = 0.0
    knots_per_bias: float = 0.0
    n_board: int = 0
    n_intr: tuple = ()

    @property
    def rot(self) -> int:
        return 0

    @property
    def pos(self) -> int:
        return 3 * self.n_ctrl

    @property
    def cam(self) -> int:
        return 6 * self.n_ctrl

    @property
    def offset(self) -> int:
        return self.cam + 6 * self.n_cam

    @property
    def bg(self) -> int:
        return self.offset + self.n_cam

    @property
    def ba(self) -> int:
        return self.bg + 3 * self.n_bias

    @property
    def grav(self) -> int:
        return self.ba + 3 * self.n_bias

    @property
    def imu(self) -> int:
        return self.grav + 2

    @property
    def line_delay(self) -> int:
        return self.imu + 6

    @property
    def scale(self) -> int:
        """12 columns: L of M_gyro (6, SCALE_ROWS / SCALE_COLS order), then of M_accel."""
        return self.line_delay + self.n_cam

    @property
    def board(self) -> int:
        """6 columns (rotation, position) per board 1 .. n_board: board b at board + 6 (b - 1)."""
        return self.scale + 12

    @property
    def intr(self) -> int:
        """Each camera's intrinsic parameters in turn (n_intr[c] columns for camera c)."""
        return self.board + 6 * self.n_board

    def intr_start(self, c: int) -> int:
        return self.intr + int(sum(self.n_intr[:c]))

    @property
    def size(self) -> int:
        return self.intr + int(sum(self.n_intr))

    def group(self, name: str, start: np.ndarray | int, width: int) -> np.ndarray:
        """Columns start .. start + width - 1 (start (M,) or scalar), or -1 when `name` is held."""
        cols = np.asarray(start)[..., None] + np.arange(width)
        return np.full_like(cols, -1) if name in self.held else cols


def layout_for(state: State, held: frozenset = frozenset({"imu_rot", "imu_pos", "line_delay", "scale"})) -> Layout:
    sp_ = state.spline
    return Layout(len(sp_.p), len(state.T_body_cam), len(state.gyro_bias), held,
                  (state.bias_t0 - sp_.t0) / sp_.dt, state.bias_dt / sp_.dt, len(state.T_world_board) - 1,
                  tuple(i.basis().shape[1] for i in state.intrinsics))


@dataclass(frozen=True, eq=False)
class Block:
    """r (M, D) weighted residuals, J (M, D, K), cols (M, K) global columns (-1: held);
    cost: the block's share of the objective when it is not sum r^2 (a robust loss: r and J
    are then the iteratively reweighted ones, whose gradient J^T r is half the cost's);
    group (M,): rows with the same group share their columns (normal_rows may merge them);
    rms: the RMS of the residuals before such a merge (residual_rms)."""

    r: np.ndarray
    J: np.ndarray
    cols: np.ndarray
    cost: float | None = None
    group: np.ndarray | None = None
    rms: float | None = None  # of the residuals r stood for before normal_rows merged them

    @property
    def objective(self) -> float:
        return float(np.sum(self.r ** 2)) if self.cost is None else self.cost

    @property
    def residual_rms(self) -> float:
        """RMS of the block's residuals (of each coordinate, as weighted)."""
        return float(np.sqrt(np.mean(self.r ** 2))) if self.rms is None else self.rms


def huber(block: Block, k: float) -> Block:
    """The block under a Huber loss on each row's residual norm s (in sigma units): cost
    s^2 up to k, 2 k s - k^2 beyond; rows beyond k weighted by sqrt(k / s) (IRLS)."""
    s = np.linalg.norm(block.r.reshape(len(block.r), -1), axis=1)
    far = s > k
    w = np.ones_like(s)
    w[far] = np.sqrt(k / s[far])
    cost = float(np.sum(np.where(far, 2 * k * s - k * k, s * s)))
    return Block(block.r * w[:, None], block.J * w[:, None, None], block.cols, cost, block.group)


def tangent_basis(R_grav: np.ndarray) -> np.ndarray:
    """(3, 2): the two world directions orthogonal to gravity that its 2 dof turn about."""
    return R_grav[:, :2]


def scale_jacobian(x: np.ndarray) -> np.ndarray:
    """d (M x) / d L for M = I + L, L's 6 parameters in SCALE_ROWS / SCALE_COLS order:
    (M, 3, 6) from the ideal readings x (M, 3). Linear, so exact."""
    J = np.zeros((len(x), 3, 6))
    J[:, SCALE_ROWS, np.arange(6)] = x[:, SCALE_COLS]
    return J


def lower(params: np.ndarray) -> np.ndarray:
    """L (3, 3) from its 6 parameters (SCALE_ROWS / SCALE_COLS order)."""
    L = np.zeros((3, 3))
    L[SCALE_ROWS, SCALE_COLS] = params
    return L


def _controls(spline: Spline, t: np.ndarray):
    i, u = segment(spline, t)
    idx = i[:, None] + np.arange(ORDER)
    return i, u, spline.R[idx], spline.p[idx]


def _turn(R: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exp(d) @ R, d (..., 3)."""
    return geo.R_from_rotvec(d) @ R


def _bias_at(state: State, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(knot j (M,), fraction s (M,)) of the linear bias interpolation at times t."""
    x = (t - state.bias_t0) / state.bias_dt
    j = np.clip(np.floor(x).astype(int), 0, len(state.gyro_bias) - 2)
    return j, x - j


def bias_values(state: State, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gyro bias (M, 3), accel bias (M, 3)) at times t."""
    j, s = _bias_at(state, t)
    lerp = lambda b: (1 - s)[:, None] * b[j] + s[:, None] * b[j + 1]  # noqa: E731
    return lerp(state.gyro_bias), lerp(state.accel_bias)


def _spline_cols(lay: Layout, i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ctrl = (i[:, None] + np.arange(ORDER))  # (M, 4)
    rot = (lay.rot + 3 * ctrl[:, :, None] + np.arange(3)).reshape(len(i), -1)
    pos = (lay.pos + 3 * ctrl[:, :, None] + np.arange(3)).reshape(len(i), -1)
    return rot, pos


@dataclass(frozen=True, eq=False)
class MotionJacobian:
    """The motion at times t and its derivatives with respect to each time's local controls:
    J_rot (M, 9, 12) of [theta; omega_body; alpha_body] (theta: the world-side rotation
    perturbation of R_world_body) by the 12 control-rotation perturbations (a local forward
    difference: 24 evaluations over all rows, each redoing only the one or two segment
    rotations the perturbed control enters), and the exact weights (M, 4) of
    the control positions in p_world (w_p) and a_world (w_a)."""

    motion: Motion
    i: np.ndarray
    J_rot: np.ndarray
    w_p: np.ndarray
    w_a: np.ndarray


def _position_weights(b: np.ndarray) -> np.ndarray:
    """Cumulative basis (M, 4) -> weight of each control position (M, 4) (sum_k w_k P_k)."""
    return b - np.concatenate([b[:, 1:], np.zeros((len(b), 1))], axis=1)


def motion_jacobian(state: State, t: np.ndarray) -> MotionJacobian:
    i, u, Rc, P = _controls(state.spline, t)
    dt = state.spline.dt
    m0 = motion_from_controls(t, u, Rc, P, dt)
    b, db, ddb = basis(u, dt)
    # forward differences, one control rotation and axis at a time (MOTION_STEP: truncation
    # and rounding both ~1e-8 relative; central ones took twice the evaluations for accuracy
    # no step of the estimate can use); a control enters only the one or two segment
    # rotations next to it, so the others are reused unperturbed (the same numbers as
    # perturbing every control by zero)
    phi, A = segment_rotations(Rc, b)
    R0t = np.swapaxes(m0.R_world_body, 1, 2)
    base = np.concatenate([np.zeros((len(t), 3)), m0.omega_body, m0.alpha_body], axis=1)
    J = np.empty((len(t), 9, 3 * ORDER))
    for c in range(ORDER):
        near = [j for j in (c, c + 1) if 1 <= j < ORDER]
        for axis in range(3):
            d = np.zeros(3)
            d[axis] = MOTION_STEP
            Rc_c = geo.R_from_rotvec(d) @ Rc[:, c]
            ph, AA = list(phi), list(A)
            for j in near:
                lo = Rc_c if j - 1 == c else Rc[:, j - 1]
                hi = Rc_c if j == c else Rc[:, j]
                ph[j - 1] = geo.rotvecs_from_R(np.swapaxes(lo, 1, 2) @ hi)
                AA[j - 1] = geo.R_from_rotvec(b[:, j, None] * ph[j - 1])
            R, omega, alpha = rotation_chain(Rc_c if c == 0 else Rc[:, 0], ph, AA, db, ddb)
            out = np.concatenate([geo.rotvecs_from_R(R @ R0t), omega, alpha], axis=1)
            J[:, :, 3 * c + axis] = (out - base) / MOTION_STEP
    return MotionJacobian(m0, i, J, _position_weights(b), _position_weights(ddb))


def _per_control(M: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(M, 3, 3) matrices times each control's weight (M, 4) -> (M, 3, 12)."""
    return np.einsum("mij,mk->mikj", M, w).reshape(len(w), 3, 12)


def gyro_block(state: State, lay: Layout, t: np.ndarray, gyro: np.ndarray, sigma: float,
               mj: MotionJacobian | None = None) -> Block:
    """(M_gyro R_body_imu^T omega_body(t) + b_g(t) - gyro) / sigma; local parameters: 4
    control rotations (12), R_body_imu (3), two gyro bias knots (6), L of M_gyro (6).
    `mj`: motion_jacobian(state, t) when the caller has it (the accelerometer block shares it)."""
    mj = mj or motion_jacobian(state, t)
    j, s = _bias_at(state, t)
    Rt_bi = state.T_body_imu[:3, :3].T
    M = state.M_gyro
    w = mj.motion.omega_body
    w_imu = w @ Rt_bi.T  # the ideal reading, IMU axes
    b = (1 - s)[:, None] * state.gyro_bias[j] + s[:, None] * state.gyro_bias[j + 1]
    eye = np.broadcast_to(np.eye(3), (len(t), 3, 3))
    MR = M @ Rt_bi
    J = np.concatenate([MR @ mj.J_rot[:, 3:6], MR @ geo.skew(w), (1 - s)[:, None, None] * eye,
                        s[:, None, None] * eye, scale_jacobian(w_imu)], axis=2) / sigma
    rot, _ = _spline_cols(lay, mj.i)
    n = np.full(len(t), 0)
    cols = np.concatenate([rot, lay.group("imu_rot", n + lay.imu, 3),
                           lay.group("bg", lay.bg + 3 * j, 6), lay.group("scale", n + lay.scale, 6)], axis=1)
    return Block((w_imu @ M.T + b - gyro) / sigma, J, cols)


def specific_force(m, R_body_imu: np.ndarray, t_body_imu: np.ndarray, g_world: np.ndarray) -> np.ndarray:
    """What an ideal accelerometer at (R_body_imu, t_body_imu) reads (M, 3), row-wise
    parameters allowed ((M, 3, 3), (M, 3), (M, 3)); the model of rigcal.sim.imu_model.ideal_readings."""
    w, al, r = m.omega_body, m.alpha_body, t_body_imu
    lever = np.cross(al, r) + np.cross(w, np.cross(w, r))
    f_body = np.einsum("mji,mj->mi", m.R_world_body, m.a_world - g_world) + lever
    return np.einsum("...ji,...j->...i", R_body_imu, f_body)


def accel_block(state: State, lay: Layout, t: np.ndarray, accel: np.ndarray, sigma: float,
                mj: MotionJacobian | None = None) -> Block:
    """(M_accel specific force(t) + b_a(t) - accel) / sigma; local parameters: 4 control
    rotations (12) and positions (12), R_body_imu (3), t_body_imu (3), two accel bias knots
    (6), gravity's direction (2), L of M_accel (6). Chain rule on
    f_body = R^T (a - g) + alpha x r + omega x (omega x r)."""
    mj = mj or motion_jacobian(state, t)
    m = mj.motion
    j, s = _bias_at(state, t)
    Rt_bi, r_lever = state.T_body_imu[:3, :3].T, state.T_body_imu[:3, 3]
    M = state.M_accel
    MR = M @ Rt_bi
    g0 = state.g_world
    w, al = m.omega_body, m.alpha_body
    Rt = np.swapaxes(m.R_world_body, 1, 2)
    f_body = np.einsum("mij,mj->mi", Rt, m.a_world - g0) + np.cross(al, r_lever) + np.cross(w, np.cross(w, r_lever))
    K_r, K_w = geo.skew(r_lever), geo.skew(w)
    d_theta = Rt @ geo.skew(m.a_world - g0)
    d_omega = -K_w @ K_r - geo.skew(np.cross(w, r_lever))
    d_rot = d_theta @ mj.J_rot[:, :3] - K_r @ mj.J_rot[:, 6:9] + d_omega @ mj.J_rot[:, 3:6]
    eye = np.broadcast_to(np.eye(3), (len(t), 3, 3))
    f_imu = f_body @ Rt_bi.T  # the ideal reading, IMU axes
    J = np.concatenate([MR @ d_rot, MR @ _per_control(Rt, mj.w_a), MR @ geo.skew(f_body),
                        MR @ (geo.skew(al) + K_w @ K_w), (1 - s)[:, None, None] * eye, s[:, None, None] * eye,
                        MR @ Rt @ (geo.skew(g0) @ tangent_basis(state.R_grav)), scale_jacobian(f_imu)], axis=2) / sigma
    b = (1 - s)[:, None] * state.accel_bias[j] + s[:, None] * state.accel_bias[j + 1]
    rot, pos = _spline_cols(lay, mj.i)
    n = np.full(len(t), 0)
    cols = np.concatenate([rot, pos, lay.group("imu_rot", n + lay.imu, 3), lay.group("imu_pos", n + lay.imu + 3, 3),
                           lay.group("ba", lay.ba + 3 * j, 6), lay.group("grav", n + lay.grav, 2),
                           lay.group("scale", n + lay.scale + 6, 6)], axis=1)
    return Block((f_imu @ M.T + b - accel) / sigma, J, cols)


@dataclass(frozen=True, eq=False)
class Corners:
    """Corner observations: cam (M,) int, t_cam (M,) seconds on that camera's clock (the
    image's first-row mid-exposure), uv (M, 2) pixels, p_board (M, 3) the corner's point in
    its board's frame, board (M,) int indexing State.T_world_board (static boards; None:
    p_board are world points, as with one board at the identity)."""

    cam: np.ndarray
    t_cam: np.ndarray
    uv: np.ndarray
    p_board: np.ndarray
    board: np.ndarray | None = None

    def boards(self) -> np.ndarray:
        return np.zeros(len(self.cam), int) if self.board is None else self.board

    def subset(self, keep: np.ndarray) -> "Corners":
        return Corners(self.cam[keep], self.t_cam[keep], self.uv[keep], self.p_board[keep],
                       None if self.board is None else self.board[keep])


def world_points(state: State, obs: Corners) -> np.ndarray:
    """(M, 3) each corner's point in the world (its board placed by state.T_world_board)."""
    if obs.board is None:  # world points
        return obs.p_board
    T = state.T_world_board[obs.board]
    return np.einsum("mij,mj->mi", T[:, :3, :3], obs.p_board) + T[:, :3, 3]


def corner_times(state: State, obs: Corners) -> np.ndarray:
    """IMU-clock time of each corner's row: t_cam + time_offset_s + v * line_delay_s."""
    return obs.t_cam + state.time_offset_s[obs.cam] + obs.uv[:, 1] * state.line_delay_s[obs.cam]


def pose_jacobian(state: State, t: np.ndarray) -> tuple[Motion, np.ndarray, np.ndarray]:
    """(motion at t (M,), segment index i (M,), d [theta; p] / d local controls (M, 6, 24)):
    theta the world-side rotation perturbation of R_world_body (Exp(theta) R), p the body
    position; local controls as in the blocks (12 rotations, then 12 positions)."""
    mj = motion_jacobian(state, t)
    J = np.zeros((len(t), 6, 24))
    J[:, :3, :12] = mj.J_rot[:, :3]
    J[:, 3:, 12:] = _per_control(np.broadcast_to(np.eye(3), (len(t), 3, 3)), mj.w_p)
    return mj.motion, mj.i, J


def reprojection_block(state: State, lay: Layout, obs: Corners, cameras: list[CameraModel], sigma_px: float
                       ) -> Block:
    """(project(T_body_cam^-1 T_world_body(t)^-1 T_world_board p_board) - uv) / sigma_px at
    the corner's IMU-clock time; local parameters: 4 control rotations (12) and positions
    (12), the camera's rotation (3) and position (3) in the body, its time offset (1) and
    line delay (1), its board's rotation (3) and position (3) (held for board 0). The row time uses the measured row (v), as Kalibr and basalt do for rolling shutters.

    The spline is differentiated once per distinct time (an image's corners share it under
    a global shutter), the rest by the chain rule; d/d(offset) is the image motion from the
    spline's velocity and angular velocity."""
    cp = _corner_parts(state, lay, obs, cameras, sigma_px)
    mj, inv = cp.mj, cp.inv
    # the controls' columns by their structure (12 rotation columns through the spline's
    # rotation Jacobian, 12 position columns as the controls' weights times d r / d p_world)
    # rather than one (M, 2, 6) x (M, 6, 24) product that is half zeros: 2.2 -> 1.2 s on EuRoC
    d_rot = cp.d_theta @ mj.J_rot[inv, :3]
    d_pos = np.einsum("mij,mk->mikj", cp.d_p, mj.w_p[inv]).reshape(len(inv), 2, 12)
    seg = mj.i[inv]  # each corner's spline segment
    rot, pos = _spline_cols(lay, seg)
    c, b = obs.cam, obs.boards()
    # an image's corners of one board (one camera, one spline segment) share all their columns
    group = np.unique((seg * len(state.T_body_cam) + c) * len(state.T_world_board) + b, return_inverse=True)[1]
    return Block(cp.r, np.concatenate([d_rot, d_pos, cp.J_rest], axis=2),
                 np.concatenate([rot, pos, cp.cols_rest], axis=1), group=group)


@dataclass(frozen=True, eq=False)
class _CornerParts:
    """The corner block before the spline's controls enter: residuals r (M, 2), d r / d theta
    and d r / d p_world of the body pose at the corner's time (M, 2, 3 each), the other local
    columns (M, 2, K) and their indices (M, K) (camera, offset, line delay, board, intrinsics),
    the motion Jacobian at the distinct times and each corner's time index `inv`."""

    r: np.ndarray
    d_theta: np.ndarray
    d_p: np.ndarray
    J_rest: np.ndarray
    cols_rest: np.ndarray
    mj: MotionJacobian
    inv: np.ndarray


def _corner_parts(state: State, lay: Layout, obs: Corners, cameras: list[CameraModel], sigma_px: float
                  ) -> _CornerParts:
    t_u, inv = np.unique(corner_times(state, obs), return_inverse=True)
    mj = motion_jacobian(state, t_u)
    m_u = mj.motion
    R, p_world, dw, q, p_cam, uv, vals, kinds = _projected(state, obs, cameras, m_u, inv)
    c = obs.cam
    R_bc = state.T_body_cam[c, :3, :3]
    J_uv, J_intr = projection_jacobians(p_cam, c, vals, kinds)  # (M, 2, 3), per camera (M_c, 2, n_values)
    Rt = np.swapaxes(R, 1, 2)
    Rt_skew_dw = Rt @ geo.skew(dw)  # d p_body / d theta (world-side rotation of R_world_body)
    A = J_uv @ np.swapaxes(R_bc, 1, 2) / sigma_px  # d r / d p_body (M, 2, 3)
    omega_world = np.einsum("mij,mj->mi", R, m_u.omega_body[inv])
    d_body_dt = np.einsum("mij,mj->mi", Rt_skew_dw, omega_world) - np.einsum("mji,mj->mi", R, m_u.v_world[inv])
    d_dt = A @ d_body_dt[..., None]
    A_Rt = A @ Rt
    parts = [(J_uv @ (np.swapaxes(R_bc, 1, 2) @ geo.skew(q))) / sigma_px, -A, d_dt, d_dt * obs.uv[:, 1, None, None]]
    cols = [lay.group("cam", lay.cam + 6 * c, 6), lay.group("offset", lay.offset + c, 1),
            lay.group("line_delay", lay.line_delay + c, 1)]
    b = obs.boards()
    if lay.n_board:
        # the board turned about its own origin (R <- Exp(d) R, as the cameras) and moved:
        # p_world changes by -skew(R_world_board p_board) d_rot + d_pos, r by A R^T times that
        R_wb_p = p_world - state.T_world_board[b, :3, 3]
        parts.append(np.concatenate([-(A_Rt @ geo.skew(R_wb_p)), A_Rt], axis=2))
        free = np.where(b > 0, lay.board + 6 * (b - 1), -1)
        cols.append(np.where(free[:, None] >= 0, lay.group("board", free, 6), -1))
    if lay.n_intr and "intrinsics" not in lay.held:
        parts_i, cols_i = intrinsic_columns(state, lay, c, J_intr, sigma_px)
        parts.append(parts_i)
        cols.append(cols_i)
    return _CornerParts((uv - obs.uv) / sigma_px, A @ Rt_skew_dw, -A_Rt, np.concatenate(parts, axis=2),
                        np.concatenate(cols, axis=1), mj, inv)


def _projected(state: State, obs: Corners, cameras: list[CameraModel], m_u: Motion, inv: np.ndarray) -> tuple:
    """The corners through the rig at their times (m_u: the motion at the unique times, inv:
    each corner's): (R_world_body, p_world, p_world - p_body_origin, p_body - t_body_cam,
    p_cam, uv, per camera the projection values and kinds)."""
    R, p = m_u.R_world_body[inv], m_u.p_world[inv]
    c = obs.cam
    R_bc, t_bc = state.T_body_cam[c, :3, :3], state.T_body_cam[c, :3, 3]
    p_world = world_points(state, obs)
    dw = p_world - p
    q = np.einsum("mji,mj->mi", R, dw) - t_bc
    p_cam = np.einsum("mji,mj->mi", R_bc, q)
    if state.intrinsics:
        vals, kinds = [i.values for i in state.intrinsics], [i.model for i in state.intrinsics]
    else:
        vals, kinds = [np.array([k.fx, k.fy, k.cx, k.cy, *k.dist]) for k in cameras], [k.model for k in cameras]
    # the lens polynomial as the camera BA evaluates it, also past the radius where it folds
    # back (CameraModel.project gives NaN there): a start or a trial step may put a corner
    # there, and a NaN cost made LM refuse every step (EuRoC: the start returned as result)
    return R, p_world, dw, q, p_cam, project_obs(p_cam, c, vals, kinds), vals, kinds


def corner_errors(state: State, obs: Corners, cameras: list[CameraModel]) -> np.ndarray:
    """(M, 2) each corner's projection at its IMU-clock time minus its measurement, pixels
    (the corner block's residuals unweighted), without the block's Jacobians."""
    t_u, inv = np.unique(corner_times(state, obs), return_inverse=True)
    return _projected(state, obs, cameras, evaluate(state.spline, t_u), inv)[5] - obs.uv


def _image_rows(state: State, lay: Layout, obs: Corners, cameras: list[CameraModel], sigma_px: float,
                huber_k: float | None) -> Block:
    """The corner rows of one chunk as reprojection_rows gives them, for corners that share
    their time per image (no line delay): each image's corners of one board (one time, one
    camera) merged in the pose's 6 columns (theta, p_world) and the other live columns, then
    the pose's rows carried to the 24 control columns through the motion Jacobian at that
    time. The same normal equations as merging the 24 control columns per corner: the pose
    Jacobian is one matrix per time, so J = J_pose E and J^T J = E^T (J_pose^T J_pose) E.
    EuRoC's held-intrinsics rows: 13 a view instead of 32."""
    cp = _corner_parts(state, lay, obs, cameras, sigma_px)
    live = _live_rest(lay, cp.cols_rest.shape[1])  # held groups' columns drop out (the same in every chunk)
    J = np.concatenate([cp.d_theta, cp.d_p, cp.J_rest[:, :, live]], axis=2)
    c, b = obs.cam, obs.boards()
    group = np.unique((cp.inv * len(state.T_body_cam) + c) * len(state.T_world_board) + b, return_inverse=True)[1]
    # the time index rides in the pose columns' indices through the merge (not columns yet)
    pose_cols = np.broadcast_to(cp.inv[:, None], (len(c), 6))
    blk = Block(cp.r, J, np.concatenate([pose_cols, cp.cols_rest[:, live]], axis=1), group=group)
    blk = blk if huber_k is None else huber(blk, huber_k)
    m = _merge_groups(blk, always=True)
    ti = m.cols[:, 0]  # each merged view's time index
    mj = cp.mj
    n = len(ti)
    d_rot = m.J[:, :, :3] @ mj.J_rot[ti, :3]
    d_pos = np.einsum("gij,gk->gikj", m.J[:, :, 3:6], mj.w_p[ti]).reshape(n, m.J.shape[1], 12)
    rot, pos = _spline_cols(lay, mj.i[ti])
    return Block(m.r, np.concatenate([d_rot, d_pos, m.J[:, :, 6:]], axis=2),
                 np.concatenate([rot, pos, m.cols[:, 6:]], axis=1), blk.objective, rms=m.rms)


def _live_rest(lay: Layout, k: int) -> np.ndarray:
    """The indices of _corner_parts' other columns (camera 6, offset 1, line delay 1, then
    board 6 and intrinsics when present; k in all) whose groups the layout estimates."""
    held = [("cam", 6), ("offset", 1), ("line_delay", 1)] + ([("board", 6)] if lay.n_board else [])
    mask = np.concatenate([np.full(w, name not in lay.held) for name, w in held])
    return np.flatnonzero(np.r_[mask, np.ones(k - len(mask), bool)])


def reprojection_rows(state: State, lay: Layout, obs: Corners, cameras: list[CameraModel], sigma_px: float,
                      huber_k: float | None = None) -> Block:
    """The corner block as normal_rows turns it into (the Huber loss first when huber_k is
    given), built CHUNK_CORNERS corners at a time in time order: the same normal equations,
    objective and residual RMS. Whole, EuRoC's block is 350,000 x 2 x 41 values (230 MB) and
    as many temporaries, each fresh memory whose page faults took more time than the
    arithmetic (1.1 of its 2.1 s); a chunk's arrays are reused from the heap. Without line
    delays (held, all zero) an image's corners share one time and merge in the pose's 6
    columns (_image_rows); the chunks run on JOBS_THREADS threads (numpy's heavy parts release
    the GIL), as many of equal size as makes each at most CHUNK_CORNERS and their number a
    multiple of the threads (the 30 s three-camera recording's 62,000 corners: 4 x 15,500, two
    at a time, not 3 x 20,000 + 2,000, whose last round ran one 20,000 alone)."""
    order = np.argsort(corner_times(state, obs), kind="stable")  # a time's corners in one chunk
    shared_time = "line_delay" in lay.held and not np.any(state.line_delay_s)
    n_chunks = -(-len(order) // CHUNK_CORNERS)
    if JOBS_THREADS > 1 and n_chunks > 1:
        n_chunks = -(-n_chunks // JOBS_THREADS) * JOBS_THREADS
    bounds = np.linspace(0, len(order), max(n_chunks, 1) + 1).round().astype(int)

    def chunk(span):
        sub = obs.subset(order[span[0]:span[1]])
        if shared_time:
            m = _image_rows(state, lay, sub, cameras, sigma_px, huber_k)
            return m, m.objective, m.rms ** 2 * 2 * len(sub.cam)
        b = reprojection_block(state, lay, sub, cameras, sigma_px)
        b = b if huber_k is None else huber(b, huber_k)
        # K rows a group, so the chunks stack
        return _merge_groups(b, always=True), b.objective, float(np.sum(b.r ** 2))

    spans = [(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:]) if hi > lo]
    if JOBS_THREADS > 1 and len(spans) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=JOBS_THREADS) as ex:
            done = list(ex.map(chunk, spans))
    else:
        done = [chunk(span) for span in spans]
    pieces = [d[0] for d in done]
    cost = sum(d[1] for d in done)
    sq = sum(d[2] for d in done)
    n_res = 2 * len(order)
    if not pieces:
        return Block(np.zeros((0, 2)), np.zeros((0, 2, 0)), np.zeros((0, 0), int), 0.0, rms=0.0)
    return Block(np.concatenate([p.r for p in pieces]), np.concatenate([p.J for p in pieces]),
                 np.concatenate([p.cols for p in pieces]), cost, rms=float(np.sqrt(sq / n_res)))


def intrinsic_columns(state: State, lay: Layout, cam: np.ndarray, J_values: list, sigma_px: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The corners' columns (M, 2, K) and their indices (M, K) for their camera's intrinsic
    parameters (K: the most any camera has; a camera with fewer pads with held columns):
    d uv / d values (projection_jacobians) through each camera's parameter basis."""
    k_max = max(lay.n_intr)
    J = np.zeros((len(cam), 2, k_max))
    cols = np.full((len(cam), k_max), -1)
    for c, intr in enumerate(state.intrinsics):
        m = cam == c
        E = intr.basis()
        J[m, :, :E.shape[1]] = J_values[c] @ E / sigma_px
        cols[m, :E.shape[1]] = lay.intr_start(c) + np.arange(E.shape[1])
    return J, cols


def normal_rows(blocks: list[Block]) -> list[Block]:
    """The blocks with each group's rows replaced by at most K rows with the same normal
    equations (J^T J and J^T r to ~1e-12 relative; the objective kept): R and Q^T r of a QR
    of the group's [J | r], computed as the Cholesky factor of its Gram matrix. What the
    solver and the covariance need, at a fraction of the entries: EuRoC's corner block
    (351,000 corners in 2,828 images) 21.8 -> 2.8 million, its J^T J 0.8 -> 0.1 s."""
    return [b if b.group is None or len(b.r) == 0 else _merge_groups(b) for b in blocks]


def _merge_groups(b: Block, always: bool = False) -> Block:
    """b with each group's rows replaced by K rows (normal_rows); unchanged when no group has
    more than K residuals (nothing to gain), unless `always`."""
    m, d, k = b.J.shape
    order = np.argsort(b.group, kind="stable")
    g = b.group[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    counts = np.diff(np.r_[starts, m])
    if counts.max() * d <= k and not always:
        return b
    slot = np.arange(m) - np.repeat(starts, counts)
    which = np.repeat(np.arange(len(starts)), counts)
    A = np.zeros((len(starts), counts.max(), d, k + 1))
    A[which, slot, :, :k] = b.J[order]
    A[which, slot, :, k] = b.r[order]
    # zero rows (groups with fewer rows) change neither the Gram matrix nor its factor
    X = A.reshape(len(starts), -1, k + 1)
    # [J | r]^T [J | r] per group, the transpose made contiguous first: numpy's batched
    # matmul of the strided view fell off its BLAS path at some widths (EuRoC, intrinsics
    # estimated, 42 columns: 0.50 s a chunk, contiguous 0.005 s; 520 of the 720 s its
    # solves took without a camera calibration)
    G = np.ascontiguousarray(np.swapaxes(X, 1, 2)) @ X
    # its Cholesky factor R (R^T R = G) is what a QR of [J | r] gives up to row signs, by a
    # batched product instead of a batched QR: with the 9 intrinsic columns of a radtan5
    # camera (K 32 -> 41) the QR took 1.3 s an iteration on EuRoC, this ~0.3 s. Its
    # precision is that of J^T J, which the solver forms anyway. Factored with unit diagonal
    # (the columns' scales differ by 1e8) and EPS_GRAM added to it: a group with fewer
    # independent rows than columns has a singular G, and J^T J moves by EPS_GRAM relative
    diag = np.einsum("gii->gi", G)
    scale = np.sqrt(np.where(diag > 0, diag, 1.0))
    Gs = G / scale[:, :, None] / scale[:, None, :]
    Gs[:, np.arange(k + 1), np.arange(k + 1)] += EPS_GRAM
    R = np.swapaxes(np.linalg.cholesky(Gs), 1, 2) * scale[:, None, :]
    # all K rows: unlike a QR's, a Cholesky factor of a rank-deficient G (one image's corners
    # move through a few pose and lens degrees of freedom) may carry weight in every row
    return Block(R[:, :k, k], R[:, :k, :k], b.cols[order][starts], b.objective, rms=b.residual_rms)



def bias_prior_block(state: State, lay: Layout, gyro_random_walk: float, accel_random_walk: float) -> Block:
    """(b_{k+1} - b_k) / (random_walk * sqrt(bias_dt)) for both biases: a random walk of the
    declared density (Kalibr units, per sqrt(s)) over one knot interval. Linear: exact J."""
    k = len(state.gyro_bias) - 1
    sig = np.array([gyro_random_walk, accel_random_walk]) * np.sqrt(state.bias_dt)
    db = np.concatenate([np.diff(state.gyro_bias, axis=0) / sig[0], np.diff(state.accel_bias, axis=0) / sig[1]])
    J = np.zeros((2 * k, 3, 6))
    J[:, :, :3] = -np.eye(3)
    J[:, :, 3:] = np.eye(3)
    J /= np.repeat(sig, k)[:, None, None]
    start = np.concatenate([lay.bg + 3 * np.arange(k), lay.ba + 3 * np.arange(k)])
    return Block(db, J, start[:, None] + np.arange(6))


def intrinsics_prior_block(state: State, lay: Layout, prior: tuple) -> Block:
    """(values - prior) / sigma of each camera's fx, fy, cx, cy: an earlier camera
    calibration as a prior (`prior`: per camera (values (4,), sigma (4,)) or None for none).
    The four must be parameters of their own (Intrinsics with tie_focal and hold_centre
    False: basis columns 0-3). Linear: exact J."""
    rows, Js, cols = [], [], []
    for c, (intr, pr) in enumerate(zip(state.intrinsics, prior)):
        if pr is None:
            continue
        v0, sig = (np.asarray(x, float) for x in pr)
        rows.append((intr.values[:4] - v0) / sig)
        Js.append(np.diag(1.0 / sig))
        cols.append(lay.group("intrinsics", lay.intr_start(c), 4))
    if not rows:
        return Block(np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros((0, 4), int))
    return Block(np.stack(rows), np.stack(Js), np.stack(cols))


def assemble(blocks: list[Block], n_cols: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """The sparse Jacobian (rows: every residual of every block in order) and residual vector.
    Built as CSR directly (rows come in order, each with its block's columns): going through
    COO made EuRoC's 23 million entries cost 2 s per iteration in the row sort alone. Each
    block is written into arrays allocated once: on EuRoC the per-block pieces and their
    concatenation were ~1 GB of fresh memory an iteration, most of its time page faults."""
    held = [b.cols < 0 for b in blocks]
    # whole local columns held (a held group): sliced out; anything else masked entry by entry
    whole = [len(h) == 0 or bool((h == h[0]).all()) for h in held]
    row_nnz = [np.full(b.J.shape[0] * b.J.shape[1], int((~h[0]).sum()) if len(h) else 0) if w
               else np.repeat((~h).sum(axis=1), b.J.shape[1]) for b, h, w in zip(blocks, held, whole)]
    counts = np.concatenate(row_nnz)
    indptr = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    index_type = np.int32 if indptr[-1] < np.iinfo(np.int32).max and n_cols < np.iinfo(np.int32).max else np.int64
    data, indices = np.empty(indptr[-1]), np.empty(indptr[-1], dtype=index_type)
    at = 0
    for b, h, w, nz in zip(blocks, held, whole, row_nnz):
        m, d, k = b.J.shape
        n = int(nz.sum())
        if w and m:
            live = np.flatnonzero(~h[0])
            data[at:at + n].reshape(m, d, len(live))[...] = b.J[:, :, live]
            indices[at:at + n].reshape(m, d, len(live))[...] = b.cols[:, None, live]
        elif m:
            keep = np.broadcast_to(~h[:, None, :], (m, d, k))
            data[at:at + n] = b.J[keep]
            indices[at:at + n] = np.broadcast_to(b.cols[:, None, :], (m, d, k))[keep]
        at += n
    r = np.concatenate([b.r.ravel() for b in blocks])
    J = sp.csr_matrix((data, indices, indptr.astype(index_type, copy=False)), shape=(len(r), n_cols))
    return J, r


def retract(state: State, lay: Layout, dx: np.ndarray) -> State:
    """The state moved by a step dx (lay.size,) in the block's perturbation conventions."""
    n, c, k = lay.n_ctrl, lay.n_cam, lay.n_bias
    sp_ = state.spline
    spline = replace(sp_, R=_turn(sp_.R, dx[:3 * n].reshape(n, 3)), p=sp_.p + dx[lay.pos:lay.pos + 3 * n].reshape(n, 3))
    dc = dx[lay.cam:lay.cam + 6 * c].reshape(c, 6)
    T_body_cam = state.T_body_cam.copy()
    T_body_cam[:, :3, :3] = _turn(T_body_cam[:, :3, :3], dc[:, :3])
    T_body_cam[:, :3, 3] += dc[:, 3:]
    T_body_imu = state.T_body_imu.copy()
    T_body_imu[:3, :3] = _turn(T_body_imu[:3, :3], dx[lay.imu:lay.imu + 3])
    T_body_imu[:3, 3] += dx[lay.imu + 3:lay.imu + 6]
    R_grav = geo.R_from_rotvec(tangent_basis(state.R_grav) @ dx[lay.grav:lay.grav + 2]) @ state.R_grav
    T_world_board = state.T_world_board.copy()
    if lay.n_board:
        db = dx[lay.board:lay.board + 6 * lay.n_board].reshape(-1, 6)
        T_world_board[1:, :3, :3] = _turn(T_world_board[1:, :3, :3], db[:, :3])
        T_world_board[1:, :3, 3] += db[:, 3:]
    intrinsics = tuple(i.with_params(i.params() + dx[lay.intr_start(c):lay.intr_start(c) + n])
                       for c, (i, n) in enumerate(zip(state.intrinsics, lay.n_intr)))
    return replace(state, spline=spline, T_world_board=T_world_board, intrinsics=intrinsics, M_gyro=state.M_gyro + lower(dx[lay.scale:lay.scale + 6]),
                   M_accel=state.M_accel + lower(dx[lay.scale + 6:lay.scale + 12]), T_body_cam=T_body_cam, T_body_imu=T_body_imu,
                   time_offset_s=state.time_offset_s + dx[lay.offset:lay.offset + c],
                   line_delay_s=state.line_delay_s + dx[lay.line_delay:lay.line_delay + c],
                   gyro_bias=state.gyro_bias + dx[lay.bg:lay.bg + 3 * k].reshape(k, 3),
                   accel_bias=state.accel_bias + dx[lay.ba:lay.ba + 3 * k].reshape(k, 3), R_grav=R_grav)
