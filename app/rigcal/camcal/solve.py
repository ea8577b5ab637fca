"""Joint bundle adjustment of a camera rig.

Unknowns: every camera's intrinsics and distortion, `T_cam_body` for every camera
but the gauge camera, `T_body_world` for every frame, `T_world_board` for every
board but the gauge board. One corner observation predicts

    p_cam = T_cam_body @ T_body_world(frame) @ T_world_board(board) @ p_board
    uv    = project(intrinsics(cam), p_cam)

A moving board seen by a static rig is the same model (only relative motion
matters): the world is the board's frame and each frame's body pose moves.

Rotations are parameterised locally, R = exp(delta) @ R0, so every rotation can
be anywhere on SO(3) while the optimiser only sees small vectors. The Jacobian is
analytic in the poses (with the SO(3) left Jacobian, so it is exact away from
delta = 0 too) and central-differenced only through the per-point projection,
which costs a handful of vectorised projections.

The problem is written in rigcal.camcal.blocks' terms: RigParameters registers the parameter
blocks (per camera its intrinsics and pose, the boards, the frames: the family the Schur
step eliminates), and Reprojection is the corner residual block. Problem.blocks is the
list of residual blocks; a further kind (gyroscope, accelerometer, clock offsets,
rolling-shutter rows) appends its own block with its own Jacobian chunks. The solve
never holds the whole Jacobian: blocks.sum_normal_equations sums J^T W J and J^T W r
chunk by chunk straight into the kept, frame and coupling blocks the Schur solve uses, so
time and memory are linear in corners (a few hundred bytes each).
Problem.jacobian builds the whole sparse matrix for tests.

Corners may carry weights (Observations.weight: inverse variances, from the detector's
own per-corner sigma calibrated by a NoiseModel); the solve is then least squares on
sqrt(w) r, outliers are judged on those whitened residuals, the reported sigma_px stays
the plain RMS in px, and the covariance is variance_factor (J^T W J)^-1.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np
import scipy.sparse as sp

from rigcal.core import geometry as geo
from rigcal.camcal.blocks import (JacobianChunk, NormalEquations, ParameterBlock, ParameterBlocks, register,
                                  sparse_jacobian, sum_normal_equations)
from rigcal.core.camera import distort_fisheye, distort_pinhole

POSE_DIM = 6
# corners per chunk of Reprojection.jacobian_chunks: bounds its temporaries (2-3 kB a corner
# in the chunk) whatever the problem's size, and is large enough for numpy to amortise
NE_CHUNK = 8192


@dataclass(frozen=True)
class Observations:
    """Corner observations, one row each. cam/frame/board index into the problem's lists;
    p_board (M, 3) board-frame corner positions (metres); uv (M, 2) measured pixels;
    weight (M,) or None: each corner's inverse variance (noise_weights; any common scale,
    the solve's variance factor takes it), None for all equal."""

    cam: np.ndarray
    frame: np.ndarray
    board: np.ndarray
    p_board: np.ndarray
    uv: np.ndarray
    view: np.ndarray  # (M,) index of the (cam, frame, board) view the corner belongs to
    weight: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.cam)

    def subset(self, mask: np.ndarray) -> "Observations":
        w = None if self.weight is None else self.weight[mask]
        return Observations(*(a[mask] for a in (self.cam, self.frame, self.board, self.p_board, self.uv, self.view)), w)

    def sqrt_weights(self) -> np.ndarray:
        """(2M,) the square root of each residual row's weight (ones without weights)."""
        if self.weight is None:
            return np.ones(2 * len(self))
        return np.repeat(np.sqrt(self.weight), 2)


# ----------------------------------------------------------------------------- corner noise model

# The detector's own per-corner sigma (BoardView.sigma) ranks corners well but its
# spread is not to be trusted: on pinhole renders it spreads 2.2x where the true error
# spreads 1.3x, on fisheye renders 3.2x against 2x (10 % to 90 % of corners). Each camera's
# residuals calibrate it: s_eff = scale * s_det^gamma, fitted on quantile bins of s_det.
NOISE_BINS = 8
NOISE_MIN_CORNERS = 400  # fewer inlier corners with a sigma in a camera: every corner alike
# weights (1 / s_eff^2) within a camera span at most this ratio, centred on its median in
# log: no corner a fit calls exceptionally clean dominates, none is all but dropped
WEIGHT_RATIO_MAX = 10.0


@dataclass(frozen=True)
class NoiseModel:
    """One camera's corner noise: s_eff = scale * s_det^gamma px per axis, clipped to
    s_mid * WEIGHT_RATIO_MAX^(+-1/4); a corner without s_det takes s_mid's. gamma 0 and
    scale the camera's RMS is a camera whose detector sigma tells nothing."""

    scale: float
    gamma: float
    s_mid: float  # the camera's median s_eff (px)
    s_ref: float  # the camera's median detected sigma (px), for corners without one

    def sigma(self, s_det: np.ndarray) -> np.ndarray:
        """(M,) effective 1-sigma px of corners with detected sigma s_det (M,), NaN unknown."""
        s = np.where(np.isfinite(s_det) & (s_det > 0), s_det, self.s_ref)
        lim = WEIGHT_RATIO_MAX ** 0.25
        return np.clip(self.scale * s ** self.gamma, self.s_mid / lim, self.s_mid * lim)


def fit_noise_model(s_det: np.ndarray, r2: np.ndarray) -> NoiseModel | None:
    """A camera's NoiseModel from its inlier corners: s_det (M,) detected sigma px (NaN
    unknown), r2 (M,) each corner's squared residual per axis, |r|^2 / 2, divided by the
    solve's redundancy (so its mean is the noise variance). gamma: the slope of log RMS
    residual against log median s_det over NOISE_BINS quantile bins, within [0, 1]; scale:
    the variance-component estimate given gamma, mean(r2 / s_det^2gamma). None when fewer
    than NOISE_MIN_CORNERS corners have a sigma."""
    known = np.isfinite(s_det) & (s_det > 0) & np.isfinite(r2)
    if known.sum() < NOISE_MIN_CORNERS:
        return None
    s, r = s_det[known], r2[known]
    edges = np.quantile(s, np.linspace(0.0, 1.0, NOISE_BINS + 1))
    b = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, NOISE_BINS - 1)
    n = np.bincount(b, minlength=NOISE_BINS)
    use = n > 0
    x = np.log(np.array([np.median(s[b == k]) for k in np.flatnonzero(use)]))
    y = 0.5 * np.log(np.bincount(b, r, minlength=NOISE_BINS)[use] / n[use])
    gamma = float(np.clip(np.polyfit(x, y, 1, w=np.sqrt(n[use]))[0], 0.0, 1.0)) if len(x) > 1 else 0.0
    scale = float(np.sqrt(np.mean(r / s ** (2 * gamma))))
    s_ref = float(np.median(s))
    return NoiseModel(scale, gamma, float(np.median(scale * s ** gamma)), s_ref)


def noise_weights(s_det: np.ndarray, cam: np.ndarray, models: list) -> np.ndarray:
    """(M,) 1 / s_eff^2 (px^-2) from each camera's NoiseModel; a camera without one
    (None) gets every corner at the mean of the others' weights (the solve's variance
    factor scales them all)."""
    w = np.full(len(cam), np.nan)
    for c, m in enumerate(models):
        k = cam == c
        if m is not None and k.any():
            w[k] = 1.0 / m.sigma(s_det[k]) ** 2
    fill = float(np.nanmean(w)) if np.isfinite(w).any() else 1.0
    return np.where(np.isfinite(w), w, fill)


@dataclass(frozen=True)
class Intrinsics:
    """One camera's intrinsics in optimiser form: model, [fx, fy, cx, cy, dist...], and
    which of them the solve estimates. tie_focal: fx = fy, one focal parameter (square
    pixels); hold_centre: cx, cy stay at their values and are no parameters. A tied or
    held value is not a parameter at all (basis()), so the covariance of the rest is
    that of the reduced problem, not of the full one with a prior."""

    model: str  # pinhole | fisheye
    values: np.ndarray  # (4 + n_dist,)
    tie_focal: bool = False
    hold_centre: bool = False

    @property
    def n_dist(self) -> int:
        return len(self.values) - 4

    def basis(self) -> np.ndarray:
        """(n_values, n_params) 0/1 matrix E: values = E @ params on the estimated rows
        (rows of zeros are held at `values`)."""
        return intrinsic_basis(len(self.values), self.tie_focal, self.hold_centre)

    def params(self) -> np.ndarray:
        """The estimated parameters of `values` (a tied focal is the mean of fx and fy)."""
        E = self.basis()
        return (E.T @ self.values) / E.sum(axis=0)

    def with_params(self, x: np.ndarray) -> "Intrinsics":
        """These intrinsics with the estimated parameters set to x (held values kept)."""
        E = self.basis()
        v = self.values.copy()
        est = E.any(axis=1)
        v[est] = (E @ x)[est]
        return replace(self, values=v)

    @property
    def structure(self) -> str:
        """'fx=fy' / 'fx,fy', and 'cx,cy held' / 'cx,cy free', for logs and reports."""
        return f"{'fx=fy' if self.tie_focal else 'fx,fy'}, {'cx,cy held' if self.hold_centre else 'cx,cy free'}"


def intrinsic_basis(n_values: int, tie_focal: bool, hold_centre: bool) -> np.ndarray:
    """(n_values, n_params) E mapping the estimated parameters onto [fx, fy, cx, cy, dist...]
    (see Intrinsics.basis): one column for a tied focal, none for a held centre."""
    cols = [[0, 1]] if tie_focal else [[0], [1]]
    if not hold_centre:
        cols += [[2], [3]]
    cols += [[k] for k in range(4, n_values)]
    E = np.zeros((n_values, len(cols)))
    for j, rows in enumerate(cols):
        E[rows, j] = 1.0
    return E


@dataclass
class State:
    """The full unknown set (poses as 4x4)."""

    intrinsics: list[Intrinsics]
    T_cam_body: np.ndarray  # (C, 4, 4)
    T_body_world: np.ndarray  # (F, 4, 4)
    T_world_board: np.ndarray  # (B, 4, 4)

    def copy(self) -> "State":
        return State([replace(i, values=i.values.copy()) for i in self.intrinsics], self.T_cam_body.copy(),
                     self.T_body_world.copy(), self.T_world_board.copy())


@dataclass(frozen=True)
class Layout:
    """Where each unknown lives in the parameter vector (ParameterBlocks.slices of the
    rig's families). Fixed blocks have no slice."""

    intr: tuple  # per camera slice or None
    cam: tuple  # per camera slice or None (gauge camera)
    frame: tuple  # per frame slice
    board: tuple  # per board slice or None (gauge board)
    size: int


def rig_parameter_blocks(state: State, gauge_cam: int, gauge_board: int, fix_intrinsics: np.ndarray) -> ParameterBlocks:
    """The rig's parameter blocks: per camera its intrinsics then its pose (T_cam_body),
    then the boards (T_world_board), then the frames (T_body_world), the family the Schur
    step eliminates (6x6 blocks, trailing). Held: fixed intrinsics, the gauge camera's and
    the gauge board's poses."""
    blocks = []
    for c, it in enumerate(state.intrinsics):
        blocks.append(ParameterBlock("intrinsics", c, it.basis().shape[1], bool(fix_intrinsics[c])))
        blocks.append(ParameterBlock("camera", c, POSE_DIM, c == gauge_cam))
    blocks += [ParameterBlock("board", b, POSE_DIM, b == gauge_board) for b in range(len(state.T_world_board))]
    blocks += [ParameterBlock("frame", f, POSE_DIM) for f in range(len(state.T_body_world))]
    return register(blocks, eliminated="frame")


def make_layout(state: State, gauge_cam: int, gauge_board: int, fix_intrinsics: np.ndarray) -> Layout:
    """The Layout of rig_parameter_blocks: camera blocks (intrinsics, extrinsics), boards,
    then frames last so the frame block is trailing and block-diagonal (Schur complement)."""
    pb = rig_parameter_blocks(state, gauge_cam, gauge_board, fix_intrinsics)
    return Layout(pb.slices("intrinsics"), pb.slices("camera"), pb.slices("frame"), pb.slices("board"), pb.size)


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian J_l(phi) for (..., 3): d/d(phi) [exp(phi) v] = -[exp(phi) v]x J_l(phi)."""
    th2 = np.sum(phi * phi, axis=-1)[..., None, None]
    th = np.sqrt(th2)
    small = th2 < 1e-10
    safe = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0, (1 - np.cos(safe)) / (safe * safe))
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (safe - np.sin(safe)) / (safe**3))
    K = geo.skew(phi)
    return np.eye(3) + a * K + b * (K @ K)


@dataclass(frozen=True)
class PoseSet:
    """One pose family at x: R (N, 3, 3), t (N, 3), the local rotation delta (N, 3) and its
    SO(3) left Jacobian J_l (N, 3, 3)."""

    R: np.ndarray
    t: np.ndarray
    delta: np.ndarray
    J_l: np.ndarray


class RigParameters:
    """The rig's unknowns as a parameter vector around a reference state: intrinsics
    through each camera's basis (Intrinsics.basis), poses as R = exp(delta) R0 with the
    translation itself. x0() is the reference; state(x) the State at x."""

    def __init__(self, state: State, gauge_cam: int, gauge_board: int, fix_intrinsics: np.ndarray):
        self.ref = state.copy()
        self.blocks = rig_parameter_blocks(state, gauge_cam, gauge_board, fix_intrinsics)
        self.layout = Layout(self.blocks.slices("intrinsics"), self.blocks.slices("camera"),
                             self.blocks.slices("frame"), self.blocks.slices("board"), self.blocks.size)
        self.bases = [it.basis() for it in state.intrinsics]
        self.models = [it.model for it in state.intrinsics]

    def _families(self) -> tuple:
        L = self.layout
        return ((self.ref.T_cam_body, L.cam), (self.ref.T_body_world, L.frame), (self.ref.T_world_board, L.board))

    def x0(self) -> np.ndarray:
        x = np.zeros(self.layout.size)
        for c, s in enumerate(self.layout.intr):
            if s is not None:
                x[s] = self.ref.intrinsics[c].params()
        for T, slices in self._families():
            for i, s in enumerate(slices):
                if s is not None:
                    x[s.start + 3:s.stop] = T[i, :3, 3]
        return x

    @staticmethod
    def _poses(x: np.ndarray, T_ref: np.ndarray, slices) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> R (N,3,3), t (N,3), delta (N,3) for a pose family."""
        n = len(T_ref)
        delta = np.zeros((n, 3))
        t = T_ref[:, :3, 3].copy()
        idx = [i for i, s in enumerate(slices) if s is not None]
        if idx:
            starts = np.array([slices[i].start for i in idx])
            delta[idx] = x[starts[:, None] + np.arange(3)]
            t[idx] = x[starts[:, None] + np.arange(3, 6)]
        R = geo.R_from_rotvec(delta) @ T_ref[:, :3, :3]
        return R, t, delta

    def pose_sets(self, x: np.ndarray) -> tuple:
        """(cameras, frames, boards) PoseSets at x: the left Jacobians once per x, not per chunk."""
        out = []
        for T_ref, slices in self._families():
            R, t, delta = self._poses(x, T_ref, slices)
            out.append(PoseSet(R, t, delta, _left_jacobian(delta)))
        return tuple(out)

    def intrinsic_values(self, x: np.ndarray) -> list[np.ndarray]:
        """Per camera [fx, fy, cx, cy, dist...] at x."""
        vals = []
        for c, s in enumerate(self.layout.intr):
            it = self.ref.intrinsics[c]
            vals.append(it.with_params(x[s]).values if s is not None else it.values)
        return vals

    def state(self, x: np.ndarray) -> State:
        intr = []
        for c, s in enumerate(self.layout.intr):
            it = self.ref.intrinsics[c]
            intr.append(it.with_params(x[s]) if s is not None else replace(it, values=it.values.copy()))
        out = []
        for T_ref, slices in self._families():
            R, t, _ = self._poses(x, T_ref, slices)
            T = np.tile(np.eye(4), (len(T_ref), 1, 1))
            T[:, :3, :3], T[:, :3, 3] = R, t
            out.append(T)
        return State(intr, *out)


@dataclass(frozen=True)
class PoseChain:
    """p_cam = Rc (Rf (Rb p_board + tb) + tf) + tc for some observations, with the rotated
    intermediates the Jacobian needs: w_rot = Rb p_board, f_rot = Rf q_world, c_rot = Rc q_body."""

    w_rot: np.ndarray
    f_rot: np.ndarray
    c_rot: np.ndarray
    p: np.ndarray


def pose_chain(o: Observations, poses: tuple) -> PoseChain:
    """The pose chain of observations `o` at `poses` (RigParameters.pose_sets)."""
    cam, frame, board = poses
    w_rot = np.einsum("mij,mj->mi", board.R[o.board], o.p_board)
    q1 = w_rot + board.t[o.board]  # world point
    f_rot = np.einsum("mij,mj->mi", frame.R[o.frame], q1)
    q2 = f_rot + frame.t[o.frame]  # body point
    c_rot = np.einsum("mij,mj->mi", cam.R[o.cam], q2)
    return PoseChain(w_rot, f_rot, c_rot, c_rot + cam.t[o.cam])


@dataclass(frozen=True)
class CornerJacobians:
    """d uv of some observations: intr {camera: (M_c, 2, n_params)} over each camera's
    estimated intrinsics (rows of that camera's observations, in order), and
    (M, 2, 6) over [rotation, translation] of the camera, frame and board poses (held
    poses included: callers skip them)."""

    intr: dict
    cam: np.ndarray
    frame: np.ndarray
    board: np.ndarray


class Reprojection:
    """The corner reprojection residual block: per observation uv(x) - uv measured (px,
    D = 2), over the intrinsics, camera, board and frame parameter blocks of
    RigParameters. Its chunks are runs of one camera and one board, frames ascending,
    so each is one dense product over shared columns (blocks.add_chunk)."""

    dim = 2

    def __init__(self, obs: Observations, params: RigParameters):
        self.obs, self.params = obs, params
        self.n_rows = len(obs)
        self._order = None  # see _sorted()

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(M, 2) projected minus measured pixels at x."""
        p = pose_chain(self.obs, self.params.pose_sets(x)).p
        return project_obs(p, self.obs.cam, self.params.intrinsic_values(x), self.params.models) - self.obs.uv

    def jacobians(self, o: Observations, poses: tuple, vals: list, cam: int | None = None) -> CornerJacobians:
        """The Jacobians of observations `o` (any subset of the problem's) at `poses` /
        `vals`. cam: every observation is of this camera (skips the per-camera split)."""
        ch = pose_chain(o, poses)
        P_cam, P_frame, P_board = poses
        models = self.params.models
        if cam is None:
            J_p, J_list = projection_jacobians(ch.p, o.cam, vals, models)
            J_intr = dict(enumerate(J_list))
        else:
            J_p, Ji = _projection_jacobians_one(ch.p, vals[cam], models[cam])
            J_intr = {cam: Ji}
        # d uv / d params = d uv / d values @ E: a tied focal's column is fx's + fy's
        J_intr = {c: Ji @ self.params.bases[c] for c, Ji in J_intr.items()}
        # camera extrinsics: p = exp(dc) Rc0 q2 + tc
        D_rot_c = -geo.skew(ch.c_rot) @ P_cam.J_l[o.cam]
        cam_J = np.concatenate([J_p @ D_rot_c, J_p], axis=2)
        # frames: q2 = exp(df) Rf0 q1 + tf, p = Rc q2 + ...
        Rc_o = P_cam.R[o.cam]
        D_rot_f = Rc_o @ (-geo.skew(ch.f_rot)) @ P_frame.J_l[o.frame]
        frame = np.concatenate([J_p @ D_rot_f, J_p @ Rc_o], axis=2)
        # boards: q1 = exp(db) Rb0 P + tb
        RcRf = Rc_o @ P_frame.R[o.frame]
        D_rot_b = RcRf @ (-geo.skew(ch.w_rot)) @ P_board.J_l[o.board]
        board = np.concatenate([J_p @ D_rot_b, J_p @ RcRf], axis=2)
        return CornerJacobians(J_intr, cam_J, frame, board)

    def _sorted(self) -> np.ndarray:
        """Observation indices sorted by (camera, board, frame), cached (8 bytes a corner)."""
        if self._order is None:
            o = self.obs
            self._order = np.lexsort((o.frame, o.board, o.cam))
        return self._order

    def jacobian_chunks(self, x: np.ndarray) -> Iterator[JacobianChunk]:
        """Chunks of NE_CHUNK corners in (camera, board, frame) order, each cut into runs of
        one camera and one board: a run's kept columns (the camera's intrinsics and pose,
        the board's pose) are shared by all its rows."""
        poses, vals = self.params.pose_sets(x), self.params.intrinsic_values(x)
        L = self.params.layout
        order = self._sorted()
        o = self.obs
        for lo in range(0, len(order), NE_CHUNK):
            idx = order[lo:lo + NE_CHUNK]
            key = o.cam[idx] * len(L.board) + o.board[idx]
            cuts = np.concatenate([[0], np.flatnonzero(np.diff(key)) + 1, [len(idx)]])
            for a, b in zip(cuts[:-1], cuts[1:]):
                yield self._run_chunk(idx[a:b], poses, vals)

    def _run_chunk(self, g: np.ndarray, poses: tuple, vals: list) -> JacobianChunk:
        """The chunk of observations g (one camera, one board, frames ascending)."""
        L = self.params.layout
        o = self.obs.subset(g)
        c, b = int(o.cam[0]), int(o.board[0])
        J = self.jacobians(o, poses, vals, cam=c)
        parts, cols = [], []
        for D, s in ((J.intr[c], L.intr[c]), (J.cam, L.cam[c]), (J.board, L.board[b])):
            if s is not None:
                parts.append(D)
                cols.append(np.arange(s.start, s.stop))
        if not parts:
            return JacobianChunk(g, np.zeros((len(g), 2, 0)), np.zeros(0, int), J.frame, o.frame)
        return JacobianChunk(g, np.concatenate(parts, axis=2), np.concatenate(cols), J.frame, o.frame)


class Problem:
    """The rig bundle adjustment around a reference state: RigParameters and its residual
    blocks (corner reprojection today; further kinds append to `blocks`)."""

    def __init__(self, obs: Observations, state: State, gauge_cam: int = 0, gauge_board: int = 0,
                 fix_intrinsics: np.ndarray | None = None):
        self.obs = obs
        C = len(state.intrinsics)
        self.fix_intr = np.zeros(C, bool) if fix_intrinsics is None else np.asarray(fix_intrinsics, bool)
        self.params = RigParameters(state, gauge_cam, gauge_board, self.fix_intr)
        self.ref, self.layout = self.params.ref, self.params.layout
        self.gauge_cam, self.gauge_board = gauge_cam, gauge_board
        self.blocks = [Reprojection(obs, self.params)]
        self._sparsity = None

    def x0(self) -> np.ndarray:
        return self.params.x0()

    def state(self, x: np.ndarray) -> State:
        return self.params.state(x)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Every block's residuals at x, concatenated (corners: u0, v0, u1, ...)."""
        return np.concatenate([b.residuals(x).ravel() for b in self.blocks])

    def sqrt_weights(self) -> np.ndarray:
        """The square root of each residual's weight: the corners' noise weights, ones for
        the blocks after them (a block other than the corners whitens its own residuals,
        as the IMU blocks divide by their noise)."""
        return np.concatenate([self.obs.sqrt_weights()] + [np.ones(b.n_rows * b.dim) for b in self.blocks[1:]])

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        """The whole sparse Jacobian (rows of residuals(), layout.size): for tests and small
        problems; the solve itself sums the normal equations chunk by chunk."""
        return sparse_jacobian(self.blocks, self.params.blocks, x)

    def normal_equations(self, x: np.ndarray, e: np.ndarray, w: np.ndarray) -> NormalEquations:
        """J^T W J and J^T W e at x (e residuals, w row weights), summed chunk by chunk
        (blocks.sum_normal_equations): the Jacobian is never held whole, so memory per
        corner stays a few hundred bytes and the time linear in corners."""
        return sum_normal_equations(self.blocks, self.params.blocks, x, e, w)

    def sparsity(self) -> sp.csr_matrix:
        if self._sparsity is None:
            J = self.jacobian(self.x0())
            self._sparsity = (J != 0).astype(np.int8)
        return self._sparsity


# ----------------------------------------------------------------------------- projection


def project_obs(p: np.ndarray, cam: np.ndarray, vals: list[np.ndarray], models: list[str]) -> np.ndarray:
    """Project camera-frame points (M, 3) each through its own camera's intrinsics."""
    uv = np.empty((len(p), 2))
    for c, (v, model) in enumerate(zip(vals, models)):
        m = cam == c
        if not m.any():
            continue
        uv[m] = _project_one(p[m], v, model)
    return uv


def _project_one(p: np.ndarray, v: np.ndarray, model: str) -> np.ndarray:
    if model == "fisheye":
        xd = distort_fisheye(p, v[4:])
    else:
        z = np.where(np.abs(p[:, 2]) > 1e-12, p[:, 2], 1e-12)
        xd = distort_pinhole(p[:, :2] / z[:, None], v[4:])
    return np.column_stack([v[0] * xd[:, 0] + v[2], v[1] * xd[:, 1] + v[3]])


def projection_jacobians(p: np.ndarray, cam: np.ndarray, vals: list[np.ndarray], models: list[str]):
    """d uv / d p_cam (M, 2, 3), and per camera d uv / d intrinsics (M_c, 2, n_intr).

    Central differences through the projection only (never through the pose chain):
    a few vectorised projections, accurate to ~1e-9 relative, model-agnostic."""
    J_p = np.empty((len(p), 2, 3))
    J_intr = []
    for c, (v, model) in enumerate(zip(vals, models)):
        m = cam == c
        if not m.any():
            J_intr.append(np.zeros((0, 2, len(v))))
            continue
        J_p[m], Ji = _projection_jacobians_one(p[m], v, model)
        J_intr.append(Ji)
    return J_p, J_intr


def _projection_jacobians_one(pc: np.ndarray, v: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray]:
    """projection_jacobians for points pc (M, 3) all of one camera (values v, model)."""
    h = 1e-6 * np.maximum(np.linalg.norm(pc, axis=1), 1e-3)
    Jp = np.empty((len(pc), 2, 3))
    for k in range(3):
        dp = np.zeros_like(pc)
        dp[:, k] = h
        Jp[:, :, k] = (_project_one(pc + dp, v, model) - _project_one(pc - dp, v, model)) / (2 * h[:, None])
    Ji = np.empty((len(pc), 2, len(v)))
    base = _project_one(pc, v, model)
    # fx, fy, cx, cy enter linearly: exact derivatives.
    Ji[:, 0, 0] = (base[:, 0] - v[2]) / v[0]
    Ji[:, 1, 0] = 0.0
    Ji[:, 0, 1] = 0.0
    Ji[:, 1, 1] = (base[:, 1] - v[3]) / v[1]
    Ji[:, :, 2] = [1.0, 0.0]
    Ji[:, :, 3] = [0.0, 1.0]
    for k in range(4, len(v)):
        hk = 1e-6
        vp, vm = v.copy(), v.copy()
        vp[k] += hk
        vm[k] -= hk
        Ji[:, :, k] = (_project_one(pc, vp, model) - _project_one(pc, vm, model)) / (2 * hk)
    return Jp, Ji


# ----------------------------------------------------------------------------- solving


@dataclass
class SolveResult:
    """bundle_adjust's answer: the solved state, the problem linearised there, which
    observations were kept, their residuals and sigma, and how the iterations went."""

    state: State
    problem: Problem  # linearised at the solution (reference = solution), inliers only
    inliers: np.ndarray  # (M_all,) bool over the observations given to bundle_adjust()
    residuals: np.ndarray  # (M_inliers, 2) px at the solution
    sigma_px: float  # residual-based 1-sigma per coordinate (dof-corrected), unweighted px
    n_iterations: int
    seconds: float
    converged: bool = True
    history: list = field(default_factory=list)
    # weighted solves: the residual variance of a corner of weight 1 (px^2); the covariance
    # is variance_factor (J^T W J)^-1. None: unweighted, sigma_px^2 (J^T J)^-1.
    variance_factor: float | None = None


def _robust_weights(r: np.ndarray, scale: float | None) -> np.ndarray:
    """Per-residual IRLS weights for the Cauchy loss on each corner's 2D error (1 = plain LS)."""
    if scale is None:
        return np.ones_like(r)
    e2 = np.sum(r.reshape(-1, 2) ** 2, axis=1)
    w = 1.0 / (1.0 + e2 / scale**2)
    return np.repeat(w, 2)


def _cost(r: np.ndarray, scale: float | None) -> float:
    if scale is None:
        return 0.5 * float(np.sum(r * r))
    e2 = np.sum(r.reshape(-1, 2) ** 2, axis=1)
    return 0.5 * float(np.sum(scale**2 * np.log1p(e2 / scale**2)))


# Initial damping of the least-squares rounds, which start at or next to their solution
# (the robust pass's, or a k3-reduced one): Marquardt's usual 1e-3 held back the poorly
# conditioned directions (decentering against the principal point) and took 4 iterations
# where Gauss-Newton takes 2. A step that does not lower the cost raises it, as always.
LS_LAM0 = 1e-6


def levenberg_marquardt(problem: Problem, scale: float | None = None, max_iter: int = 100,
                        chi2_tol: float = 1e-2, lam0: float = 1e-3) -> tuple[np.ndarray, int, bool]:
    """LM with Marquardt scaling and a Schur-eliminated frame block; robust via IRLS when
    `scale` is given (Cauchy). Converged when an accepted step lowers the chi-square (cost
    in units of the residual variance) by less than chi2_tol: past that, further digits
    are far below what the data can tell. Returns (x, iterations, converged)."""
    x = problem.x0()
    sw = problem.sqrt_weights()  # weighted least squares = plain LS on sw * e
    e = problem.residuals(x)  # px
    r = sw * e
    cost = _cost(r, scale)
    dof = max(r.size - problem.layout.size, 1)
    lam = lam0
    for it in range(1, max_iter + 1):
        ne = problem.normal_equations(x, e, sw**2 * _robust_weights(r, scale))
        improved = False
        for _ in range(12):
            dx, _ = ne.solve(lam)
            x_new = x + dx
            e_new = problem.residuals(x_new)
            r_new = sw * e_new
            cost_new = _cost(r_new, scale)
            if np.isfinite(cost_new) and cost_new <= cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            return x, it, True  # no descent at any damping: at the minimum to precision
        variance = max(2.0 * cost_new / dof, 1e-300)
        drop_chi2 = 2.0 * (cost - cost_new) / variance
        x, e, r, cost = x_new, e_new, r_new, cost_new
        lam = max(lam / 10.0, 1e-9)
        if drop_chi2 < chi2_tol:
            return x, it, True
    return x, max_iter, False


def judge_inliers(obs: Observations, state: State, inliers: np.ndarray, gauge_cam: int, gauge_board: int,
                  fix_intrinsics: np.ndarray | None = None, reject_sigma: float = 5.0) -> np.ndarray:
    """(M,) bool: the corners within `reject_sigma` robust sigmas at `state`, the sigma
    from the median error of the current `inliers`; errors in units of each corner's own
    noise when it has weights (whitened residuals)."""
    pb_all = Problem(obs, state, gauge_cam, gauge_board, fix_intrinsics)
    e = np.linalg.norm((obs.sqrt_weights() * pb_all.residuals(pb_all.x0())).reshape(-1, 2), axis=1)
    return within_robust_sigmas(e, reject_sigma, inliers)


def within_robust_sigmas(e: np.ndarray, reject_sigma: float, ref: np.ndarray | None = None) -> np.ndarray:
    """(M,) bool: the 2D errors e (M,) within reject_sigma robust sigmas, the sigma from the
    median error of e[ref] (all when None): median |e| = sigma sqrt(2 ln 2) for isotropic
    Gaussian noise (Rayleigh). Also the camera-IMU step's outlier test (imucal.step)."""
    sigma = np.median(e if ref is None else e[ref]) / np.sqrt(2 * np.log(2))
    return e < reject_sigma * max(sigma, 1e-4)


@dataclass(frozen=True)
class RobustPass:
    """robust_pass's answer: the state the Cauchy-weighted solve reached, its iterations,
    whether it converged, and its seconds."""

    state: State
    n_iterations: int
    converged: bool
    seconds: float


def robust_pass(obs: Observations, state: State, gauge_cam: int, gauge_board: int,
                fix_intrinsics: np.ndarray | None = None) -> RobustPass:
    """bundle_adjust's first stage: the solve under a Cauchy loss from a rough start. It only
    has to bring the inliers close enough to tell them from the outliers (a few sigma of
    parameter error move residuals far less than the noise), so it stops at a chi-square
    drop of 10; the least-squares rounds after it converge to chi2_tol."""
    import time

    t0 = time.perf_counter()
    pb = Problem(obs, state, gauge_cam, gauge_board, fix_intrinsics)
    r0 = (obs.sqrt_weights() * pb.residuals(pb.x0())).reshape(-1, 2)  # whitened, as LM sees them
    # Cauchy scale: generous at first so a rough start is not mistaken for outliers.
    scale = max(3.0 * np.median(np.linalg.norm(r0, axis=1)), 1.0)
    x, nit, conv = levenberg_marquardt(pb, scale=scale, chi2_tol=10.0)
    return RobustPass(pb.state(x), nit, conv, time.perf_counter() - t0)


def provisional_result(obs: Observations, robust: RobustPass, gauge_cam: int, gauge_board: int,
                       fix_intrinsics: np.ndarray | None = None, reject_sigma: float = 5.0) -> SolveResult:
    """The robust pass read as a solve without its least-squares rounds: the corners within
    reject_sigma robust sigmas of it (judged once) are the inliers, the residuals theirs at
    the robust state. For a verdict that does not need the converged solution (the
    rigidity test of a rig that will be solved again), at the cost of the rounds."""
    inliers = judge_inliers(obs, robust.state, np.ones(len(obs), bool), gauge_cam, gauge_board, fix_intrinsics,
                            reject_sigma)
    return _result(obs, robust.state, inliers, gauge_cam, gauge_board, fix_intrinsics, robust.n_iterations,
                   robust.seconds, robust.converged, [("robust", robust.n_iterations)])


def _result(obs: Observations, cur: State, inliers: np.ndarray, gauge_cam: int, gauge_board: int,
            fix_intrinsics: np.ndarray | None, nit: int, seconds: float, conv: bool, history: list) -> SolveResult:
    final = Problem(obs.subset(inliers), cur, gauge_cam, gauge_board, fix_intrinsics)
    r = final.residuals(final.x0()).reshape(-1, 2)
    dof = max(r.size - final.layout.size, 1)
    sigma_px = float(np.sqrt(np.sum(r**2) / dof))
    # the weighted problem's variance of unit weight (px^2 for a corner of weight 1)
    vf = None if obs.weight is None else float(np.sum((final.obs.sqrt_weights() * r.ravel()) ** 2) / dof)
    return SolveResult(cur, final, inliers, r, sigma_px, nit, seconds, conv, history, vf)


def bundle_adjust(obs: Observations, state: State, gauge_cam: int, gauge_board: int,
                  fix_intrinsics: np.ndarray | None = None, reject_sigma: float = 5.0,
                  max_rounds: int = 5, inliers: np.ndarray | None = None) -> SolveResult:
    """Robust solve (Cauchy, robust_pass), then drop corners beyond `reject_sigma` robust
    sigmas and re-solve with plain least squares on the inliers until the inlier set is
    stable.

    inliers: (M,) bool from an earlier solve of nearly this problem (the same corners,
    a state close to its solution): the robust pass is skipped and rejection starts
    from that set."""
    import time

    t0 = time.perf_counter()
    history = []
    conv = True
    if inliers is None:
        robust = robust_pass(obs, state, gauge_cam, gauge_board, fix_intrinsics)
        cur, nit, conv = robust.state, robust.n_iterations, robust.converged
        history.append(("robust", nit))
        inliers = np.ones(len(obs), bool)
    else:
        # solve on the given set first: rejecting at the start state would judge corners
        # by a model not yet re-fitted (k3 just removed bends the image border)
        inliers = np.asarray(inliers, bool).copy()
        pb = Problem(obs.subset(inliers), state, gauge_cam, gauge_board, fix_intrinsics)
        x, nit, conv = levenberg_marquardt(pb, scale=None, lam0=LS_LAM0)
        cur = pb.state(x)
        history.append(("warm", nit, int(inliers.sum())))
    ls_solved = len(history) > 0 and history[0][0] == "warm"  # cur is the LS solution on `inliers`
    for _ in range(max_rounds):
        new_inliers = judge_inliers(obs, cur, inliers, gauge_cam, gauge_board, fix_intrinsics, reject_sigma)
        n_changed = int(np.sum(new_inliers != inliers))
        # A handful of corners hovering at the threshold (1 in 1000) does not move the
        # solution: keep the least-squares solution already in hand.
        if ls_solved and n_changed <= max(5, int(1e-3 * len(obs))):
            break
        pb = Problem(obs.subset(new_inliers), cur, gauge_cam, gauge_board, fix_intrinsics)
        x, k, conv = levenberg_marquardt(pb, scale=None, lam0=LS_LAM0)
        nit += k
        cur = pb.state(x)
        inliers, ls_solved = new_inliers, True
        history.append(("inliers", k, int(inliers.sum())))
    return _result(obs, cur, inliers, gauge_cam, gauge_board, fix_intrinsics, nit, time.perf_counter() - t0, conv,
                   history)


# ----------------------------------------------------------------------------- covariance


def camera_covariance(result: SolveResult) -> tuple[np.ndarray, list, list]:
    """Covariance of the camera and board parameters with the frames marginalised:
    cov = sigma^2 S^-1, S the Schur complement of the frame block of J^T J (no dense
    inverse of the whole problem); for a weighted solve J^T W J and its variance factor.
    Returns (cov, intr_slices, cam_slices) indexing cov."""
    pb = result.problem
    x = pb.x0()
    weighted = result.variance_factor is not None and pb.obs.weight is not None
    w = pb.obs.sqrt_weights() ** 2 if weighted else np.ones(2 * len(pb.obs))
    _, S = pb.normal_equations(x, np.zeros(2 * len(pb.obs)), w).solve(0.0)
    cov = (result.variance_factor if weighted else result.sigma_px**2) * np.linalg.inv(S)
    return cov, list(pb.layout.intr), list(pb.layout.cam)


def intrinsics_covariance(cov: np.ndarray, intr_slices: list, intrinsics: list[Intrinsics]) -> list:
    """Per camera the (n_values, n_values) covariance of [fx, fy, cx, cy, dist...], E C E^T
    from the covariance of its estimated parameters (camera_covariance): a tied fy has fx's
    variance and full correlation, a held cx, cy zero variance. None for fixed cameras."""
    out = []
    for s, it in zip(intr_slices, intrinsics):
        if s is None:
            out.append(None)
            continue
        E = it.basis()
        out.append(E @ cov[s, s] @ E.T)
    return out
