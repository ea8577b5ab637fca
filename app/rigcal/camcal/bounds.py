"""The noise limit: Cramér-Rao bounds of the relative camera poses (bench).

The Fisher information of the rig bundle adjustment evaluated at the TRUE state, for
the corners the calibration actually used and the measured corner noise sigma:
cov = sigma^2 (J^T J)^-1 (frames marginalised by their Schur complement). The bound on
a camera pair's relative pose is that covariance pushed through the relative pose;
it does not depend on the gauge (relative poses are gauge-invariant)."""

from __future__ import annotations

import numpy as np

from rigcal.core import geometry as geo
from rigcal.camcal.solve import Intrinsics, Problem, SolveResult, State, camera_covariance


def true_state(cal, truth) -> State | None:
    """The truth expressed in the solver's unknowns, for the calibration's frames and boards.

    A moving board (per-frame board poses) is folded into the frame pose, as the solver
    does: world = board frame, T_body_world(f) = inv(T_world_body) T_world_board(f)."""
    rig = truth.rig
    intr = []
    for n, it in zip(cal.cam_names, cal.state.intrinsics):
        m = rig.camera(n).intrinsics
        vals = np.concatenate([[m.fx, m.fy, m.cx, m.cy], m.dist])
        intr.append(Intrinsics(it.model, vals))
    T_cam_body = np.array([geo.inv_T(rig.camera(n).T_body_cam) for n in cal.cam_names])
    moving = bool(truth.frame_boards)
    if moving and len(cal.boards) != 1:
        return None
    T_body_world, T_world_board = [], []
    for stem in cal.frames:
        if stem not in truth.T_world_body:
            return None
        T_world_body = truth.T_world_body[stem]
        if moving:
            T_world_board_f = truth.board_pose(stem, cal.boards[0])  # the board moves: it is the world
            T_body_world.append(geo.inv_T(T_world_body) @ T_world_board_f)
        else:
            T_body_world.append(geo.inv_T(T_world_body))
    if moving:
        T_world_board = [np.eye(4)]
    else:
        T_world_board = [truth.T_world_board[b] for b in cal.boards]
    return State(intr, T_cam_body, np.array(T_body_world), np.array(T_world_board))


def pair_bounds(cal, truth, sigma_px: float) -> dict[tuple[str, str], dict]:
    """{(a, b): {rot_deg, trans_mm}}: the RMS error the noise alone allows for each camera
    pair's relative rotation (angle) and translation (vector norm)."""
    st = true_state(cal, truth)
    if st is None:
        return {}
    obs = cal.obs.subset(cal.inliers)
    gauge_cam = cal.problem.gauge_cam
    pb = Problem(obs, st, gauge_cam, cal.problem.gauge_board, cal.problem.fix_intr)
    res = SolveResult(st, pb, np.ones(len(obs), bool), np.zeros((len(obs), 2)), sigma_px, 0, 0.0)
    cov, _, cam_sl = camera_covariance(res)
    C = len(cal.cam_names)
    free = [c for c in range(C) if cam_sl[c] is not None]
    idx = np.concatenate([np.arange(cam_sl[c].start, cam_sl[c].stop) for c in free])
    Ce = cov[np.ix_(idx, idx)]
    out = {}
    for i in range(C):
        for j in range(i + 1, C):
            G = relative_pose_jacobian(st.T_cam_body, i, j, free)
            S = G @ Ce @ G.T
            out[(cal.cam_names[i], cal.cam_names[j])] = {
                "rot_deg": float(np.degrees(np.sqrt(np.trace(S[:3, :3])))),
                "trans_mm": float(1000 * np.sqrt(np.trace(S[3:, 3:]))),
            }
    return out


def relative_pose_jacobian(T_cam_body: np.ndarray, i: int, j: int, free: list[int]) -> np.ndarray:
    """d [rotation error (rad), translation (m)] of T_i_j = T_cam_body_i inv(T_cam_body_j)
    with respect to each free camera's [delta, t] (central differences)."""
    def rel(T):
        return T[i] @ geo.inv_T(T[j])

    R0 = rel(T_cam_body)
    G = np.zeros((6, 6 * len(free)))
    h = 1e-7
    for a, c in enumerate(free):
        for k in range(6):
            Ts = []
            for s in (1.0, -1.0):
                T = T_cam_body.copy()
                if k < 3:
                    d = np.zeros(3)
                    d[k] = s * h
                    T[c, :3, :3] = geo.R_from_rotvec(d) @ T[c, :3, :3]
                else:
                    T[c, :3, 3] = T_cam_body[c, :3, 3] + s * h * np.eye(3)[k - 3]
                Ts.append(rel(T))
            e = [np.concatenate([geo.rotvec_from_R(Tx[:3, :3] @ R0[:3, :3].T), Tx[:3, 3]]) for Tx in Ts]
            G[:, 6 * a + k] = (e[0] - e[1]) / (2 * h)
    return G


def measured_corner_noise(cal, truth) -> float | None:
    """1-sigma per coordinate of detected corners against their true projections."""
    st = true_state(cal, truth)
    if st is None:
        return None
    obs = cal.obs.subset(cal.inliers)
    pb = Problem(obs, st, cal.problem.gauge_cam, cal.problem.gauge_board)
    r = pb.residuals(pb.x0())
    return float(np.sqrt(np.mean(r**2)))
