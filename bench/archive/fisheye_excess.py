"""Which part of the detected corner error drives the fisheye pair's relative-rotation error?

The DETECTOR's corners (`--guided off`), as bench.indie_noise: the study that led to the
guided pass (rigcal.detect.guided), which bench.noise_limit and bench.archive.guided measure.

    BENCH_REUSE_CACHE=1 python -m bench.archive.fisheye_excess [--seeds 10] [--scenario fisheye-stereo]

Per seed (bench.common's render + detect cache, bench.noise_limit's frame count) the
detected corners' error e = detected - true projection is split into parts, and the same
bundle adjustment (rigcal.camcal.pipeline.calibrate_views) runs on true projections + each part:

- full: e itself (must reproduce the detected calibration)
- radial / tangential: e's component along / across the ray from the principal point
- radial trend: per camera, the mean radial error in radius bins (a smooth radial bias)
- view mean: each view's mean error; view resid: e minus it
- view affine: per view, the affine function of the true pixel position that fits e best
  (offset, scale, shear, rotation of the view's corners); affine resid: e minus it
- shuffled: e permuted among the corners of each camera (same values, no structure)
- shuffled in class / hetero white: e permuted, or Gaussian noise of the class's RMS,
  within classes of camera x grid neighbours detected x 50 px radius band
- tails -> white: corners beyond 3 sigma replaced by white noise
- white: Gaussian noise of the measured sigma (bench.noise_limit's reference)

Then the linear influence (one Gauss-Newton step at the true state) splits the detected
error into per-corner contributions to the rotation error; summing them with random
signs per corner, per view and per camera gives what independent corners (or views, or
cameras) with these very errors would produce: how far the observed ratio is beyond it.

A pixel-phase regression (pixel locking) of the detected error closes the output.

The relative rotation error of the pair is a vector (left camera frame, deg); errors
are nearly linear in e, so the parts of a split add up to 'full'. The table gives the RMS
angle over seeds and its ratio to the RMS Cramér-Rao bound, and per axis the RMS error
against the bound's own per-axis sigma.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from rigcal.core import geometry as geo
from rigcal.camcal.bounds import relative_pose_jacobian, measured_corner_noise, true_state
from rigcal.core.target import load_target
from rigcal.camcal.solve import Problem, SolveResult, camera_covariance

from bench.common import (calibrate, gaussian_views, get_dataset, md_table, run_pool, say, scenario, true_projections,
                     write_json)
from bench.noise_limit import FRAMES


def rel_rot_error(cal, truth_rig) -> np.ndarray:
    """(3,) rotation error (deg) of the pair T_left_right, rotvec(R_est R_true^T), as
    rigcal.camcal.bounds measures it (left camera frame)."""
    a, b = cal.cam_names[:2]
    rel = lambda r: geo.inv_T(r.camera(a).T_body_cam) @ r.camera(b).T_body_cam  # noqa: E731
    Ra, Rb = rel(cal.rig)[:3, :3], rel(truth_rig)[:3, :3]
    return np.degrees(geo.rotvec_from_R(Ra @ Rb.T))


def rot_bound_cov(cal, truth, sigma: float) -> np.ndarray:
    """(3, 3) Cramér-Rao covariance (deg^2) of the pair's rotation error vector."""
    st = true_state(cal, truth)
    obs = cal.obs.subset(cal.inliers)
    pb = Problem(obs, st, cal.problem.gauge_cam, cal.problem.gauge_board, cal.problem.fix_intr)
    res = SolveResult(st, pb, np.ones(len(obs), bool), np.zeros((len(obs), 2)), sigma, 0, 0.0)
    cov, _, cam_sl = camera_covariance(res)
    free = [c for c in range(len(cal.cam_names)) if cam_sl[c] is not None]
    idx = np.concatenate([np.arange(cam_sl[c].start, cam_sl[c].stop) for c in free])
    G = relative_pose_jacobian(st.T_cam_body, 0, 1, free)
    S = G @ cov[np.ix_(idx, idx)] @ G.T
    return np.degrees(np.degrees(S[:3, :3]))


def per_group_mean(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(M, k) mean of x (M, k) over each row's group g (M,), broadcast back."""
    n = np.bincount(g)
    m = np.stack([np.bincount(g, x[:, i], minlength=len(n)) / np.maximum(n, 1) for i in range(x.shape[1])], 1)
    return m[g]


def view_affine(e: np.ndarray, uv: np.ndarray, view: np.ndarray) -> np.ndarray:
    """(M, 2) per view least-squares affine fit of e on the (centred) true pixel positions."""
    out = np.zeros_like(e)
    for v in np.unique(view):
        k = view == v
        x = uv[k] - uv[k].mean(0)
        A = np.column_stack([np.ones(k.sum()), x / 100.0])
        coef, *_ = np.linalg.lstsq(A, e[k], rcond=None)
        out[k] = A @ coef
    return out


def neighbour_count(cal, boards: dict) -> np.ndarray:
    """(M,) how many of each corner's 4 grid neighbours are in its view."""
    o = cal.obs
    out = np.zeros(len(o), int)
    for v in np.unique(o.view):
        m = np.nonzero(o.view == v)[0]
        b = boards[cal.boards[int(o.board[m[0]])]]
        ids = np.argmin(np.linalg.norm(b.corners[None] - o.p_board[m][:, None], axis=2), 1)
        nx = b.inner_corners[0]
        col = ids % nx
        have = np.zeros(len(b.corners) + 2 * nx + 2, bool)
        have[ids + nx + 1] = True
        out[m] = (have[ids + nx + 2] & (col < nx - 1)).astype(int) + (have[ids + nx] & (col > 0)) \
            + have[ids + 2 * nx + 1] + have[ids + 1]
    return out


def parts(cal, truth, truth_boards, uv_true: np.ndarray, sigma: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """{name: (M, 2) error to add to the true projections}."""
    o = cal.obs
    e = o.uv - uv_true
    c = np.array([[truth.rig.camera(n).intrinsics.cx, truth.rig.camera(n).intrinsics.cy] for n in cal.cam_names])
    d = uv_true - c[o.cam]
    rad = np.linalg.norm(d, axis=1)
    rhat = d / np.maximum(rad, 1e-9)[:, None]
    er = np.sum(e * rhat, 1)
    radial = er[:, None] * rhat
    # radial trend: mean radial error per camera and 25 px radius bin
    g = o.cam * 100 + np.minimum(rad // 25, 99).astype(int)
    _, gi = np.unique(g, return_inverse=True)
    trend = per_group_mean(er[:, None], gi)[:, 0][:, None] * rhat
    vmean = per_group_mean(e, o.view)
    vaff = view_affine(e, uv_true, o.view)
    shuf = e.copy()
    for ci in np.unique(o.cam):
        k = np.nonzero(o.cam == ci)[0]
        shuf[k] = e[rng.permutation(k)]
    # corners' classes: 4-neighbours detected (the grid's edge), radius band
    nn = neighbour_count(cal, truth_boards)
    cls = (o.cam * 10 + nn) * 100 + np.minimum(rad // 50, 99).astype(int)
    _, ci_ = np.unique(cls, return_inverse=True)
    inl = cal.inliers
    rms_cls = np.sqrt(np.bincount(ci_, np.where(inl, np.sum(e**2, 1) / 2, 0), minlength=ci_.max() + 1)
              / np.maximum(np.bincount(ci_, inl, minlength=ci_.max() + 1), 1))[ci_]
    hetero = np.where(inl[:, None], rng.normal(0.0, 1.0, e.shape) * rms_cls[:, None], e)
    shuf_cls = e.copy()
    for g_ in np.unique(ci_):
        k = np.nonzero(ci_ == g_)[0]
        shuf_cls[k] = e[rng.permutation(k)]
    # the tails replaced by white noise (parts that leave most corners exact would make
    # the solver's robust scale collapse and reject the rest, so none is run alone)
    tail = (np.abs(e).max(1) / sigma > 3) & inl
    core = np.where(tail[:, None], rng.normal(0.0, sigma, e.shape), e)
    extra = {"hetero white": hetero, "shuffled in class": shuf_cls, "tails -> white": core}
    return {**extra, "full": e, "radial": radial, "tangential": e - radial, "radial trend": trend,
            "radial - trend": radial - trend, "view mean": vmean, "view resid": e - vmean, "view affine": vaff,
            "affine resid": e - vaff, "shuffled": shuf, "white": rng.normal(0.0, sigma, e.shape)}


PHASE_TERMS = ("sin u", "cos u", "sin v", "cos v", "sin 2u", "cos 2u", "sin 2v", "cos 2v")


def phase_design(uv: np.ndarray) -> np.ndarray:
    """(M, 9) a constant and the first two harmonics of each pixel coordinate's fractional
    part (pixel locking: a bias that repeats with the pixel grid)."""
    a, b = 2 * np.pi * (uv[:, 0] % 1.0), 2 * np.pi * (uv[:, 1] % 1.0)
    return np.column_stack([np.ones(len(uv)), np.sin(a), np.cos(a), np.sin(b), np.cos(b),
                            np.sin(2 * a), np.cos(2 * a), np.sin(2 * b), np.cos(2 * b)])


def phase_regression(e: np.ndarray, uv_true: np.ndarray) -> dict:
    """Least-squares fit of each error component on phase_design (corners beyond 5 robust
    sigma left out): {"u"|"v": (coefficients (8,), standard errors (8,), R^2)}, px."""
    X = phase_design(uv_true)
    out = {}
    for j, comp in enumerate("uv"):
        y = e[:, j]
        keep = np.abs(y - np.median(y)) < 5 * 1.4826 * np.median(np.abs(y - np.median(y)))
        coef, *_ = np.linalg.lstsq(X[keep], y[keep], rcond=None)
        res = y[keep] - X[keep] @ coef
        s2 = res @ res / max(keep.sum() - X.shape[1], 1)
        se = np.sqrt(np.diag(s2 * np.linalg.inv(X[keep].T @ X[keep])))
        out[comp] = (coef[1:], se[1:], float(1 - res.var() / y[keep].var()))
    return out


def influence(cal, truth, weighted: bool = True) -> np.ndarray:
    """(3, 2M') d(pair rotation error, deg) / d(inlier corner pixels): one Gauss-Newton
    step of the bundle adjustment at the true state (the calibration's inliers, weighted
    by the detector's per-corner sigma as the solve was)."""
    st = true_state(cal, truth)
    pb = Problem(cal.obs.subset(cal.inliers), st, cal.problem.gauge_cam, cal.problem.gauge_board,
                 cal.problem.fix_intr)
    w = pb.obs.sqrt_weights()[:, None] if weighted else np.ones((2 * len(pb.obs), 1))
    J = w * pb.jacobian(pb.x0()).toarray()
    free = [c for c in range(len(cal.cam_names)) if pb.layout.cam[c] is not None]
    G = relative_pose_jacobian(st.T_cam_body, 0, 1, free)[:3]
    return np.degrees(G @ np.linalg.solve(J.T @ J, (w * J).T)[pb.layout.cam[free[0]]])


def flip_null(runs: list[dict], draws: int = 4000, seed: int = 0) -> str:
    """Is the detected error more than independent corner errors of their own sizes?
    Per-corner contributions c_i = K_i e_i to the rotation error, summed with random signs
    per corner / per view / per camera (each keeps the correlations inside its unit): the
    RMS ratio's null distribution over the seeds against the observed one."""
    rng = np.random.default_rng(seed)
    obs, crb = 0.0, 0.0
    null = {"corner": np.zeros(draws), "view": np.zeros(draws), "camera": np.zeros(draws)}
    for r in runs:
        C, crb_r = np.array(r["contrib"]), r["crb_trace"]
        obs += np.sum(C.sum(0) ** 2)
        crb += crb_r
        for unit, g in (("corner", np.arange(len(C))), ("view", np.array(r["contrib_view"])),
                        ("camera", np.array(r["contrib_cam"]))):
            _, gi = np.unique(g, return_inverse=True)
            S = np.stack([np.bincount(gi, C[:, k]) for k in range(3)], 1)
            F = rng.choice([-1.0, 1.0], size=(draws, len(S)))
            null[unit] += np.sum((F @ S) ** 2, 1)
    lines = [f"linear influence: observed ratio {np.sqrt(obs / crb):.2f}; random signs per"]
    for unit, x in null.items():
        q = np.sqrt(x / crb)
        lines.append(f"  {unit}: median ratio {np.median(q):.2f}, 95th percentile {np.percentile(q, 95):.2f}, "
                     f"P(>= observed) {np.mean(x >= obs):.3f}")
    return "\n".join(lines)


def run_seed(name: str, frames: int, seed: int) -> dict:
    ds = get_dataset(scenario(name).with_frames(frames), seed, jobs=1)
    cal = calibrate(ds.views, ds.rig, ds.corners)
    sigma = measured_corner_noise(cal, ds.truth)
    uv_true = true_projections(cal, ds.truth)
    out = {"seed": seed, "sigma": sigma, "detected": rel_rot_error(cal, ds.truth.rig).tolist(),
           "bound_cov": rot_bound_cov(cal, ds.truth, sigma).tolist()}
    K = influence(cal, ds.truth)
    e_in = (cal.obs.uv - uv_true)[cal.inliers]
    out["contrib"] = np.einsum("kmj,mj->mk", K.reshape(3, -1, 2), e_in).tolist()
    out["contrib_view"] = cal.obs.view[cal.inliers].tolist()
    out["contrib_cam"] = cal.obs.cam[cal.inliers].tolist()
    K0 = influence(cal, ds.truth, weighted=False)  # the bound: one sigma, unweighted (rigcal.camcal.bounds)
    out["crb_trace"] = float(sigma**2 * np.trace(K0 @ K0.T))
    out["phase_e"] = (cal.obs.uv - uv_true).tolist()
    out["phase_uv"] = uv_true.tolist()
    out["phase_cam"] = cal.obs.cam.tolist()
    rng = np.random.default_rng([seed, 11])
    boards = {b.name: b for b in load_target(ds.path / "target.yaml").boards}
    for k, p in parts(cal, ds.truth, boards, uv_true, sigma, rng).items():
        c = calibrate(gaussian_views(cal, uv_true + p, ds.corners, 0.0, rng), ds.rig, ds.corners)
        out[k] = rel_rot_error(c, ds.truth.rig).tolist()
        out[k + " rms px"] = float(np.sqrt(np.mean(p**2)))
    return out


def summary(runs: list[dict]) -> str:
    B = np.array([r["bound_cov"] for r in runs])
    b_rms = np.sqrt(np.mean(np.trace(B, axis1=1, axis2=2)))
    b_ax = np.sqrt(np.mean(np.diagonal(B, axis1=1, axis2=2), 0))
    skip = ("seed", "sigma", "bound_cov", "contrib", "contrib_view", "contrib_cam", "crb_trace", "phase_e", "phase_uv",
            "phase_cam")
    keys = [k for k in runs[0] if k not in skip and not k.endswith(" rms px")]
    rows = []
    for k in keys:
        E = np.array([r[k] for r in runs])
        rms = np.sqrt(np.mean(np.sum(E**2, 1)))
        ax = np.sqrt(np.mean(E**2, 0))
        px = np.sqrt(np.mean([r[k + " rms px"] ** 2 for r in runs])) if k + " rms px" in runs[0] else None
        rows.append([k, px, rms, rms / b_rms, *(ax / b_ax)])
    return md_table(["corner error", "RMS px", "rot RMS deg", "ratio to CRB", "ratio x", "ratio y", "ratio z"], rows,
                    f"fisheye pair rotation error from parts of the corner error ({len(runs)} seeds; CRB RMS "
                    f"{b_rms:.5f} deg, per axis {np.array2string(b_ax, precision=5)})")


def phase_table(runs: list[dict]) -> str:
    """Pixel locking per camera over all seeds (phase_regression), milli-pixels."""
    e, uv, cam = (np.concatenate([np.array(r[k]) for r in runs]) for k in ("phase_e", "phase_uv", "phase_cam"))
    rows = []
    for c in np.unique(cam):
        for comp, (coef, se, r2) in phase_regression(e[cam == c], uv[cam == c]).items():
            rows.append([int(c), comp, f"{100 * r2:.2f} %",
                         *(f"{1e3 * a:+.2f} ({1e3 * b:.2f})" for a, b in zip(coef, se))])
    return md_table(["camera", "error", "R^2", *PHASE_TERMS], rows,
                    "pixel-phase regression of the detected corner error (mpx, standard error)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="fisheye-stereo")
    ap.add_argument("--seeds", type=int, default=10)
    a = ap.parse_args(argv)
    runs = run_pool(run_seed, [(a.scenario, FRAMES[a.scenario], s) for s in range(a.seeds)])
    say(summary(runs))
    say(flip_null(runs))
    say(phase_table(runs))
    for r in runs:
        say(r["seed"], " ".join(f"{k}={np.linalg.norm(r[k]):.5f}" for k in ("detected", "full", "view mean",
                                                                          "radial trend", "white")))
    slim = [{k: v for k, v in r.items() if not k.startswith(("contrib", "phase_"))} for r in runs]
    write_json("fisheye_excess", {"runs": slim, "cache_reused": os.environ.get("BENCH_REUSE_CACHE") == "1"})


if __name__ == "__main__":
    main()
