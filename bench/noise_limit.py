"""The noise limit: camera-pair errors over seeds against the Cramér-Rao bound.

For each scenario and seed: render (seeded), detect, calibrate; the bound is the
Fisher information of the bundle adjustment at the TRUE state, for the corners the
calibration used, with the measured corner noise (detected corners vs their true
projections), pushed through each pair's relative pose (rigcal.camcal.bounds). The ratio
reported per pair is RMS(error over seeds) / RMS(bound over seeds); 1.0 is an
efficient estimator, the goal is <= 1.2 (target: within 1.3x).

A ratio well above 1 is something systematic. To say what, every seed is also
calibrated with the detected corners REPLACED by their true projections plus white
Gaussian noise of the measured sigma (same corners, same views): that isolates the
solver (model selection, initialisation, convergence) from the detector. On the
first seeds two more diagnostics run: distortion fixed to the truth's own model
(is model selection to blame?) and the bundle adjustment restarted from the true
state on the detected corners (did the solver stop at the minimum?).

Every seed is calibrated as `rigcal calibrate` calibrates (--guided auto: a fisheye
camera's corners are measured again once the rig is solved, rigcal.detect.guided); where that
guides a camera, the same detections are also calibrated with the guided pass off, each
with the bound for its own measured corner noise. The white-noise and restart diagnostics
start from the default calibration; corner weighting and the hetero CRB are about the
detector's own sigma, so they use the detector's corners.

Corner weighting (rigcal.camcal.pipeline.calibrate_views(weight_corners=True): each corner weighted
by the detector's own sigma, calibrated per camera on the residuals, rigcal.camcal.solve's
NoiseModel) runs on the same detections as a variant, with its own restart and the
honesty of its reported sigmas. The 'hetero CRB' is the bound for corners whose noise
differs as the detector's sigma can tell (the NoiseModel fitted on the TRUE errors):
when it is no lower than the plain bound, no weighting by that sigma can gain much.

Frames are reduced from the accuracy scenarios (drone 30, stereo-forward 20,
surround-6 30, fisheye 20) so 10 seeds of 4 scenes fit the benchmark's budget; the
bound is computed per seed for its own scene, so the ratio keeps its meaning.

    python -m bench.noise_limit [--seeds 10] [--scenario NAME ...] [--diag-seeds 3]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import RigcalError
from rigcal.camcal.bounds import relative_pose_jacobian, measured_corner_noise, true_state
from rigcal.camcal.pipeline import weighted_solve
from rigcal.camcal.solve import (Intrinsics, Problem, SolveResult, State, bundle_adjust, camera_covariance,
                                 fit_noise_model, noise_weights)

from .common import (SCENARIOS, Timer, calibrate, calibrate_dataset, crb_pairs, gaussian_views, get_dataset, md_table, pose_errors_body,
                     rig_errors, rig_scale_ppm, run_pool, say, scenario, true_projections, write_json)

FRAMES = {"drone-stereo-back": 30, "stereo-forward": 20, "surround-6": 30, "fisheye-stereo": 20}
AXES = ("F", "L", "U")


def pair_stats(cal, truth, sigma: float) -> dict:
    b, _ = crb_pairs(cal, truth, sigma)
    e = rig_errors(cal.rig, truth.rig)["pairs"]
    out = {}
    for k, v in e.items():
        bb = b.get(tuple(k.split("/")))
        if bb is None:
            continue
        out[k] = {"rot_deg": v["rot_deg"], "trans_mm": v["trans_mm"], "bound_rot_deg": bb["rot_deg"],
                  "bound_trans_mm": bb["trans_mm"]}
    return out


def hetero_weights(cal, uv_true: np.ndarray) -> np.ndarray | None:
    """(M,) 1 / s^2 per corner, s the NoiseModel (rigcal.camcal.solve) fitted per camera on the
    TRUE corner errors against the detector's own sigma: the best a weighting by that
    sigma can know. None without detector sigmas."""
    s_det = cal.corner_sigma_detected
    if s_det is None:
        return None
    e2 = np.sum((cal.obs.uv - uv_true) ** 2, axis=1) / 2.0
    inl = cal.inliers
    models = [fit_noise_model(s_det[inl & (cal.obs.cam == c)], e2[inl & (cal.obs.cam == c)])
              for c in range(len(cal.cam_names))]
    if all(m is None for m in models):
        return None
    return noise_weights(s_det, cal.obs.cam, models)


def hetero_pair_bounds(cal, truth, weights: np.ndarray) -> dict:
    """rigcal.camcal.bounds.pair_bounds for corners whose noise differs (1 / weights px^2 each):
    the Cramér-Rao bound of the weighted solve with those very weights (variance factor 1)."""
    st = true_state(cal, truth)
    obs = replace(cal.obs, weight=weights).subset(cal.inliers)
    pb = Problem(obs, st, cal.problem.gauge_cam, cal.problem.gauge_board, cal.problem.fix_intr)
    res = SolveResult(st, pb, np.ones(len(obs), bool), np.zeros((len(obs), 2)), 1.0, 0, 0.0, variance_factor=1.0)
    cov, _, cam_sl = camera_covariance(res)
    free = [c for c in range(len(cal.cam_names)) if cam_sl[c] is not None]
    idx = np.concatenate([np.arange(cam_sl[c].start, cam_sl[c].stop) for c in free])
    out = {}
    for i in range(len(cal.cam_names)):
        for j in range(i + 1, len(cal.cam_names)):
            G = relative_pose_jacobian(st.T_cam_body, i, j, free)
            S = G @ cov[np.ix_(idx, idx)] @ G.T
            out[f"{cal.cam_names[i]}/{cal.cam_names[j]}"] = {
                "rot_deg": float(np.degrees(np.sqrt(np.trace(S[:3, :3])))),
                "trans_mm": float(1000 * np.sqrt(np.trace(S[3:, 3:])))}
    return out


def _hetero_stats(cal, truth, uv_true: np.ndarray, auto: dict) -> dict | None:
    """The calibration's pair errors (auto) against hetero_pair_bounds."""
    w = hetero_weights(cal, uv_true)
    if w is None:
        return None
    try:
        b = hetero_pair_bounds(cal, truth, w)
    except np.linalg.LinAlgError:
        return None
    return {k: {"rot_deg": v["rot_deg"], "trans_mm": v["trans_mm"], "bound_rot_deg": b[k]["rot_deg"],
                "bound_trans_mm": b[k]["trans_mm"]} for k, v in auto.items() if k in b}


def _coverage_samples(cal, truth_rig) -> dict:
    """Per camera: true error (6) and predicted 1-sigma (6) in the output body frame."""
    err = pose_errors_body(cal, truth_rig)
    out = {}
    for n in cal.cam_names:
        st = cal.stats[n]
        if st.sigma_rotation_deg is None:
            continue
        out[n] = {"error": err[n].tolist(),
                  "sigma": np.concatenate([st.sigma_rotation_deg, st.sigma_position_mm]).tolist()}
    return out


def view_offsets(cal, uv_true: np.ndarray, sigma: float) -> dict:
    """How far the detector's errors are from white: RMS of each view's mean error
    (a per-image common offset) against sigma / sqrt(corners in the view), over the
    corners the calibration kept (cal.inliers), as sigma (measured_corner_noise) is.
    uv_true: (M, 2) true projections of all cal.obs. A corner the solve rejected never
    reached the estimate, and one misdetection a few px off in a 40-corner view is by
    itself an 'offset' of ~0.05 px: counted, a handful of them over 20 seeds made up the
    whole RMS. rejected_corners: how many were left out."""
    ok = np.asarray(cal.inliers, bool)
    r = (cal.obs.uv - uv_true)[ok]
    v = cal.obs.view[ok]
    n = np.bincount(v)
    keep = n > 0
    mean = np.stack([np.bincount(v, r[:, i])[keep] / n[keep] for i in range(2)], 1)
    white = sigma / np.sqrt(n[keep])
    return {"view_offset_rms_px": float(np.sqrt(np.mean(np.sum(mean**2, 1)) / 2)),
            "white_expectation_px": float(np.sqrt(np.mean(white**2))), "rejected_corners": int(np.sum(~ok))}


def _relative(T_cam_body: np.ndarray, i: int, j: int) -> np.ndarray:
    return T_cam_body[i] @ geo.inv_T(T_cam_body[j])


def restart_from_truth(cal, truth) -> dict | None:
    """Bundle adjustment of the same detected corners started at the true state (the
    calibrated distortion model, true values; corner weighting as rigcal.camcal.pipeline does it,
    pipeline.weighted_solve): the largest difference from the
    calibration's own relative poses (deg, mm) says whether the solver stopped short."""
    st = true_state(cal, truth)
    if st is None:
        return None
    intr = []
    for it_cal, it_true in zip(cal.state.intrinsics, st.intrinsics):
        v = np.zeros(len(it_cal.values))
        k = min(len(v), len(it_true.values))
        v[:k] = it_true.values[:k]
        intr.append(Intrinsics(it_cal.model, v))
    start = State(intr, st.T_cam_body, st.T_body_world, st.T_world_board)
    # the whole solve again: unweighted (its outlier rejection), then the corner weighting
    obs = replace(cal.obs, weight=None)
    gauge = (cal.problem.gauge_cam, cal.problem.gauge_board)
    res = bundle_adjust(obs, start, *gauge, cal.problem.fix_intr)
    if cal.obs.weight is not None:
        res = weighted_solve(res, obs, cal.corner_sigma_detected, *gauge, cal.problem.fix_intr)[0]
    C = len(cal.cam_names)
    drot, dtr = 0.0, 0.0
    for i in range(C):
        for j in range(i + 1, C):
            a, b = _relative(cal.state.T_cam_body, i, j), _relative(res.state.T_cam_body, i, j)
            drot = max(drot, geo.rotation_angle_deg(a[:3, :3] @ b[:3, :3].T))
            dtr = max(dtr, 1000 * float(np.linalg.norm(a[:3, 3] - b[:3, 3])))
    return {"max_rot_diff_deg": drot, "max_trans_diff_mm": dtr}


def truth_model(truth_rig) -> str:
    """The distortion choice equal to the truth's own model (fisheye needs none)."""
    m = truth_rig.cameras[0].intrinsics
    if m.model == "fisheye":
        return "auto"
    return {2: "radtan2", 4: "radtan4", 5: "radtan5", 8: "rational8"}[len(m.dist)]


def run_seed(name: str, frames: int, seed: int, diagnostics: bool) -> dict:
    """Everything for one (scenario, seed); runs in a worker process. A failure is
    reported in the tables (with its message), not allowed to stop the other runs."""
    try:
        return _run_seed(name, frames, seed, diagnostics)
    except (np.linalg.LinAlgError, RigcalError, ValueError) as e:
        return {"scenario": name, "seed": seed, "frames": frames, "failed": f"{type(e).__name__}: {e}"}


def _run_seed(name: str, frames: int, seed: int, diagnostics: bool) -> dict:
    scn = scenario(name).with_frames(frames)
    ds = get_dataset(scn, seed, jobs=1)
    with Timer() as t:
        cal = calibrate_dataset(ds)  # as `rigcal calibrate` does: --guided auto
    sigma = measured_corner_noise(cal, ds.truth)
    uv_true = true_projections(cal, ds.truth)
    # the detector's own corners (--guided off): the same as cal where auto guides no camera
    guided = "guided_s" in cal.timings
    dcal, sigma_det, uv_true_det = cal, sigma, uv_true
    if guided:
        dcal = calibrate(ds.views, ds.rig, ds.corners)
        sigma_det, uv_true_det = measured_corner_noise(dcal, ds.truth), true_projections(dcal, ds.truth)
    out = {"scenario": name, "seed": seed, "frames": frames, "sigma_px": sigma, "calibration_s": t.wall,
           "models": [cal.stats[n].distortion_model for n in cal.cam_names],
           "auto": pair_stats(cal, ds.truth, sigma), "coverage": _coverage_samples(cal, ds.truth.rig),
           "scale_ppm": rig_scale_ppm(cal, ds.truth.rig),
           "sigma_reported": all(st.sigma_position_mm is not None for st in cal.stats.values()),
           "corners_used": len(cal.obs), "corners_detected": int(sum(len(v.ids) for v in ds.views)),
           **view_offsets(cal, uv_true, sigma)}
    out["guided"] = guided
    out["sigma_px_detector"] = sigma_det
    out["detector"] = pair_stats(dcal, ds.truth, sigma_det)
    out["detector_coverage"] = _coverage_samples(dcal, ds.truth.rig)
    # weighting by the detector's sigma is about the detector's corners: hetero CRB and the
    # weighted variant both on them (the guided pass has no such sigma to weight by)
    out["hetero"] = _hetero_stats(dcal, ds.truth, uv_true_det, out["detector"])
    wcal = calibrate(ds.views, ds.rig, ds.corners, weight_corners=True)
    out["weighted_used"] = wcal.obs.weight is not None
    out["weighted"] = pair_stats(wcal, ds.truth, sigma_det)
    out["weighted_coverage"] = _coverage_samples(wcal, ds.truth.rig)
    rng = np.random.default_rng([seed, 7])
    gcal = calibrate(gaussian_views(cal, uv_true, ds.corners, sigma, rng), ds.rig, ds.corners)
    out["gauss"] = pair_stats(gcal, ds.truth, sigma)
    out["gauss_coverage"] = _coverage_samples(gcal, ds.truth.rig)
    out["gauss_scale_ppm"] = rig_scale_ppm(gcal, ds.truth.rig)
    if diagnostics:
        model = truth_model(ds.truth.rig)
        if model != "auto":
            out["truth_model"] = pair_stats(calibrate_dataset(ds, model), ds.truth, sigma)
            out["truth_model_name"] = model
        out["restart"] = restart_from_truth(cal, ds.truth)
        out["restart_weighted"] = restart_from_truth(wcal, ds.truth)
    return out


def run(names: list[str] | None = None, seeds: int = 10, diag_seeds: int = 3, frames: dict | None = None,
        log=say) -> dict:
    frames = {**FRAMES, **(frames or {})}
    scns = SCENARIOS if not names else [scenario(n) for n in names]
    tasks = [(s.name, frames[s.name], k, k < diag_seeds) for s in scns for k in range(seeds)]
    log(f"noise limit: {len(tasks)} (scenario, seed) runs: render, detect, calibrate 2-{4 if diag_seeds else 2}x ...")
    with Timer() as t:
        runs = run_pool(run_seed, tasks)
    return {"runs": runs, "summary": summarise(runs), "seconds": t.wall, "frames": frames, "seeds": seeds}


def error_to_bound(runs: list[dict], variant: str, key: str) -> dict:
    """{pair: (rms err, rms bound, ratio, n)} over the runs that have the variant."""
    acc: dict[str, list] = {}
    for r in runs:
        for k, v in (r.get(variant) or {}).items():
            acc.setdefault(k, []).append((v[key], v[f"bound_{key}"]))
    out = {}
    for k, vals in acc.items():
        a = np.array(vals)
        e, b = np.sqrt(np.mean(a[:, 0] ** 2)), np.sqrt(np.mean(a[:, 1] ** 2))
        out[k] = {"rms_error": float(e), "rms_bound": float(b), "ratio": float(e / b), "n": len(a)}
    return out


def summarise(runs: list[dict]) -> dict:
    by = {}
    for r in runs:
        if "failed" not in r:
            by.setdefault(r["scenario"], []).append(r)
    out = {}
    for name, rs in by.items():
        s = {}
        for variant in ("auto", "detector", "gauss", "truth_model", "hetero", "weighted"):
            s[variant] = {q: error_to_bound(rs, variant, q) for q in ("rot_deg", "trans_mm")}
        restarts = [r["restart"] for r in rs if r.get("restart")]
        s["restart_max_rot_diff_deg"] = max((x["max_rot_diff_deg"] for x in restarts), default=None)
        s["restart_max_trans_diff_mm"] = max((x["max_trans_diff_mm"] for x in restarts), default=None)
        rw = [r["restart_weighted"] for r in rs if r.get("restart_weighted")]
        s["restart_weighted_max_rot_diff_deg"] = max((x["max_rot_diff_deg"] for x in rw), default=None)
        s["restart_weighted_max_trans_diff_mm"] = max((x["max_trans_diff_mm"] for x in rw), default=None)
        s["sigma_px"] = float(np.mean([r["sigma_px"] for r in rs]))
        s["view_offset_rms_px"] = float(np.sqrt(np.mean([r["view_offset_rms_px"] ** 2 for r in rs])))
        s["white_expectation_px"] = float(np.sqrt(np.mean([r["white_expectation_px"] ** 2 for r in rs])))
        s["scale_ppm_mean"] = float(np.mean([r["scale_ppm"] for r in rs]))
        s["scale_ppm_std"] = float(np.std([r["scale_ppm"] for r in rs]))
        s["gauss_scale_ppm_mean"] = float(np.mean([r["gauss_scale_ppm"] for r in rs]))
        s["gauss_scale_ppm_std"] = float(np.std([r["gauss_scale_ppm"] for r in rs]))
        s["corners_used_share"] = float(sum(r["corners_used"] for r in rs) / sum(r["corners_detected"] for r in rs))
        s["sigma_reported"] = int(sum(r.get("sigma_reported", False) for r in rs))
        s["seeds"] = len(rs)
        s["weighted_used"] = int(sum(r.get("weighted_used", False) for r in rs))
        s["coverage"] = coverage_summary([r["coverage"] for r in rs])
        s["detector_coverage"] = coverage_summary([r["detector_coverage"] for r in rs if "detector_coverage" in r])
        s["guided"] = int(sum(r.get("guided", False) for r in rs))
        s["weighted_coverage"] = coverage_summary([r["weighted_coverage"] for r in rs if "weighted_coverage" in r])
        s["frames"] = rs[0]["frames"]
        out[name] = s
    return out


def coverage_summary(samples: list[dict]) -> dict:
    """How honest the reported per-camera sigmas are, over cameras, axes and seeds: RMS of
    error / reported sigma (1 = honest) and the share within 2 sigma (95 % if Gaussian),
    rotation and position apart. The gauge camera's tiny sigmas are left out (aligned
    frame: none is exactly zero, but those under 1e-9 would dominate)."""
    out = {}
    for name, sl in (("rot", slice(0, 3)), ("pos", slice(3, 6))):
        z = []
        for smp in samples:
            for v in smp.values():
                e, sd = np.array(v["error"])[sl], np.array(v["sigma"])[sl]
                ok = sd > 1e-9
                z.extend((e[ok] / sd[ok]).tolist())
        z = np.array(z)
        out[f"{name}_z_rms"] = float(np.sqrt(np.mean(z**2))) if len(z) else None
        out[f"{name}_within_2sigma"] = float(np.mean(np.abs(z) < 2)) if len(z) else None
    return out


def tables(res: dict) -> str:
    rows = []
    for name, s in res["summary"].items():
        for k, rot in s["auto"]["rot_deg"].items():
            tr = s["auto"]["trans_mm"][k]
            grot, gtr = s["gauss"]["rot_deg"].get(k, {}), s["gauss"]["trans_mm"].get(k, {})
            hrot, htr = s["hetero"]["rot_deg"].get(k, {}), s["hetero"]["trans_mm"].get(k, {})
            wrot, wtr = s["weighted"]["rot_deg"].get(k, {}), s["weighted"]["trans_mm"].get(k, {})
            drot, dtr = ((s["detector"]["rot_deg"].get(k, {}), s["detector"]["trans_mm"].get(k, {})) if s["guided"]
                         else ({}, {}))
            rows.append([name, k, rot["rms_error"], rot["rms_bound"], rot["ratio"], tr["rms_error"], tr["rms_bound"],
                         tr["ratio"], drot.get("rms_error"), drot.get("ratio"), dtr.get("rms_error"), dtr.get("ratio"),
                         grot.get("ratio"), gtr.get("ratio"), hrot.get("ratio"), htr.get("ratio"),
                         wrot.get("ratio"), wtr.get("ratio")])
    seeds = max(s["seeds"] for s in res["summary"].values())
    parts = [md_table(["scenario", "pair", "rot RMS deg", "CRB deg", "rot ratio", "trans RMS mm", "CRB mm",
                       "trans ratio", "--guided off: rot RMS deg", "rot ratio", "trans RMS mm", "trans ratio",
                       "rot ratio, white noise", "trans ratio, white noise", "rot ratio, hetero CRB",
                       "trans ratio, hetero CRB", "rot ratio, weighted", "trans ratio, weighted"], rows,
                      f"Noise limit: RMS error over {seeds} seeds vs Cramér-Rao bound (ratio 1 = efficient; "
                      f"calibrated as `rigcal calibrate` does, --guided auto; '--guided off' = the detector's "
                      f"corners, with the bound for their own noise, blank where auto guides no camera; "
                      f"'white noise' = same corners, true projections + Gaussian noise of the measured sigma; "
                      f"'hetero CRB' = the bound for each corner's own noise as the detector's sigma can tell it, "
                      f"noise_limit.hetero_weights; 'weighted' = calibrate_views(weight_corners=True) on the "
                      f"same detections)")]
    rows, wrows = [], []
    for name, s in res["summary"].items():
        tm = s["truth_model"]
        worst_auto = max(max(v["ratio"] for v in s["auto"][q].values()) for q in ("rot_deg", "trans_mm"))
        worst_tm = (max(max(v["ratio"] for v in tm[q].values()) for q in ("rot_deg", "trans_mm"))
                    if tm["rot_deg"] else None)
        n_tm = next(iter(tm["rot_deg"].values()))["n"] if tm["rot_deg"] else 0
        rows.append([name, s["frames"], s["seeds"], f"{s['sigma_reported']}/{s['seeds']}",
                     f"{100 * s['corners_used_share']:.0f} %", s["sigma_px"],
                     s["view_offset_rms_px"], s["white_expectation_px"],
                     f"{s['scale_ppm_mean']:+.0f} +- {s['scale_ppm_std']:.0f}",
                     f"{s['gauss_scale_ppm_mean']:+.0f} +- {s['gauss_scale_ppm_std']:.0f}",
                     worst_auto, f"{worst_tm:.2f} ({n_tm} seeds)" if worst_tm is not None else "- (fisheye)",
                     s["restart_max_rot_diff_deg"], s["restart_max_trans_diff_mm"],
                     s["coverage"]["rot_z_rms"], s["coverage"]["rot_within_2sigma"], s["coverage"]["pos_z_rms"],
                     s["coverage"]["pos_within_2sigma"]])
        wc = s["weighted_coverage"]
        wrows.append([name, f"{s['weighted_used']}/{s['seeds']}", s["restart_weighted_max_rot_diff_deg"],
                      s["restart_weighted_max_trans_diff_mm"], wc["rot_z_rms"], wc["rot_within_2sigma"],
                      wc["pos_z_rms"], wc["pos_within_2sigma"]])
    parts.append(md_table(["scenario", "frames", "seeds", "sigma reported", "detected corners used", "corner noise px",
                           "per-view offset RMS px", "same if white px", "rig scale ppm", "rig scale ppm, white",
                           "worst ratio (auto)", "worst ratio (truth's model)", "restart from truth: max rot diff deg",
                           "max trans diff mm", "rot error/sigma RMS", "rot within 2 sigma",
                           "pos error/sigma RMS", "pos within 2 sigma"], rows,
                          "Noise-limit diagnostics (error/sigma: each camera's pose error against its reported "
                          "sigma, 1 and 95 % when honest)"))
    parts.append(md_table(["scenario", "seeds weighted", "restart from truth: max rot diff deg", "max trans diff mm",
                           "rot error/sigma RMS", "rot within 2 sigma", "pos error/sigma RMS", "pos within 2 sigma"],
                          wrows, "Corner weighting (weight_corners=True): restart and reported sigma"))
    failed = [f"{r['scenario']} seed {r['seed']}: {r.get('failed') or r.get('gauss_failed')}" for r in res["runs"]
              if "failed" in r or "gauss_failed" in r]
    if failed:
        parts.append("\nruns that failed (left out above): " + "; ".join(failed))
    return "\n".join(parts)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", action="append")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--diag-seeds", type=int, default=3)
    a = ap.parse_args(argv)
    res = run(a.scenario, a.seeds, a.diag_seeds)
    say(tables(res))
    write_json("noise_limit", res)


if __name__ == "__main__":
    main()
