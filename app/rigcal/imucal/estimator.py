"""The camera-IMU estimator: the body trajectory as a spline, every camera's
T_body_cam and clock offset, gyroscope and accelerometer biases and gravity's direction,
and, when the state carries them, the boards' poses and the cameras' intrinsics, jointly,
by Levenberg-Marquardt on the sparse residual blocks of rigcal.imucal.residuals.

`rigcal calibrate` calls it through rigcal.imucal.step. What it assumes: a start for the
intrinsics (a camera-only calibration; held unless Settings.intrinsics), static boards
with board 0 the world frame (held), the reference IMU's T_body_imu held (it defines the
body frame, docs/formats.md#motion-datasets), no outlier rejection, one IMU.

The cost is linear in recording length: each residual touches 4 consecutive control
points, so J^T J is banded apart from the few camera, offset, board, intrinsic and gravity
columns, and scipy's sparse LU factors it in time linear in the number of knots.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from rigcal.core import geometry as geo
from rigcal.imucal import residuals as ir
from rigcal.imucal import start as imu_start
from rigcal.core import spline as spl
from rigcal.core.camera import CameraModel
from rigcal.errors import CalibrationError


@dataclass(frozen=True)
class ImuInput:
    """One IMU's samples (t (N,) seconds on the IMU clock, gyro, accel (N, 3)), its declared
    noise (Kalibr units) and its pose T_body_imu (held)."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    update_rate: float
    gyroscope_noise_density: float
    gyroscope_random_walk: float
    accelerometer_noise_density: float
    accelerometer_random_walk: float
    T_body_imu: np.ndarray


@dataclass(frozen=True)
class CameraInput:
    """One camera: its intrinsics, declared T_body_cam (its translation is the start),
    line delay, and its poses T_world_cam (F, 4, 4) at frame times t_cam (F,) (camera clock),
    e.g. from PnP on the board views: only the start uses them."""

    model: CameraModel
    T_body_cam: np.ndarray
    t_cam: np.ndarray
    T_world_cam: np.ndarray
    line_delay_s: float = 0.0
    time_offset_guess_s: float = 0.0


@dataclass(frozen=True)
class Settings:
    """knot_dt: spline knot spacing (s); bias_dt: bias knot spacing (s); sigma_px: corner
    noise (px); gravity: |g|; window_s: the clock-offset search half-width; line_delay:
    estimate line delays (else held at the declared ones); scale_misalignment: estimate
    the IMU's scale-misalignment matrices (the `scale-misalignment` model; else M = I);
    intrinsics: estimate every camera's intrinsics (given to calibrate_camera_imu) jointly."""

    knot_dt: float = 0.05
    bias_dt: float = 1.0
    sigma_px: float = 0.5
    gravity: float = ir.GRAVITY
    window_s: float = imu_start.SEARCH_WINDOW_S
    max_iter: int = 30
    line_delay: bool = False  # estimate every camera's line delay (rolling shutter)
    huber: float | None = None  # Huber loss on each corner's residual beyond this many sigma_px
    scale_misalignment: bool = False
    intrinsics: bool = False  # estimate the intrinsics the state carries (State.intrinsics)
    # with intrinsics: per camera (fx fy cx cy (4,), their 1-sigma (4,)) of an earlier camera
    # calibration weighing them (residuals.intrinsics_prior_block), or None; empty: no prior
    intrinsics_prior: tuple = ()


@dataclass(frozen=True, eq=False)
class CameraImuResult:
    """The estimate: state (all of it), per camera T_imu_cam (C, 4, 4) and time_offset_s (C,),
    their 1-sigma (C, 7): rotation (rad, body axes), translation (m), offset (s), from the
    declared noise; the starts; per-block RMS of the normalised residuals (1 = as declared)
    and objective (sum of squares, or the Huber cost); corners_used (M,) bool: the given
    corners inside the IMU stream's spline (frame_span)."""

    state: ir.State
    T_imu_cam: np.ndarray
    time_offset_s: np.ndarray
    sigma: np.ndarray
    starts: tuple
    normalised_rms: dict
    iterations: int
    seconds: float
    corners_used: np.ndarray
    costs: dict
    # the residual blocks at `state` as the last Levenberg-Marquardt iteration made them,
    # with the settings they were weighted by: step.jacobian reuses them instead of one more
    # evaluation (1.5 s on EuRoC). Empty when not kept.
    blocks: tuple = ()
    settings: Settings | None = None
    # the corners_used the blocks were made on (this very array: a result whose corners_used
    # was replaced, e.g. outliers left out, no longer matches its blocks)
    blocks_corners: np.ndarray | None = None


def imu_sigmas(imu: ImuInput) -> tuple[float, float]:
    """The declared discrete noise (gyroscope rad/s, accelerometer m/s^2): density x sqrt(rate)."""
    r = math.sqrt(imu.update_rate)
    return imu.gyroscope_noise_density * r, imu.accelerometer_noise_density * r


REFINE_COST_TOL = 0.05  # refine(): a step lowering the cost (chi-square units) by less ends it
# the estimate: a step lowering the cost by less than this (chi-square units) ends it. The
# optimum is then within sqrt(0.01) = 0.1 standard deviations (Mahalanobis, all parameters)
# at most; on EuRoC it saves the last of 10 evaluations, whose step gained 0.001
ESTIMATE_COST_TOL = 0.01
# levenberg_marquardt's first damping (relative to diag(J^T J)) from a start and from a
# solution (a refit with more parameters, or of a part of the recording). Nearly
# Gauss-Newton: a step that raises the cost is retried with 10x the damping, and a larger
# first damping held back the directions the cameras, the trajectory and the IMU model
# share. On EuRoC (0.01 s knots) the estimate took 9 cost evaluations from 1e-4, 7 from
# 1e-6, 5 from 1e-8, to the same optimum (within 1e-6 deg and 1e-4 mm); the
# scale-misalignment refit 8 iterations from 1e-4, 4 from 1e-8, to a lower cost
START_LAMBDA = 1e-8
WARM_LAMBDA = 1e-8
# levenberg_marquardt also ends once the next step would gain less than this fraction of
# the stopping threshold, as the Gauss-Newton model at the new state predicts it (its
# gradient, the last factorisation): the step that would only confirm convergence, one cost
# and Jacobian evaluation and one factorisation, is not taken. Predicted and taken gains of
# steps taken agreed to 0.3 % in every pass (EuRoC, the 30 s recording)
MODEL_STOP = 0.5
NEARLY_GN = 1e-4  # ... when the last factorisation was damped by at most this (relative to diag(J^T J))
SPLINE_PAD = 2  # knots beyond the first and last frame: room for clock-offset steps


def initial_spline(t: np.ndarray, T_world_body: np.ndarray, dt: float, smooth_s: float, pad: int = SPLINE_PAD,
                   attitude=None) -> spl.Spline:
    """A start spline with knots every dt through noisy sampled body poses: each control point
    is the Gaussian-weighted (sigma smooth_s) mean of the samples near its knot, positions
    arithmetically, rotations by the chordal mean. A cubic B-spline's curve lies within
    dt^2 |p''| / 6 of its control points, so this is a start the estimator refines; linear
    in the samples (each knot gathers a fixed window). `pad` extra knots on each side keep
    clock-offset steps on the spline (the IMU shapes them).

    attitude: R_start_body(t) (e.g. gyro_attitude's, any start) or None; given, each sample's
    rotation is carried to the knot's time by it before averaging, so the mean does not lag
    behind fast turns, and a knot without samples near it (the board out of view: EuRoC's
    recording has a 1.2 s gap) takes the nearest sample's rotation carried by the gyroscope
    (positions there are interpolated linearly between covered knots; the accelerometer
    then shapes them). Without it such a start put EuRoC's LM in a wrong minimum."""
    order = np.argsort(t)
    t, T = t[order], T_world_body[order]
    t0, n = spl.knots_for(t[0], t[-1], dt)
    knot_t = t0 + (np.arange(-pad, n + pad) - 1) * dt
    lo = np.searchsorted(t, knot_t - 3 * smooth_s)
    hi = np.searchsorted(t, knot_t + 3 * smooth_s)
    width = max(int((hi - lo).max()), 1)
    idx = np.minimum(lo[:, None] + np.arange(width), len(t) - 1)
    inside = np.arange(width)[None] < (hi - lo)[:, None]
    w = np.exp(-0.5 * ((t[idx] - knot_t[:, None]) / smooth_s) ** 2) * inside
    # a knot past the ends (padding) takes the nearest sample
    empty = w.sum(axis=1) == 0
    idx[empty, 0] = np.clip(np.searchsorted(t, knot_t[empty]), 0, len(t) - 1)
    w[empty, 0] = 1.0
    w /= w.sum(axis=1, keepdims=True)
    p = np.einsum("kw,kwi->ki", w, T[idx, :3, 3])
    R_s = T[idx, :3, :3]
    if attitude is not None:
        R_s = R_s @ np.swapaxes(attitude(t[idx]), -1, -2) @ attitude(knot_t)[:, None]
        inner = (knot_t > t[0]) & (knot_t < t[-1])
        lone = empty & inner
        if lone.any() and (~lone).sum() >= 2:
            for k in range(3):
                p[lone, k] = np.interp(knot_t[lone], knot_t[~lone], p[~lone, k])
    R = geo.nearest_rotation(np.einsum("kw,kwij->kij", w, R_s))
    return spl.Spline(t0 - pad * dt, dt, R, p)


def gyro_attitude(imu: ImuInput):
    """R_start_body(t) for any times (nearest IMU sample): the gyroscope (in body axes
    through the held R_body_imu) integrated from the first sample, one Exp per interval."""
    w = imu.gyro @ imu.T_body_imu[:3, :3].T
    steps = geo.R_from_rotvec(0.5 * (w[1:] + w[:-1]) * np.diff(imu.t)[:, None])
    out = np.empty((len(imu.t), 3, 3))
    out[0] = np.eye(3)
    for k, S in enumerate(steps):  # sequential by nature; 3x3 products, ~15k a minute of IMU
        out[k + 1] = out[k] @ S
    return lambda t: out[np.clip(np.searchsorted(imu.t, t), 0, len(imu.t) - 1)]


def gravity_start(spline: spl.Spline, imu: ImuInput, t: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """R_grav whose third column is -g's direction: g_world = a_world - R_world_imu f, averaged."""
    m = spl.evaluate(spline, t)
    R_wi = m.R_world_body @ imu.T_body_imu[:3, :3]
    g = (m.a_world - np.einsum("mij,mj->mi", R_wi, accel)).mean(axis=0)
    z = -g / np.linalg.norm(g)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def start_state(cams: list[CameraInput], imu: ImuInput, settings: Settings) -> tuple[ir.State, tuple, np.ndarray]:
    """(state, per-camera RateStart, IMU sample mask): offsets and rotations from rates,
    declared translations, the trajectory from the camera poses, zero biases, gravity from
    the accelerometer. Refuses a recording that turns about one axis or never accelerates.

    The spline spans the frames inside the IMU stream (less its padding knots): a knot that
    only frames at a segment's edge touch, with no IMU sample, is all but unobserved, LM's
    scale-free damping then let it turn by thousands of degrees (EuRoC's first frame is 5 ms
    after its first IMU sample) and no step lowered the cost. Corners of frames outside the
    span are left out (`frame_span`)."""
    starts, T_body_cam, t_all, T_world_body = [], [], [], []
    for ci, c in enumerate(cams):
        s = imu_start.rate_start(c.t_cam, c.T_world_cam[:, :3, :3], imu.t, imu.gyro, c.time_offset_guess_s,
                                 settings.window_s, what=f"camera {ci}")
        T = c.T_body_cam.copy()
        T[:3, :3] = imu.T_body_imu[:3, :3] @ s.R_imu_cam
        starts.append(s)
        T_body_cam.append(T)
        t_all.append(c.t_cam + s.time_offset_s)
        T_world_body.append(c.T_world_cam @ geo.inv_T(T))
    t_all, T_world_body = np.concatenate(t_all), np.concatenate(T_world_body)
    pad = SPLINE_PAD * settings.knot_dt
    inside = (t_all >= imu.t[0] + pad) & (t_all <= imu.t[-1] - pad - settings.knot_dt)
    if inside.sum() < 2:
        raise CalibrationError("no camera frame falls inside the IMU stream")
    t_all, T_world_body = t_all[inside], T_world_body[inside]
    frame_dt = float(np.median(np.diff(np.sort(cams[0].t_cam))))
    spline = initial_spline(t_all, T_world_body, settings.knot_dt, max(settings.knot_dt, 1.5 * frame_dt),
                            attitude=gyro_attitude(imu))
    imu_start.check_acceleration(spl.evaluate(spline, np.arange(t_all.min(), t_all.max(), 0.01)).a_world,
                                 "the camera trajectory")
    use = imu_span(spline, imu.t)
    n_bias = int(math.ceil((spline.t_end - spline.t0) / settings.bias_dt)) + 1
    state = ir.State(spline=spline, T_body_imu=imu.T_body_imu.copy(), T_body_cam=np.stack(T_body_cam),
                     time_offset_s=np.array([s.time_offset_s for s in starts]),
                     line_delay_s=np.array([c.line_delay_s for c in cams]), bias_t0=spline.t0,
                     bias_dt=settings.bias_dt, gyro_bias=np.zeros((n_bias, 3)), accel_bias=np.zeros((n_bias, 3)),
                     R_grav=np.eye(3), gravity=settings.gravity)
    R_grav = gravity_start(spline, imu, imu.t[use], imu.accel[use])
    return replace(state, R_grav=R_grav), tuple(starts), use


def residual_blocks(state: ir.State, lay: ir.Layout, obs: ir.Corners, models: list, imu: ImuInput,
                    use: np.ndarray, settings: Settings, corners: ir.Block | None = None) -> list:
    """The blocks the estimate minimises at `state`: corners (normal_rows' form), gyroscope,
    accelerometer and the biases' random walk, on the IMU samples `use` (imu_span). corners:
    the corner block at `state` when the caller has it (not evaluated again)."""
    sg, sa = imu_sigmas(imu)
    mj = ir.motion_jacobian(state, imu.t[use])  # shared by both IMU blocks
    blocks = [corners if corners is not None else ir.reprojection_rows(state, lay, obs, models, settings.sigma_px,
                                                                       settings.huber),
              ir.gyro_block(state, lay, imu.t[use], imu.gyro[use], sg, mj),
              ir.accel_block(state, lay, imu.t[use], imu.accel[use], sa, mj),
              ir.bias_prior_block(state, lay, imu.gyroscope_random_walk, imu.accelerometer_random_walk)]
    if settings.intrinsics and settings.intrinsics_prior and state.intrinsics:
        blocks.append(ir.intrinsics_prior_block(state, lay, settings.intrinsics_prior))
    return blocks


def band_order(lay: ir.Layout) -> np.ndarray:
    """A column permutation that makes J^T J banded with an arrow: each control point's
    rotation and position together, in time order (a residual touches 4 consecutive ones),
    each bias knot's 6 columns just after the last control point whose residuals reach it,
    then the few global columns (cameras, offsets, gravity, IMU pose, line delays).
    Factored in this order without pivoting the fill stays in the band, the bias knots'
    spans and the arrow, so the cost is linear in the number of knots (sparse LU's own
    column ordering filled far more: 3x slower at 100 knots/s). With the bias knots in the
    arrow instead, every bias row filled in to the end of the recording: on EuRoC's 72 s at
    100 knots/s (73 bias knots) a factorisation took 1.02 s, interleaved 0.17 s."""
    n = lay.n_ctrl
    k = np.arange(n)[:, None]
    spline = np.concatenate([lay.rot + 3 * k + np.arange(3), lay.pos + 3 * k + np.arange(3)], axis=1)
    j = np.arange(lay.n_bias)
    bias = np.concatenate([lay.bg + 3 * j[:, None] + np.arange(3), lay.ba + 3 * j[:, None] + np.arange(3)], axis=1)
    if lay.knots_per_bias <= 0:  # placement unknown: the bias knots join the arrow
        return np.concatenate([spline.ravel(), np.arange(6 * n, lay.size)])
    # bias knot j is interpolated over [j - 1, j + 1] bias intervals; the residuals there
    # reach control points up to segment index ... + ORDER - 1
    last = np.ceil(lay.bias_knot0 + (j + 1) * lay.knots_per_bias).astype(int) + spl.ORDER - 1
    after = np.clip(last, 0, n - 1)
    # a stable sort of (position, kind): control c, then the bias knots placed after it
    key = np.concatenate([2 * np.arange(n), 2 * after + 1])
    rows = np.concatenate([spline, bias])[np.argsort(key, kind="stable")].ravel()
    rest = np.setdiff1d(np.arange(lay.size), rows, assume_unique=True)
    return np.concatenate([rows, rest])


def factor(H: sp.spmatrix, order: np.ndarray):
    """(solve, active columns): a sparse LU of the SPD matrix H restricted to its non-empty
    columns (held groups have none), in `order` without pivoting; solve maps right-hand
    sides over the active columns (in H's own indexing) to solutions."""
    d = H.diagonal()
    act = order[d[order] > 0]
    lu = spla.splu(H[act][:, act].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    return lu.solve, act


# gram: below this many rows J^T J is one product (threads cost more than they save)
GRAM_SPLIT_ROWS = 20_000


def gram(J: sp.csr_matrix) -> sp.csc_matrix:
    """J^T J (CSC) as the sum over two halves of J's rows, each product on its own thread:
    scipy's sparse product runs on one core with the GIL released, and it is the estimate's
    largest single-threaded step (on the 30 s three-camera recording 1.0 of the 5.7 s of
    camera-IMU; on 2 cores the halves take 0.6 of the whole's time). The same matrix to
    rounding (the sums in another order)."""
    if J.shape[0] < GRAM_SPLIT_ROWS:
        return (J.T @ J).tocsc()
    from concurrent.futures import ThreadPoolExecutor

    h = J.shape[0] // 2
    with ThreadPoolExecutor(max_workers=2) as ex:
        a, b = ex.map(lambda P: P.T @ P, (J[:h], J[h:]))
    return (a + b).tocsc()


def levenberg_marquardt(state: ir.State, lay: ir.Layout, blocks_of, max_iter: int, cost_tol: float = 0.0,
                        lam0: float = START_LAMBDA, blocks: list | None = None, loose: tuple | None = None
                        ) -> tuple[ir.State, list, int]:
    """Minimise the sum of squared block residuals; returns (state, its blocks, iterations).
    Steps solve (J^T J + lam diag(J^T J)) dx = -J^T r by sparse LU. Converged when a step
    lowers the cost by less than tol = max(1e-9 of it, cost_tol), or when the next step
    would lower it by less than MODEL_STOP tol as predicted at the new state: g^T H^-1 g with
    its gradient g = J^T r and the last factorisation for H (near the optimum H barely
    changes). blocks: blocks_of(state) when the caller has them (not evaluated again).
    loose: (a larger cost_tol, a test of the blocks): the tolerance where the new state's
    blocks pass the test (e.g. a refinement with other weights follows from there)."""
    blocks = blocks_of(state) if blocks is None else blocks
    order = band_order(lay)
    J, r = ir.assemble(ir.normal_rows(blocks), lay.size)
    cost, lam = sum(b.objective for b in blocks), lam0
    if not np.isfinite(cost):  # no trial cost compares below NaN: LM would return the start quietly
        bad = [i for i, b in enumerate(blocks) if not np.isfinite(b.objective)]
        raise CalibrationError(f"the camera-IMU start gives non-finite residuals (blocks {bad}); nothing to refine")
    for it in range(1, max_iter + 1):
        H = gram(J)
        g = J.T @ r
        d = H.diagonal()
        while True:
            if lam > 1e8:  # no step lowers the cost: converged as far as it can
                return state, blocks, it
            solve, act = factor((H + sp.diags(lam * np.maximum(d, 1e-9))).tocsc(), order)
            dx = np.zeros(lay.size)
            dx[act] = solve(-g[act])
            if not np.all(np.isfinite(dx)):  # a factorisation without pivoting broke down: damp more
                lam *= 10
                continue
            trial = ir.retract(state, lay, dx)
            try:
                tb = blocks_of(trial)
            except ValueError:  # a step that moves a time off the spline: a smaller step
                lam *= 10
                continue
            c = sum(b.objective for b in tb)
            if c < cost:  # False for NaN too
                break
            lam *= 10
        tol = max(1e-9 * cost, cost_tol)
        if loose is not None and loose[0] > tol and loose[1](tb):
            tol = loose[0]
        done = cost - c < tol
        nearly_gn = lam <= NEARLY_GN  # the factorisation is then H's to that relative damping
        state, blocks, cost, lam = trial, tb, c, max(lam / 10, 1e-9)
        if done:
            return state, blocks, it
        # the Jacobian only for a step taken (a rejected trial needs just its cost)
        J, r = ir.assemble(ir.normal_rows(blocks), lay.size)
        g_new = J.T @ r
        if nearly_gn and -(g_new[act] @ solve(-g_new[act])) < MODEL_STOP * tol:  # the next step's predicted gain
            return state, blocks, it
    return state, blocks, max_iter


def normal_factor(J: sp.csr_matrix, lay: ir.Layout):
    """(solve, active columns) of J^T J (gram): one sparse LU in the banded-arrow order
    (band_order; SuperLU's own ordering took 157 s on EuRoC's 72 s at 100 knots/s), for
    covariances: camera_sigmas here, the step's linear_sigmas and intrinsics_coupling."""
    return factor(gram(J), band_order(lay))


def camera_sigmas(J: sp.csr_matrix, lay: ir.Layout) -> np.ndarray:
    """1-sigma (C, 7) of each camera's rotation, translation and offset: the diagonal of
    (J^T J)^-1 for those columns, by one sparse LU (normal_factor) and 7 C solves."""
    solve, active = normal_factor(J, lay)
    where = np.full(lay.size, -1)
    where[active] = np.arange(len(active))
    cols = where[np.concatenate([lay.cam + np.arange(6 * lay.n_cam), lay.offset + np.arange(lay.n_cam)])]
    E = np.zeros((len(active), len(cols)))
    E[cols, np.arange(len(cols))] = 1.0
    var = solve(E)[cols, np.arange(len(cols))]
    sd = np.sqrt(np.maximum(var, 0.0))
    return np.column_stack([sd[:6 * lay.n_cam].reshape(lay.n_cam, 6), sd[6 * lay.n_cam:]])


def frame_span(state: ir.State, obs: ir.Corners) -> np.ndarray:
    """(M,) bool: the corners whose frame (first row, IMU clock) lies between the spline's
    padding knots, i.e. among the frames start_state built it from."""
    t = obs.t_cam + state.time_offset_s[obs.cam]
    sp_ = state.spline
    pad = SPLINE_PAD * sp_.dt
    return (t >= sp_.t0 + pad - 1e-9) & (t <= sp_.t_end - pad + 1e-9)


def held_groups(settings: Settings) -> frozenset:
    """The parameter groups the estimate holds: the reference IMU's pose always, the line
    delays, the scale-misalignment matrices and the intrinsics unless settings estimate them."""
    return frozenset({"imu_rot", "imu_pos"} | (set() if settings.line_delay else {"line_delay"})
                     | (set() if settings.scale_misalignment else {"scale"})
                     | (set() if settings.intrinsics else {"intrinsics"}))


def calibrate_camera_imu(cams: list[CameraInput], obs: ir.Corners, imu: ImuInput,
                         settings: Settings = Settings(), T_world_board: np.ndarray | None = None,
                         intrinsics: tuple = (), sigmas: bool = True, loose: tuple | None = None) -> CameraImuResult:
    """Start (imu_start), then the joint estimate; raises CalibrationError on a recording
    that cannot determine it or when the corners' times fall outside the IMU stream.
    T_world_board (B, 4, 4): the boards' start poses when obs has several (board 0 is the
    world: held; the others are estimated); the cameras' T_world_cam must agree with it.
    intrinsics: per camera rigcal.camcal.solve.Intrinsics to start from (settings.intrinsics: to
    estimate; the cameras' models must agree with them). sigmas: False leaves the result's
    `sigma` NaN (a caller that computes its own saves a sparse LU: 0.6 s on EuRoC). loose:
    levenberg_marquardt's."""
    t0 = time.perf_counter()
    state, starts, use = start_state(cams, imu, settings)
    if T_world_board is not None:
        state = replace(state, T_world_board=np.array(T_world_board, float))
    if intrinsics:
        state = replace(state, intrinsics=tuple(intrinsics))
    keep = frame_span(state, obs)
    if not keep.any():
        raise CalibrationError("no corner falls inside the IMU stream")
    obs = obs.subset(keep)
    t_obs = ir.corner_times(state, obs)
    if t_obs.min() < state.spline.t0 or t_obs.max() > state.spline.t_end:
        raise CalibrationError("corner times fall outside the camera frames' span; give every frame's pose")
    return _solve(state, tuple(starts), keep, obs, [c.model for c in cams], imu, use, settings, t0, ESTIMATE_COST_TOL,
                  sigmas, loose=loose)


def refine(res: CameraImuResult, models: list[CameraModel], obs: ir.Corners, imu: ImuInput,
           settings: Settings, cost_tol: float = REFINE_COST_TOL, lam0: float | None = None) -> CameraImuResult:
    """The estimate again from `res` (its state, starts and corners: obs as given to the
    estimate that gave res), e.g. with the scale-misalignment matrices freed: the larger
    model's fit for the likelihood ratio of `--imu-model auto`. It stops once a step lowers
    the cost by less than cost_tol (REFINE_COST_TOL: the ratio is then known to that, far
    below the test's threshold, 39.1, and the last steps of the estimate's own 1e-9
    criterion cost 4 of 5 iterations on the 30 s recording; 0: to convergence). Its `sigma`
    is NaN: not computed (one more sparse LU), the test needs only the costs. lam0: LM's
    first damping (None: WARM_LAMBDA, the start being a solution). With settings that differ
    from res's only in the corner noise (the re-weighted refinement) its first evaluation is
    res's last blocks re-weighted (reweighted_blocks), not a new one; with another IMU model
    (the scale-misalignment refit) its corner block (reweighted_corners), the IMU's evaluated."""
    t0 = time.perf_counter()
    k = res.corners_used
    return _solve(res.state, res.starts, k, obs.subset(k), models, imu, imu_span(res.state.spline, imu.t), settings, t0,
                  cost_tol, sigmas=False, lam0=WARM_LAMBDA if lam0 is None else lam0,
                  blocks=reweighted_blocks(res, settings), corners=reweighted_corners(res, settings))


def solve_from(state: ir.State, obs: ir.Corners, models: list[CameraModel], imu: ImuInput, settings: Settings,
               starts: tuple = (), sigmas: bool = True, cost_tol: float = ESTIMATE_COST_TOL,
               lam0: float = START_LAMBDA, loose: tuple | None = None) -> CameraImuResult:
    """The joint estimate from a given state (e.g. a trajectory found on one board, the other
    boards and cameras placed in it, or a time window of a solution) on the corners whose
    frames the state's spline spans and the IMU samples inside it; sigmas as
    calibrate_camera_imu's; cost_tol, lam0 and loose as levenberg_marquardt's (WARM_LAMBDA
    from a solution's state, e.g. a time window of one)."""
    t0 = time.perf_counter()
    keep = frame_span(state, obs)
    if not keep.any():
        raise CalibrationError("no corner falls inside the IMU stream")
    return _solve(state, starts, keep, obs.subset(keep), models, imu, imu_span(state.spline, imu.t), settings, t0,
                  cost_tol, sigmas, lam0, loose=loose)


def imu_span(spline: spl.Spline, t: np.ndarray) -> np.ndarray:
    """(N,) bool: the IMU samples the estimate uses, those inside the spline by half a knot
    (a sample at its very end has no full segment of support)."""
    return (t >= spline.t0 + 0.5 * spline.dt) & (t <= spline.t_end - 0.5 * spline.dt)


def _solve(state: ir.State, starts: tuple, keep: np.ndarray, obs: ir.Corners, models: list, imu: ImuInput,
           use: np.ndarray, settings: Settings, t0: float, cost_tol: float = 0.0, sigmas: bool = True,
           lam0: float | None = None, blocks: list | None = None, loose: tuple | None = None,
           corners: ir.Block | None = None) -> CameraImuResult:
    lay = ir.layout_for(state, held_groups(settings))
    if blocks is None and corners is not None:  # the first evaluation without the corners'
        blocks = residual_blocks(state, lay, obs, models, imu, use, settings, corners)
    state, blocks, iters = levenberg_marquardt(state, lay, lambda s: residual_blocks(s, lay, obs, models, imu, use, settings),
                                               settings.max_iter, cost_tol, START_LAMBDA if lam0 is None else lam0,
                                               blocks, loose)
    names = ("corners", "gyro", "accel", "bias_walk")
    rms = {k: b.residual_rms for k, b in zip(names, blocks)}
    T_imu_cam = geo.inv_T(state.T_body_imu)[None] @ state.T_body_cam
    sigma = camera_sigmas(ir.assemble(ir.normal_rows(blocks), lay.size)[0], lay) if sigmas else np.full((lay.n_cam, 7), np.nan)
    return CameraImuResult(state, T_imu_cam, state.time_offset_s.copy(), sigma, starts, rms,
                           iters, time.perf_counter() - t0, keep, {k: b.objective for k, b in zip(names, blocks)},
                           tuple(blocks), settings, keep)


def reweighted_blocks(res: CameraImuResult, settings: Settings) -> list | None:
    """res's last residual blocks (at res.state) weighted as `settings` weigh them, or None
    when they cannot be had without an evaluation: none kept, a Huber loss (not linear in the
    weight), or settings that differ from res's in anything but the corner noise sigma_px
    (another parameter set or IMU model). The corner block is linear in 1 / sigma_px (its
    merged rows too: the Cholesky factor of a scaled Gram matrix scales alike), so it is
    rescaled; the IMU and prior blocks do not depend on it."""
    corners = reweighted_corners(res, settings)
    if corners is None or held_groups(res.settings) != held_groups(settings):
        return None
    return [corners, *res.blocks[1:]]


def reweighted_corners(res: CameraImuResult, settings: Settings) -> ir.Block | None:
    """res's last corner block weighted as `settings` weigh the corners, or None when it
    cannot be had without an evaluation (reweighted_blocks' cases). The IMU model may differ
    (scale_misalignment): its columns are no corner's, and every layout has them, held or not."""
    used = res.settings
    if not res.blocks or used is None or used.huber is not None or settings.huber is not None:
        return None
    if res.blocks_corners is not res.corners_used:  # made on other corners
        return None
    if (held_groups(used) - {"scale"} != held_groups(settings) - {"scale"}
            or used.intrinsics_prior is not settings.intrinsics_prior
            or replace(used, sigma_px=settings.sigma_px, intrinsics_prior=(),
                       scale_misalignment=settings.scale_misalignment) != replace(settings, intrinsics_prior=())):
        return None
    k = used.sigma_px / settings.sigma_px
    b = res.blocks[0]
    return replace(b, r=b.r * k, J=b.J * k, cost=None if b.cost is None else b.cost * k * k,
                   rms=None if b.rms is None else b.rms * k)
