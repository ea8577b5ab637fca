"""rigcal's hand-written bundle adjustment against gtsam's factor graph on the same problem.

The question, before more solver code is written (camera-IMU terms, time offsets,
rolling shutter), what a maintained library would give. Both solvers get the same rig
problem, the same observations and the same start, and solve plain least squares:

    p_cam = T_cam_body @ T_body_world(frame) @ T_world_board(board) @ p_board
    uv    = pinhole + radtan4 (OpenCV's k1 k2 p1 p2; gtsam's Cal3DS2 with skew held at 0)

The rig (shared extrinsics per camera) is not a factor gtsam ships for Python, so the
gtsam side is one `gtsam.CustomFactor` per board view (all its corners, Jacobians
vectorised in numpy, gtsam's right-multiplied pose retraction); gtsam does the graph,
the ordering, the sparse Cholesky and Levenberg-Marquardt. Gauge: camera 0 and board 0
are constants on both sides. The scene is rigcal.sim.synthetic's room (drone-stereo-back,
four wall boards, 0.3 px noise): what the two solvers find must agree to far below the
noise-limited error, which makes this a cross-check of rigcal's solver as well.

    python -m bench.solver_libraries [--frames 100 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

import rigcal
from rigcal.core import geometry as geo
from rigcal.camcal.solve import LS_LAM0, Intrinsics, Observations, Problem, State, levenberg_marquardt, projection_jacobians
from rigcal.sim.synthetic import room_scene, with_noise

from .common import RIGS, md_table, perturbed_truth, say

SIGMA_PX = 0.3
FRAMES = (100, 300)


# ----------------------------------------------------------------------------- the shared problem


def problem(frames: int, seed: int) -> tuple[Observations, State, State]:
    """(observations, true state, start state) of a room scene of `frames` frames."""
    rng = np.random.default_rng([seed, frames])
    rig = perturbed_truth(rigcal.load_rig(RIGS / "drone-stereo-back.yaml"), seed)
    cams = [replace(c, intrinsics=c.intrinsics.with_values(
        [c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy,
         *rng.normal(0, [0.05, 0.02, 0.001, 0.001])])) for c in rig.cameras]
    rig = rig.with_cameras(cams)
    sc = room_scene(rig, rng, frames)
    views = with_noise(sc.views, SIGMA_PX, rng)
    cam_ix = {c.name: i for i, c in enumerate(rig.cameras)}
    frame_names = sorted(sc.T_world_body)
    frame_ix = {f: i for i, f in enumerate(frame_names)}
    board_names = sorted(sc.T_world_board)
    board_ix = {b: i for i, b in enumerate(board_names)}
    rows = [(cam_ix[v.camera], frame_ix[v.frame], board_ix[v.board], k) for k, v in enumerate(views) for _ in v.ids]
    cam, frame, board, view = (np.array(x) for x in zip(*rows))
    obs = Observations(cam, frame, board, np.concatenate([sc.corners[v.board][v.ids] for v in views]),
                       np.concatenate([v.uv for v in views]), view)
    truth = State([Intrinsics("pinhole", np.array([c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx,
                                                   c.intrinsics.cy, *c.intrinsics.dist])) for c in cams],
                  np.array([geo.inv_T(c.T_body_cam) for c in cams]),
                  np.array([geo.inv_T(sc.T_world_body[f]) for f in frame_names]),
                  np.array([sc.T_world_board[b] for b in board_names]))
    start = truth.copy()
    for it in start.intrinsics:
        it.values[:2] *= 1 + rng.normal(0, 0.01, 2)
        it.values[2:4] += rng.normal(0, 2.0, 2)
        it.values[4:] = 0.0
    for T_group, first in ((start.T_cam_body, 1), (start.T_body_world, 0), (start.T_world_board, 1)):
        for T in T_group[first:]:  # the gauge camera and board stay at the truth
            T[:] = geo.make_T(geo.R_from_rotvec(rng.normal(0, np.radians(0.5), 3)), rng.normal(0, 0.005, 3)) @ T
    return obs, truth, start


def errors(state: State, truth: State) -> dict:
    """Worst camera-pair rotation (deg) and translation (mm) error, worst focal error (%)."""
    rot, trans = [], []
    C = len(state.intrinsics)
    for i in range(C):
        for j in range(i + 1, C):
            rel = lambda s: s.T_cam_body[i] @ geo.inv_T(s.T_cam_body[j])  # noqa: E731
            d = rel(state) @ geo.inv_T(rel(truth))
            rot.append(np.degrees(geo.rotation_angles(d[None, :3, :3])[0]))
            trans.append(1000 * np.linalg.norm(d[:3, 3]))
    focal = [100 * abs(s.values[0] / t.values[0] - 1) for s, t in zip(state.intrinsics, truth.intrinsics)]
    return {"rot_deg": max(rot), "trans_mm": max(trans), "focal_pct": max(focal)}


def max_difference(a: State, b: State) -> dict:
    """How far two solutions are apart: camera poses (deg, mm) and intrinsics (px)."""
    d = a.T_cam_body @ np.array([geo.inv_T(T) for T in b.T_cam_body])
    return {"rot_deg": float(np.degrees(geo.rotation_angles(d[:, :3, :3]).max())),
            "trans_mm": float(1000 * np.linalg.norm(d[:, :3, 3], axis=1).max()),
            "intr_px": float(max(np.abs(x.values[:4] - y.values[:4]).max() for x, y in zip(a.intrinsics, b.intrinsics)))}


# ----------------------------------------------------------------------------- the two solvers


def solve_rigcal(obs: Observations, start: State) -> tuple[State, float, int]:
    t0 = time.perf_counter()
    pb = Problem(obs, start, 0, 0)
    x, iterations, _ = levenberg_marquardt(pb, scale=None, lam0=LS_LAM0)
    return pb.state(x), time.perf_counter() - t0, iterations


def _view_factor(gtsam, keys: dict, noise, p_board: np.ndarray, uv: np.ndarray, consts: dict):
    """One CustomFactor for a board view: residual (2N,) = projection - uv, Jacobians with
    respect to whichever of E (T_body_cam), X (T_world_body), B (T_world_board), K (Cal3DS2)
    are variables (the gauge camera's E and board's B are constants)."""
    names = [n for n in ("E", "X", "B", "K") if n in keys]

    def error(this, values, H):
        get = {"E": values.atPose3, "X": values.atPose3, "B": values.atPose3, "K": values.atCal3DS2}
        m = {n: (get[n](keys[n]) if n in keys else consts[n]) for n in ("E", "X", "B", "K")}
        T_world_board, T_world_body, T_body_cam = m["B"].matrix(), m["X"].matrix(), m["E"].matrix()
        p_world = geo.transform(T_world_board, p_board)
        p_body = geo.transform(geo.inv_T(T_world_body), p_world)
        p_cam = geo.transform(geo.inv_T(T_body_cam), p_body)
        k = m["K"].vector()  # fx fy s u0 v0 k1 k2 p1 p2
        v = np.array([k[0], k[1], k[3], k[4], *k[5:]])
        J_p, (J_i,) = projection_jacobians(p_cam, np.zeros(len(p_cam), int), [v], ["pinhole"])
        from rigcal.camcal.solve import project_obs
        r = (project_obs(p_cam, np.zeros(len(p_cam), int), [v], ["pinhole"]) - uv).ravel()
        if H is not None:
            R_cam_body = T_body_cam[:3, :3].T
            R_cam_board = R_cam_body @ T_world_body[:3, :3].T @ T_world_board[:3, :3]
            eye = np.broadcast_to(np.eye(3), (len(p_cam), 3, 3))
            d_pcam = {
                "E": np.concatenate([geo.skew(p_cam), -eye], axis=2),
                "X": R_cam_body @ np.concatenate([geo.skew(p_body), -eye], axis=2),
                "B": R_cam_board @ np.concatenate([-geo.skew(p_board), eye], axis=2),
            }
            for i, n in enumerate(names):
                if n == "K":
                    JK = np.zeros((len(p_cam), 2, 9))
                    JK[:, :, [0, 1, 3, 4, 5, 6, 7, 8]] = J_i  # skew held at 0: no column
                    H[i] = JK.reshape(-1, 9)
                else:
                    H[i] = (J_p @ d_pcam[n]).reshape(-1, 6)
        return r

    return gtsam.CustomFactor(noise, [keys[n] for n in names], error)


def solve_gtsam(obs: Observations, start: State) -> tuple[State, float, int]:
    import gtsam

    t0 = time.perf_counter()
    C, F, B = len(start.intrinsics), len(start.T_body_world), len(start.T_world_board)
    key = {"E": lambda i: gtsam.symbol("e", i), "X": lambda i: gtsam.symbol("x", i),
           "B": lambda i: gtsam.symbol("b", i), "K": lambda i: gtsam.symbol("k", i)}
    values = gtsam.Values()
    for c in range(1, C):
        values.insert(key["E"](c), gtsam.Pose3(geo.inv_T(start.T_cam_body[c])))
    for c in range(C):
        v = start.intrinsics[c].values
        values.insert(key["K"](c), gtsam.Cal3DS2(v[0], v[1], 0.0, v[2], v[3], *v[4:8]))
    for f in range(F):
        values.insert(key["X"](f), gtsam.Pose3(geo.inv_T(start.T_body_world[f])))
    for b in range(1, B):
        values.insert(key["B"](b), gtsam.Pose3(start.T_world_board[b]))
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(2)  # per view: replaced below by the view's size
    bounds = np.flatnonzero(np.diff(obs.view)) + 1
    for rows in np.split(np.arange(len(obs)), bounds):
        c, f, b = int(obs.cam[rows[0]]), int(obs.frame[rows[0]]), int(obs.board[rows[0]])
        keys = {"X": key["X"](f), "K": key["K"](c)}
        consts = {}
        if c == 0:
            consts["E"] = gtsam.Pose3(geo.inv_T(start.T_cam_body[0]))
        else:
            keys["E"] = key["E"](c)
        if b == 0:
            consts["B"] = gtsam.Pose3(start.T_world_board[0])
        else:
            keys["B"] = key["B"](b)
        noise = gtsam.noiseModel.Unit.Create(2 * len(rows))
        graph.add(_view_factor(gtsam, keys, noise, obs.p_board[rows], obs.uv[rows], consts))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-8)
    params.setMaxIterations(100)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    out = start.copy()
    for c in range(C):
        if c:
            out.T_cam_body[c] = geo.inv_T(result.atPose3(key["E"](c)).matrix())
        k = result.atCal3DS2(key["K"](c)).vector()
        out.intrinsics[c] = Intrinsics("pinhole", np.array([k[0], k[1], k[3], k[4], *k[5:]]))
    for f in range(F):
        out.T_body_world[f] = geo.inv_T(result.atPose3(key["X"](f)).matrix())
    for b in range(1, B):
        out.T_world_board[b] = result.atPose3(key["B"](b)).matrix()
    return out, time.perf_counter() - t0, opt.iterations()


# ----------------------------------------------------------------------------- the section


def run(frames=FRAMES, seed: int = 0, log=say) -> list[dict]:
    out = []
    for n in frames:
        obs, truth, start = problem(n, seed)
        log(f"solver_libraries: {n} frames, {len(obs)} corners ...")
        mine, t_mine, it_mine = solve_rigcal(obs, start)
        theirs, t_theirs, it_theirs = solve_gtsam(obs, start)
        out.append({"frames": n, "corners": len(obs), "rigcal_s": t_mine, "rigcal_iterations": it_mine,
                    "gtsam_s": t_theirs, "gtsam_iterations": it_theirs, "rigcal_err": errors(mine, truth),
                    "gtsam_err": errors(theirs, truth), "apart": max_difference(mine, theirs)})
    return out


def tables(res: list[dict]) -> str:
    rows = []
    for r in res:
        for name in ("rigcal", "gtsam"):
            e = r[f"{name}_err"]
            rows.append([r["frames"], r["corners"], name, r[f"{name}_s"], r[f"{name}_iterations"], e["rot_deg"],
                         e["trans_mm"], e["focal_pct"]])
    apart = [[r["frames"], r["apart"]["rot_deg"], r["apart"]["trans_mm"], r["apart"]["intr_px"]] for r in res]
    return (md_table(["frames", "corners", "solver", "solve s", "iterations", "pair rot err deg", "pair trans err mm",
                      "focal err %"], rows, "rigcal LM vs gtsam LM, same problem and start (3 cameras, 0.3 px)")
            + "\n" + md_table(["frames", "rot deg", "trans mm", "fx fy cx cy px"], apart,
                              "the two solutions apart (must be far below the errors above)"))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=list(FRAMES))
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(tables(run(a.frames, a.seed)))


if __name__ == "__main__":
    main()
