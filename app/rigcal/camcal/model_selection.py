"""Which camera model the data support: distortion terms and intrinsics structure (a stage of the pipeline).

After the joint solve (pipeline.py), on its covariance: k3 is kept only when a Wald test at
K3_LEVEL supports it (keep_k3), and with `--intrinsics auto` fx = fy and the principal
point at its declared value are the model unless the data reject them (structure_tests
screens by Wald, select_structure confirms by the likelihood ratio of a refit).
`initialise` uses the same tests on one camera's own views, and `--imu-model auto`
(calibrate_imu) the same likelihood ratio and level for the IMU's scale and misalignment.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
# chdtri(k, q): the chi-square quantile with upper tail q; scipy.stats costs 1 s to import
from scipy.special import chdtri

from rigcal.errors import InputError
from rigcal.camcal.solve import Intrinsics, SolveResult, State, bundle_adjust, camera_covariance, intrinsics_covariance

# k3 is tested in the full bundle adjustment (Wald, on the joint solve's covariance),
# where every view of every camera constrains it; it is what overfits with few views
# (Bumblebee2 baseline 120.15 -> 120.48 mm with k3), so it must be highly
# significant.
K3_LEVEL = 1e-4
# `--intrinsics auto`: fx = fy (square pixels) and the principal point at its declared value
# (the image centre unless declared) are the model; the data free them by a Wald test at
# the level k3 must pass, on the covariance of the solve that estimated them (1 degree of
# freedom for fx - fy, 2 for cx, cy), or when the likelihood ratio of the reduced refit
# rejects the reduction at that level (select_structure). Webcams seen through a small
# board cannot pin a principal point (caliscope: 1-sigma 1.3-21 px); every rig whose data
# resolve it keeps it free (the simulated rigs: Wald 9,100 and more).
INTRINSICS_LEVEL = K3_LEVEL
# `--imu-model auto`: the 12 scale-misalignment parameters are kept when the likelihood ratio
# of the two fits passes the level of k3 and of the intrinsics' structure
IMU_MODEL_LEVEL = K3_LEVEL
# --intrinsics NAME -> (tie_focal, hold_centre); auto: tested per camera
INTRINSICS_CHOICES = {"free": (False, False), "square": (True, False), "centred": (False, True),
                      "square-centred": (True, True)}


def keep_k3(k3: float, var_k3: float) -> tuple[bool, str]:
    """Whether the joint solve supports k3 (Wald test at K3_LEVEL), and a log line."""
    w = k3 * k3 / max(var_k3, 1e-300)
    need = float(chdtri(1, K3_LEVEL))
    keep = bool(w > need)
    return keep, f"k3 {k3:.3g}: Wald {w:.1f} (needs {need:.1f}) -> {'kept' if keep else 'dropped'}"


def structure_tests(it: Intrinsics, cov: np.ndarray, centre) -> tuple[bool, bool, list[str]]:
    """Wald screen of fx = fy and of the principal point at `centre` (cx, cy), from freely
    estimated intrinsics `it` and the covariance cov (n, n) of their values, at
    INTRINSICS_LEVEL (fx - fy: 1 degree of freedom; the offset from centre: 2).
    -> (fx = fy not rejected, centre not rejected, log lines). select_structure confirms
    each by the likelihood ratio of the refit."""
    v = it.values
    d = float(v[0] - v[1])
    w_f = d * d / max(float(cov[0, 0] + cov[1, 1] - 2.0 * cov[0, 1]), 1e-300)
    off = v[2:4] - np.asarray(centre, float)
    try:
        w_c = float(off @ np.linalg.solve(cov[2:4, 2:4], off))
    except np.linalg.LinAlgError:  # a singular block cannot say the offset is noise
        w_c = float("inf")
    tie, hold = bool(w_f <= _need(1)), bool(w_c <= _need(2))
    sd = np.sqrt(np.clip(np.diag(cov)[:4], 0, None))
    return tie, hold, [
        f"fx - fy = {d:+.2f} px (sigma fx {sd[0]:.2f}, fy {sd[1]:.2f}): Wald {w_f:.1f} (needs {_need(1):.1f})",
        f"principal point {off[0]:+.1f}, {off[1]:+.1f} px from ({centre[0]:.1f}, {centre[1]:.1f}) (sigma cx "
        f"{sd[2]:.1f}, cy {sd[3]:.1f}): Wald {w_c:.1f} (needs {_need(2):.1f})"]


def _need(dof: int) -> float:
    """The chi-square threshold of the intrinsics' tests (INTRINSICS_LEVEL)."""
    return chi2_threshold(dof, INTRINSICS_LEVEL)


def chi2_threshold(dof: int, level: float) -> float:
    """The chi-square quantile with `dof` degrees of freedom and upper tail `level`."""
    return float(chdtri(dof, level))


def likelihood_ratio_test(statistic: float, dof: int, level: float = IMU_MODEL_LEVEL) -> tuple[bool, float]:
    """(the larger model is significant, the threshold): the likelihood ratio `statistic`
    (the smaller model's cost minus the larger's, in units of the measured noise, as
    select_structure's) against chi-square with `dof` degrees of freedom at `level`."""
    need = chi2_threshold(dof, level)
    return bool(statistic > need), need


def refit(res: SolveResult, c: int, it: Intrinsics) -> SolveResult:
    """res's problem solved again with camera c's intrinsics replaced by `it`, on exactly
    res's inlier corners (no rejection), so the costs compare: the likelihood ratio of
    the two is (sum r'^2 - sum r^2) / res.sigma_px^2."""
    st = res.state.copy()
    st.intrinsics[c] = it
    pb = res.problem
    return bundle_adjust(pb.obs, st, pb.gauge_cam, pb.gauge_board, pb.fix_intr,
                         inliers=np.ones(len(pb.obs), bool), max_rounds=0)


def select_structure(res: SolveResult, c: int, cov: np.ndarray, centre) -> tuple[Intrinsics | None, list[str]]:
    """Camera c's structure from a solve `res` where it was estimated freely (cov: the (n, n)
    covariance of its values): fx = fy and the principal point held at `centre` each where
    the data do not reject it. Screened by the Wald test (structure_tests), then each
    reduction, and both together, confirmed by the likelihood ratio of the refit at
    INTRINSICS_LEVEL, the rational model's statistic: on weak data (webcams, a 12-corner
    board) the covariance is too local, e.g. caliscope's cam_2 passes both Wald screens
    (13.8 and 17.6) and each reduction alone its LR, but tying and holding together costs
    an LR of 207 (needs 21.1).
    -> (the reduced intrinsics or None to keep them free, log lines)."""
    it = res.state.intrinsics[c]
    tie_w, hold_w, lines = structure_tests(it, cov, centre)
    s2 = max(res.sigma_px ** 2, 1e-300)
    base = float(np.sum(res.residuals ** 2))

    def lr(tie: bool, hold: bool) -> float:
        return (float(np.sum(refit(res, c, with_structure(it, tie, hold, centre)).residuals ** 2)) - base) / s2

    ok = {}
    for name, wald, key, dof in (("fx = fy", tie_w, (True, False), 1), ("principal point held", hold_w,
                                                                         (False, True), 2)):
        if not wald:
            lines.append(f"{name}: rejected by the Wald test -> free")
            ok[key] = False
            continue
        stat = lr(*key)
        ok[key] = stat <= _need(dof)
        lines.append(f"{name}: LR {stat:.1f} (needs {_need(dof):.1f}) -> {'accepted' if ok[key] else 'free'}")
    tie, hold = ok[(True, False)], ok[(False, True)]
    if tie and hold:
        stat = lr(True, True)
        if stat > _need(3):
            # each alone is noise, both together are not: keep the one that costs less
            hold = False
            lines.append(f"fx = fy and principal point held together: LR {stat:.1f} (needs {_need(3):.1f}) -> "
                         f"principal point free")
    return (with_structure(it, tie, hold, centre) if tie or hold else None), lines


def with_structure(it: Intrinsics, tie_focal: bool, hold_centre: bool, centre) -> Intrinsics:
    """`it` with fx = fy tied (at their mean) and/or cx, cy held at `centre`."""
    v = it.values.copy()
    if tie_focal:
        v[0] = v[1] = 0.5 * (v[0] + v[1])
    if hold_centre:
        v[2:4] = centre
    return replace(it, values=v, tie_focal=bool(tie_focal), hold_centre=bool(hold_centre))


def forced_structure(it: Intrinsics, mode: str, centre) -> Intrinsics:
    """The start of the solve for --intrinsics `mode`: a named structure imposed, auto
    (tested after the solve) and free left free."""
    if mode == "auto":
        return it
    if mode not in INTRINSICS_CHOICES:
        raise InputError(f"--intrinsics: expected one of auto, {', '.join(INTRINSICS_CHOICES)}, got {mode!r}")
    return with_structure(it, *INTRINSICS_CHOICES[mode], centre)


def solve_covariance(res) -> tuple | None:
    """camera_covariance(res), or None when the Schur complement is singular."""
    try:
        return camera_covariance(res)
    except np.linalg.LinAlgError:
        return None


def reduce_models(res, covariance: tuple | None, centres: list, test_k3: bool = True,
                   test_structure: bool = False) -> tuple[State | None, dict[int, list[str]]]:
    """The joint solve's models reduced where the data do not support them: radtan5 without
    k3 (keep_k3) and, with test_structure, fx = fy tied and the principal point held at
    centres[c] (structure_tests) on cameras estimated freely; None when every camera keeps
    its model. covariance: solve_covariance(res)."""
    if covariance is None:
        return None, {}
    cov, intr_sl, _ = covariance
    full = intrinsics_covariance(cov, intr_sl, res.state.intrinsics)
    state = res.state.copy()
    logs, changed = {}, False
    for c, intr in enumerate(state.intrinsics):
        C = full[c]
        if C is None:
            continue
        logs[c] = []
        new = intr
        if test_k3 and intr.model != "fisheye" and len(intr.values) == 9:
            keep, line = keep_k3(intr.values[8], C[8, 8])
            logs[c].append(f"joint solve: {line}")
            if not keep:
                new = replace(new, values=new.values[:8].copy())
        if test_structure and not (intr.tie_focal or intr.hold_centre):
            reduced, lines = select_structure(res, c, C, centres[c])
            logs[c].extend(f"joint solve: {x}" for x in lines)
            if reduced is not None:
                new = replace(reduced, values=np.concatenate([reduced.values[:4], new.values[4:]]))
        if new is not intr:
            state.intrinsics[c] = new
            changed = True
    return (state if changed else None), logs


def intrinsics_model(it: Intrinsics, distortion: str, fixed: bool) -> dict:
    """The calibrated YAML's `calibration.intrinsics_model` of one camera."""
    if fixed:
        return {"focal": "declared", "principal_point": "declared", "distortion": distortion}
    return {"focal": "fx=fy" if it.tie_focal else "fx,fy", "principal_point": "held" if it.hold_centre else "free",
            "distortion": distortion}


def intrinsic_sigmas(cov: np.ndarray) -> dict:
    """{fx, fy, cx, cy: 1-sigma px, distortion: [1-sigma]} from the (n, n) covariance of
    [fx, fy, cx, cy, dist...] (held values: 0)."""
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    d = {k: float(sd[i]) for i, k in enumerate(("fx", "fy", "cx", "cy"))}
    d["distortion"] = [float(x) for x in sd[4:]]
    return d
