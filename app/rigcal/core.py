"""Calibration from detections: intrinsics, pose graph, bundle adjustment, body frame.

No image I/O here (that is detect.py) and no files (calibrate.py): views in, a
calibrated Rig and its statistics out, so tests can drive it with synthetic corners.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
# chdtri(k, q): the chi-square quantile with upper tail q; scipy.stats costs 1 s to import
from scipy.special import chdtri

from . import geometry as geo
from .camera import CameraModel, PINHOLE_MODEL_NAMES
from .errors import CalibrationError, InputError
from .initialise import (MAX_INIT_VIEWS, MonoFit, PosedView, _select_views, corner_residuals, fit_pinhole,
                         inlier_masks, pnp_views, pose_graph, resolve_flips)
from .rig import Camera, Rig
from .solve import (Intrinsics, NoiseModel, Observations, Problem, SolveResult, State, bundle_adjust,
                    camera_covariance, fit_noise_model, intrinsics_covariance, judge_inliers, noise_weights)

DISTORTION_CHOICES = {"radial2": 2, "radtan4": 4, "radtan5": 5, "rational8": 8}
# `--distortion auto` for a pinhole camera: radtan4 (k1 k2 p1 p2) is the least it fits,
# as in Kalibr. Decentering is nearly a principal-point shift in reprojection, so a
# significance test misses it when it is real but small, and each miss biases that
# camera's rotation by about its cy bias / f. Measured on drone-stereo-back (30 frames,
# 0.1 px, p ~ 1e-4, bench/montecarlo.py): the joint-solve Wald statistic of (p1, p2)
# ranged 0.4-58, a 5 % test dropped p in 33 of 90 fits, and the 2-sigma coverage about
# body L fell to 62 %. Always estimating p widens the sigma of rotation about the
# camera's x and y axes 2.5-4x, yet its actual rotation errors were 2-4x SMALLER than
# radial2's (0.005-0.008 deg against 0.009-0.033 deg RMS), and coverage is 90-98 %.
# radial2 stays available by name, for lenses known to have no decentering.
# k3 is tested in the full bundle adjustment (Wald, on the joint solve's covariance),
# where every view of every camera constrains it; it is what overfits with few views
# (issue 4: Bumblebee2 baseline 120.15 -> 120.48 mm with k3), so it must be highly
# significant.
K3_LEVEL = 1e-4
# The rational model is chosen before the joint solve (it is the richest start); it must
# beat radtan5 by a likelihood ratio at this level, with a coefficient beyond RATIONAL_MIN_Z
# sigmas, and lower the RMS by RATIONAL_MIN_GAIN.
RATIONAL_LEVEL = 1e-4
RATIONAL_MIN_Z = 3.0
RATIONAL_MIN_GAIN = 0.05
# `--intrinsics auto`: fx = fy (square pixels) and the principal point at its declared value
# (the image centre unless declared) are the model; the data free them by a Wald test at
# the level k3 must pass, on the covariance of the solve that estimated them (1 degree of
# freedom for fx - fy, 2 for cx, cy), or when the likelihood ratio of the reduced refit
# rejects the reduction at that level (select_structure). Webcams seen through a small
# board cannot pin a principal point (caliscope: 1-sigma 1.3-21 px); every rig whose data
# resolve it keeps it free (the simulated rigs: Wald 9,100 and more).
INTRINSICS_LEVEL = K3_LEVEL
# --intrinsics NAME -> (tie_focal, hold_centre); auto: tested per camera
INTRINSICS_CHOICES = {"free": (False, False), "square": (True, False), "centred": (False, True),
                      "square-centred": (True, True)}
# joint / own-views RMS beyond which a rig is judged not rigid per frame (rigidity_check)
RIGIDITY_RATIO = 3.0
MIN_VIEW_CORNERS = 4
MIN_FRAMES = 3
# A camera whose corners miss the solved rig by more than this share of its image diagonal
# (RMS; at least GROSS_RMS_MIN_PX) failed to calibrate: a target.yaml that misnumbers the
# board, mirrored images, a chessboard declared on a ChArUco print. The real sets stay under
# 0.12 % (the worst, the unsynchronised caliscope webcams: 1.6 px of a 1469 px diagonal).
GROSS_RMS_FRACTION = 0.01
GROSS_RMS_MIN_PX = 5.0
# corner weights: fit each camera's NoiseModel on the residuals, re-weight, re-solve; the
# second fit is on the weighted solve's residuals (the first on the unweighted one's)
NOISE_ROUNDS = 2


@dataclass(frozen=True)
class ViewIn:
    """A detected board view (plain data, see detect.View)."""

    camera: str
    frame: str
    board: str
    ids: np.ndarray
    uv: np.ndarray
    ambiguous: bool = False
    # (N,) each corner's own 1-sigma px as the detector estimates it (detect.View.sigma;
    # NaN where unknown), or None: then every corner counts alike
    sigma: np.ndarray | None = None


@dataclass
class CameraStats:
    name: str
    rms_px: float
    observations: int
    frames: int
    outliers: int
    distortion_model: str
    sigma_position_mm: np.ndarray | None = None
    sigma_rotation_deg: np.ndarray | None = None
    sigma_intrinsics: dict | None = None
    model_selection: list = field(default_factory=list)
    # which intrinsics were estimated: {focal: fx=fy | fx,fy | declared, principal_point:
    # held | free | declared, distortion: model name} (intrinsics_model)
    intrinsics_model: dict | None = None
    # 1-sigma of fx, fy, cx, cy (px) when all four were estimated, before the structure was
    # chosen: how poorly a tied or held parameter is determined (None: not tested)
    sigma_intrinsics_free: dict | None = None


@dataclass
class Calibration:
    rig: Rig  # calibrated (body frame per reference)
    stats: dict[str, CameraStats]
    reference: str
    rms_px: float
    sigma_px: float
    state: State
    problem: Problem
    obs: Observations  # all observations fed to the solve
    inliers: np.ndarray
    frames: list[str]
    boards: list[str]
    cam_names: list[str]
    T_body_solve: np.ndarray  # maps the solver's body (gauge camera) frame into the output body frame
    cov_extrinsics: np.ndarray | None  # (6C, 6C) [rot about body axes (rad), position (m)] per camera
    timings: dict
    notes: list[str]
    flips: int = 0
    declared: Rig | None = None  # the rig as declared (initial guess and body-frame reference)
    # per observation (obs order): the detector's own 1-sigma px (NaN unknown; None: no view had one)
    corner_sigma_detected: np.ndarray | None = None
    noise_models: list | None = None  # per camera the NoiseModel the corners were weighted by (or None)


# ----------------------------------------------------------------------------- intrinsics


def _views_obj_img(views: list[ViewIn], corners: dict) -> tuple[list, list]:
    return [corners[v.board][v.ids] for v in views], [v.uv for v in views]


def _faces(views: list[ViewIn], faces: dict | None) -> list[float] | None:
    """Per view the sign of board z on the printed side (initialise.camera_faces_print)."""
    return None if faces is None else [float(faces.get(v.board, -1.0)) for v in views]


def select_rational(fit5: MonoFit, fit8: MonoFit | None, n_params_views: int) -> tuple[int, list[str]]:
    """5 or 8 coefficients as the start of the joint solve (see RATIONAL_LEVEL).

    The rational model's numerator and denominator can nearly cancel, so on a narrow
    lens a few systematic corner errors make it "significant" with absurd coefficients
    (Bumblebee2: k1 = -38, k2 = 356) while it shifts the extrinsics; a genuinely wide lens
    needs it by a wide margin, hence the RMS gain on top of the test."""
    if fit8 is None:
        return 5, []
    stat, need, z = _lr_test(fit5, fit8, 5, 8, n_params_views)
    gain = 1.0 - fit8.rms_px / fit5.rms_px
    ok = stat > need and z > RATIONAL_MIN_Z and gain >= RATIONAL_MIN_GAIN
    return (8 if ok else 5), [
        f"radtan5->rational8 (single-camera fit): LR {stat:.1f} (needs {need:.1f}), max |coef/sigma| {z:.1f}, "
        f"RMS gain {100 * gain:.1f}% (needs {100 * RATIONAL_MIN_GAIN:.0f}%) -> {'accepted' if ok else 'rejected'}"]


def _lr_test(base: MonoFit, rich: MonoFit, n_base: int, n_rich: int, n_params_views: int):
    """(LR statistic, chi2 threshold, max |z| of the added coefficients) for nested fits."""
    N = rich.n_points
    dof = max(2 * N - (4 + n_rich + n_params_views), 1)
    s2 = rich.rms_px**2 * N / dof
    stat = (base.rms_px**2 - rich.rms_px**2) * N / s2
    k = n_rich - n_base
    z = np.abs(rich.values[4 + n_base:4 + n_rich] / np.maximum(rich.sigma[4 + n_base:4 + n_rich], 1e-300))
    return stat, float(chdtri(k, RATIONAL_LEVEL)), float(z.max())


def keep_k3(k3: float, var_k3: float) -> tuple[bool, str]:
    """Whether the joint solve supports k3 (Wald test at K3_LEVEL), and a log line."""
    w = k3 * k3 / max(var_k3, 1e-300)
    need = float(chdtri(1, K3_LEVEL))
    keep = bool(w > need)
    return keep, f"k3 {k3:.3g}: Wald {w:.1f} (needs {need:.1f}) -> {'kept' if keep else 'dropped'}"


@dataclass(frozen=True)
class MonoInit:
    """One camera's start: intrinsics, per-view T_cam_board (None where PnP failed), the
    model-selection log, and its own-views fit for the rigidity check (rms_px None when
    the intrinsics were not fitted; mono() gives the values it supports on its own)."""

    values: np.ndarray
    T_cam_board: list
    log: list[str]
    rms_px: float | None = None
    mono: Callable[[], tuple[np.ndarray, str]] | None = None


def init_camera(views: list[ViewIn], corners: dict, declared: CameraModel, distortion: str,
                fix_intrinsics: bool, faces: dict | None = None) -> MonoInit:
    """Initial intrinsics and per-view poses for one camera, from its own views.

    With `auto` a pinhole camera starts from radtan5 (or rational8 when it wins clearly);
    the joint solve then drops k3 when the data do not support it (keep_k3)."""
    notes: list[str] = []
    obj, img = _views_obj_img(views, corners)
    rms, mono = None, None
    if fix_intrinsics:
        values = np.concatenate([[declared.fx, declared.fy, declared.cx, declared.cy], declared.dist])
    elif declared.model == "fisheye":
        values, rms = _init_fisheye(obj, img, declared, _faces(views, faces))
        mono = lambda: (values, "fisheye (own views)")  # noqa: E731
    else:
        sel = _select_views(np.array([len(o) for o in obj]), MAX_INIT_VIEWS)
        o_s, i_s = [obj[i] for i in sel], [img[i] for i in sel]
        n_want = 5 if distortion == "auto" else DISTORTION_CHOICES[distortion]
        fit, o_s, i_s, _, _ = _clean_fit(o_s, i_s, declared, n_want)
        chosen = fit
        if distortion == "auto" and len(fit.values) == 9:
            try:
                fit8 = fit_pinhole(o_s, i_s, declared, 8)
            except CalibrationError:
                fit8 = None
            n, log = select_rational(fit, fit8, 6 * len(o_s))
            notes.extend(log)
            if n == 8:
                chosen = fit8
        values, rms = chosen.values, chosen.rms_px

        def mono(n=len(chosen.values) - 4):
            # refitted on every view of the camera, cleaned: these intrinsics are kept,
            # not just a start
            own, _, _, o_c, i_c = _clean_fit(obj, img, declared, n)
            if distortion != "auto" or n != 5:
                return own.values, f"{PINHOLE_MODEL_NAMES[n]} (own views)"
            keep, line = keep_k3(own.values[8], own.sigma[8] ** 2)
            if keep:
                return own.values, f"radtan5 (own views; {line})"
            return fit_pinhole(o_c, i_c, declared, 4).values, f"radtan4 (own views; {line})"
    return MonoInit(values, pnp_views(obj, img, values, declared.model, _faces(views, faces)), notes, rms, mono)


def fixed_intrinsics_misfit(views: list[ViewIn], corners: dict, declared: CameraModel, mi: MonoInit,
                            faces: dict | None = None) -> str | None:
    """With --fix-intrinsics: words when the declared intrinsics fit this camera's own views
    (PnP per view) more than RIGIDITY_RATIO times worse than intrinsics fitted to them, else
    None. Own views only, so neither the rig's rigidity nor its synchronisation enters: the
    declared focal length, principal point or distortion do not describe these images, and
    the extrinsics are bent to absorb that (Bumblebee2 with focal 500 and no distortion
    declared: 2.0 px against 0.08, the baseline 137 mm instead of 120)."""
    posed = [(T[1], len(v.ids)) for v, T in zip(views, mi.T_cam_board) if T is not None]
    if not posed:
        return None
    fixed = float(np.sqrt(sum(r * r * k for r, k in posed) / sum(k for _, k in posed)))
    obj, img = _views_obj_img(views, corners)
    try:
        if declared.model == "fisheye":
            free = _init_fisheye(obj, img, declared, _faces(views, faces))[1]
        else:
            sel = _select_views(np.array([len(o) for o in obj]), MAX_INIT_VIEWS)
            free = _clean_fit([obj[i] for i in sel], [img[i] for i in sel], declared,
                              min(max(len(declared.dist), 4), 8))[0].rms_px
    except CalibrationError:
        return None
    if not fixed > RIGIDITY_RATIO * free:
        return None
    return (f"the declared intrinsics (--fix-intrinsics) fit its own views to {fixed:.2f} px RMS, {fixed / free:.0f}x "
            f"the {free:.2f} px of intrinsics fitted to them: the declared focal length, principal point or "
            f"distortion do not describe these images, and the extrinsics absorb the difference")


def _clean_fit(obj: list, img: list, declared: CameraModel, n_dist: int) -> tuple[MonoFit, list, list, list, list]:
    """OpenCV fit of `n_dist` coefficients without gross outlier corners: a few wrong
    corners would otherwise decide the rational test and skew the start. Corners beyond
    5 robust sigmas go, and so do views left with too few corners; the fit is redone
    only if what went carried over 5 % of its cost. Falls back to fewer coefficients
    when OpenCV fails (very few views). Returns (fit, the views it was fitted on, the
    cleaned views)."""
    last = None
    for n in [n_dist] + [m for m in (4, 2) if m < n_dist]:
        try:
            fit = fit_pinhole(obj, img, declared, n)
            break
        except CalibrationError as e:
            last = e
    else:
        raise last
    errors = corner_residuals(obj, img, fit.values, "pinhole", fit.T_cam_board)
    masks = inlier_masks(errors)
    keep = [k for k, m in enumerate(masks) if m.sum() >= max(MIN_VIEW_CORNERS, 6)]
    o2, i2 = [obj[k][masks[k]] for k in keep], [img[k][masks[k]] for k in keep]
    e2 = np.concatenate(errors) ** 2
    kept = np.concatenate([m if k in keep else np.zeros_like(m) for k, m in enumerate(masks)])
    # corners that carried under 5 % of the cost cannot have pulled the fit far: keep it,
    # with the views it was fitted on (the rational test compares fits on the same corners)
    if np.isfinite(e2).all() and e2[~kept].sum() <= 0.05 * e2.sum():
        return fit, obj, img, o2, i2
    try:
        return fit_pinhole(o2, i2, declared, n), o2, i2, o2, i2
    except CalibrationError:
        return fit, obj, img, obj, img


def _init_fisheye(obj: list, img: list, declared: CameraModel, faces: list[float] | None = None
                  ) -> tuple[np.ndarray, float]:
    """One-camera bundle adjustment from the declared intrinsics and per-view PnP:
    (intrinsics values, RMS reprojection px)."""
    values = np.concatenate([[declared.fx, declared.fy, declared.cx, declared.cy], declared.dist])
    res = one_camera_solve(obj, img, Intrinsics("fisheye", values), MAX_INIT_VIEWS, faces)
    if res is None:
        raise CalibrationError("fisheye: fewer than 2 views could be posed from the declared intrinsics")
    return res.state.intrinsics[0].values, float(np.sqrt(np.mean(np.sum(res.residuals**2, axis=1))))


def one_camera_solve(obj: list, img: list, intr: Intrinsics, limit: int | None = None,
                     faces: list[float] | None = None) -> SolveResult | None:
    """Bundle adjustment of one camera on its own views (each view a frame), started from
    `intr` (its structure kept) and per-view PnP (faces: per view the sign of board z on the
    printed side, _faces); at most `limit` views (_select_views) when given. None when fewer
    than 2 views can be posed."""
    keep, Ts = [], []
    for k, r in enumerate(pnp_views(obj, img, intr.values, intr.model, faces)):
        if r is not None:
            keep.append(k)
            Ts.append(r[0])
    if len(keep) < 2:
        return None
    pos = {k: j for j, k in enumerate(keep)}
    sel = keep if limit is None else [keep[j] for j in _select_views(np.array([len(obj[k]) for k in keep]), limit)]
    P = np.concatenate([obj[k] for k in sel])
    uv = np.concatenate([img[k] for k in sel])
    frame = np.concatenate([np.full(len(obj[k]), j) for j, k in enumerate(sel)])
    obs = Observations(np.zeros(len(P), int), frame, np.zeros(len(P), int), P, uv, frame)
    state = State([replace(intr, values=intr.values.copy())], np.eye(4)[None],
                  np.array([Ts[pos[k]] for k in sel]), np.eye(4)[None])
    return bundle_adjust(obs, state, gauge_cam=0, gauge_board=0)


# ----------------------------------------------------------------------------- intrinsics structure


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
    return float(chdtri(dof, INTRINSICS_LEVEL))


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


@dataclass(frozen=True)
class OwnViews:
    """One camera's intrinsics from its own views (own_views_intrinsics): the structure
    chosen, the log, and the covariance (n, n) of the values as solved and as estimated
    freely before the choice (None when unknown)."""

    intrinsics: Intrinsics
    log: list
    cov: np.ndarray | None
    cov_free: np.ndarray | None


def own_views_intrinsics(views: list[ViewIn], corners: dict, start: Intrinsics, centre, mode: str,
                         faces: dict | None = None) -> OwnViews:
    """One camera's intrinsics from its own views alone (a rig whose frames are not rigid):
    one_camera_solve over every view from `start`, the structure imposed (--intrinsics NAME)
    or chosen (auto, select_structure) and the solve redone with it."""
    obj, img = _views_obj_img(views, corners)
    start = forced_structure(start, mode, centre)
    res = one_camera_solve(obj, img, start, faces=_faces(views, faces))
    if res is None:
        return OwnViews(start, ["own views: fewer than 2 views could be posed; intrinsics kept as fitted"], None, None)
    full = _intrinsics_cov(res)
    free, lines = None, []
    if mode == "auto" and full is not None:
        free = full
        reduced, lines = select_structure(res, 0, full, centre)
        lines = [f"own views: {x}" for x in lines]
        if reduced is not None:
            res = refit(res, 0, reduced)
            full = _intrinsics_cov(res)
    return OwnViews(res.state.intrinsics[0], lines, full, free)


def _intrinsics_cov(res: SolveResult) -> np.ndarray | None:
    """The (n, n) covariance of a one-camera solve's intrinsic values, or None (singular)."""
    cov = _covariance(res)
    return None if cov is None else intrinsics_covariance(cov[0], cov[1], res.state.intrinsics)[0]


# ----------------------------------------------------------------------------- main entry


def drop_repeated_views(views: list[ViewIn]) -> tuple[list[ViewIn], list[tuple[str, str]]]:
    """One camera's views without those whose board, corner ids and pixels repeat an
    earlier view's exactly, and the (repeat, original) frame pairs. Two photographs never
    give bit-identical corners (noise); one image copied under several names, or a camera
    whose stream froze, does. Counted as independent views, such copies shrink every sigma
    and can carry the intrinsics: one pose copied 11 times calibrated to a focal length 28 %
    off and a 174 mm baseline for 120 mm, with exit 0."""
    seen: dict[tuple, str] = {}
    kept, repeats = [], []
    for v in views:
        key = (v.board, np.asarray(v.ids).tobytes(), np.asarray(v.uv, float).tobytes())
        if key in seen:
            repeats.append((v.frame, seen[key]))
            continue
        seen[key] = v.frame
        kept.append(v)
    return kept, repeats


# A camera's guided corners are kept unless the solved rig fits them this much worse than
# the detector's (reprojection RMS over the corners both solves kept). On renders the guided
# corners fit 10-40 % better; a rise means the pass measured worse than the detector on
# these images, e.g. a lens the calibrated model does not follow locally.
GUIDED_KEEP_RATIO = 1.1


def _camera_rms(res: SolveResult, cam: np.ndarray, keep: np.ndarray, C: int) -> np.ndarray:
    """(C,) reprojection RMS px per camera at res's solution over the corners `keep` (a
    subset of res.inliers; cam: every observation's camera), nan where none: from the
    residuals the solve already holds."""
    sel = keep[res.inliers]
    c = cam[res.inliers][sel]
    e2 = np.sum(res.residuals[sel] ** 2, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.bincount(c, e2, minlength=C) / np.bincount(c, minlength=C))


def _guided_solve(res: SolveResult, obs: Observations, uv_g: np.ndarray, refined: np.ndarray, cam_names: list[str],
                  gauge_cam: int, gauge_board: int, fix) -> tuple:
    """The rig solved again on the guided corners, cameras whose guided corners fit worse
    (GUIDED_KEEP_RATIO) put back to the detector's corners. -> (result or None when no
    camera keeps its guided corners, observations, refined mask kept, solve seconds, note)."""
    C = len(cam_names)
    seconds = 0.0
    guided = [c for c in range(C) if np.any(refined & (obs.cam == c))]
    if not guided:
        return None, obs, refined, seconds, "guided refinement not used: no corner could be re-measured"
    res_g = bundle_adjust(replace(obs, uv=uv_g), res.state, gauge_cam, gauge_board, fix, inliers=res.inliers)
    seconds += res_g.seconds
    both = res.inliers & res_g.inliers
    before, after = _camera_rms(res, obs.cam, both, C), _camera_rms(res_g, obs.cam, both, C)
    worse = [c for c in guided if after[c] > GUIDED_KEEP_RATIO * before[c]]
    kept = [c for c in guided if c not in worse]
    why = "; ".join(f"{cam_names[c]}: reprojection RMS {before[c]:.3f} -> {after[c]:.3f} px, so its detector "
                    f"corners were kept" for c in worse)
    if not kept:
        return None, obs, refined, seconds, f"guided refinement not used ({why})"
    if worse:
        refined = refined & ~np.isin(obs.cam, worse)
        uv_g = np.where(refined[:, None], uv_g, obs.uv)
        res_g = bundle_adjust(replace(obs, uv=uv_g), res.state, gauge_cam, gauge_board, fix, inliers=res.inliers)
        seconds += res_g.seconds
    line = (f"guided refinement: {int(refined.sum())} of {len(refined)} corners re-measured with the calibrated "
            f"model ({', '.join(cam_names[c] for c in kept)}); the rest keep the detector's position"
            + (f" ({why})" if why else ""))
    return res_g, replace(obs, uv=uv_g), refined, seconds, line


def calibrate_views(views_in: list[ViewIn], rig: Rig, corners: dict[str, np.ndarray],
                    distortion: str = "auto", fix_intrinsics: bool = False, reference: str = "aligned",
                    progress=None, weight_corners: bool = False, rerefine: Callable | None = None,
                    intrinsics: str = "auto", faces: dict[str, float] | None = None) -> Calibration:
    """The whole calibration from detected views. corners: board name -> (N, 3) object points.

    intrinsics: auto (fx = fy and the principal point held at its declared value unless the
    data show otherwise, INTRINSICS_LEVEL) or a structure of INTRINSICS_CHOICES imposed.

    weight_corners: weight each corner by its detector sigma (ViewIn.sigma) calibrated per
    camera (weighted_solve). Off by default: measured over 10 seeds (bench.noise_limit) it
    lowers the fisheye pair's rotation error only 1.61 -> 1.48 x its bound and raises some
    pinhole pairs' errors by 12-28 % (README, Accuracy and speed).

    rerefine: `f(obs, state, cam_names, frames, boards) -> (uv, refined, sigma)` re-measures the corners once the rig
    is solved (guided.guided_uv: the cross placed by the calibrated model); the rig is then
    solved again on them. None: the detector's corners are final.

    faces: board name -> the sign of board z on its printed side (-1, OpenCV's boards, when
    absent; +1 for Kalibr's AprilGrid frame: Board.print_face)."""
    t0 = time.perf_counter()
    timings = {}
    notes: list[str] = []
    cam_names = list(rig.names)
    board_names = list(corners)
    frames = sorted({v.frame for v in views_in})
    bi = {n: i for i, n in enumerate(board_names)}
    fi = {n: i for i, n in enumerate(frames)}
    _check_reference(reference, rig)
    if intrinsics != "auto" and intrinsics not in INTRINSICS_CHOICES:
        raise InputError(f"--intrinsics: expected one of auto, {', '.join(INTRINSICS_CHOICES)}, got {intrinsics!r}")
    centres = [(rig.camera(n).intrinsics.cx, rig.camera(n).intrinsics.cy) for n in cam_names]

    by_cam = {n: [v for v in views_in if v.camera == n and len(v.ids) >= MIN_VIEW_CORNERS] for n in cam_names}
    repeats = {}
    for n in cam_names:
        by_cam[n], repeats[n] = drop_repeated_views(by_cam[n])
        if repeats[n]:
            shown = ", ".join(f"{a} = {b}" for a, b in repeats[n][:3]) + (", ..." if len(repeats[n]) > 3 else "")
            notes.append(f"{n}: {len(repeats[n])} view(s) repeat another frame's corners exactly ({shown}) and were "
                         f"used once: the same image under several names, or a frozen camera?")
    for n, vs in by_cam.items():
        nf = len({v.frame for v in vs})
        if nf == 0:
            raise CalibrationError(f"{n}: no usable board views (no board detected in any image of this camera)")
        if nf < MIN_FRAMES and not fix_intrinsics:
            again = f" (and {len(repeats[n])} exact repeats of them)" if repeats[n] else ""
            raise CalibrationError(f"{n}: boards detected in only {nf} frame(s){again}; at least {MIN_FRAMES} are "
                                   f"needed to calibrate its intrinsics (or use --fix-intrinsics to keep the "
                                   f"declared ones)")

    # 1. intrinsics + PnP per camera. Serial on purpose: OpenCV and BLAS already use every
    # core, and a thread per camera measured slower (2.3 s vs 1.8 s for 3 cameras, 2 cores).
    intr, models, selection, inits = [], [], {}, []
    raw = []
    refused = np.zeros(len(cam_names), int)  # corners of views refused at PnP
    for c, n in enumerate(cam_names):
        declared = rig.camera(n).intrinsics
        mi = init_camera(by_cam[n], corners, declared, distortion, fix_intrinsics, faces)
        inits.append(mi)
        intr.append(mi.values)
        models.append(declared.model)
        selection[n] = list(mi.log)
        if fix_intrinsics:
            misfit = fixed_intrinsics_misfit(by_cam[n], corners, declared, mi, faces)
            if misfit is not None:
                notes.append(f"{n}: {misfit}")
        for v, T in zip(by_cam[n], mi.T_cam_board):
            if T is None:  # no pose with the camera in front of the print: mirrored or garbage
                refused[c] += len(v.ids)
                continue
            raw.append(dict(cam=c, frame=fi[v.frame], board=bi[v.board], ids=np.asarray(v.ids).copy(),
                            uv=v.uv, T=T[0], rms=T[1], ambiguous=v.ambiguous, sigma=v.sigma))
    timings["intrinsics_s"] = time.perf_counter() - t0

    # 2. symmetric chessboards: consistent corner order per frame
    flips, flip_notes = resolve_flips(raw, len(cam_names), [corners[b] for b in board_names])
    notes.extend(flip_notes)
    posed = [PosedView(r["cam"], r["frame"], r["board"], r["ids"], r["uv"], r["T"], r["rms"], r["sigma"])
             for r in raw]

    # 3. pose graph; the gauge camera is the one with the most views (best conditioned)
    counts = np.bincount([p.cam for p in posed], minlength=len(cam_names))
    gauge_cam = int(np.argmax(counts))
    T_cam_body, T_body_world, T_world_board, frame_posed, gauge_board, missing_b, by_hand_eye = pose_graph(
        posed, len(cam_names), len(frames), len(board_names), gauge_cam, cam_names, board_names)
    for c in by_hand_eye:
        notes.append(f"{cam_names[c]}: no other camera sees its boards; its start came from the rig's own "
                     f"motion (hand-eye), and the joint solve placed it from there")
    for b in missing_b:
        notes.append(f"board {board_names[b]}: could not be linked to the rig; its views are not used")
    t1 = time.perf_counter()
    timings["graph_s"] = t1 - t0 - timings["intrinsics_s"]

    # 4. bundle adjustment over every corner of every usable view
    use = [p for p in posed if frame_posed[p.frame] and p.board not in missing_b]
    obs = _observations(use, corners, board_names)
    sigma_det = _detected_sigma(use)
    start = [Intrinsics(m, v.copy()) for m, v in zip(models, intr)]
    if not fix_intrinsics:
        start = [forced_structure(it, intrinsics, centres[c]) for c, it in enumerate(start)]
    state = State(start, T_cam_body, T_body_world, T_world_board)
    fix = np.full(len(cam_names), fix_intrinsics)
    own: list = [None] * len(cam_names)  # OwnViews per camera when the rig is not rigid per frame
    free_sigma: dict = {}  # camera -> intrinsic_sigmas with fx, fy, cx, cy free (where the structure was tested)
    res = bundle_adjust(obs, state, gauge_cam, gauge_board, fix)
    solve_s = res.seconds
    covariance = None  # camera_covariance() of the current `res` once computed
    unsynced = None if fix_intrinsics else rigidity_check(res, inits, cam_names)
    if unsynced is not None:
        # intrinsics from each camera's own views, then the rig with them held fixed
        notes.append(unsynced)
        st = res.state.copy()
        for c, mi in enumerate(inits):
            v, line = mi.mono()
            own[c] = own_views_intrinsics(by_cam[cam_names[c]], corners,
                                          Intrinsics(st.intrinsics[c].model, np.array(v, float)), centres[c],
                                          intrinsics, faces)
            st.intrinsics[c] = own[c].intrinsics
            if own[c].cov_free is not None:
                free_sigma[c] = intrinsic_sigmas(own[c].cov_free)
            selection[cam_names[c]].append(f"rig not rigid per frame: intrinsics {line}")
            selection[cam_names[c]].extend(own[c].log)
        fix = np.ones(len(cam_names), bool)
        res = bundle_adjust(obs, st, gauge_cam, gauge_board, fix)
        solve_s += res.seconds
    elif (distortion == "auto" or intrinsics == "auto") and not fix_intrinsics:
        t_m = time.perf_counter()  # model selection's covariance and refits are solver time too
        covariance = _covariance(res)
        reduced, logs = _reduce_models(res, covariance, centres, distortion == "auto", intrinsics == "auto")
        solve_s += time.perf_counter() - t_m
        if intrinsics == "auto" and covariance is not None:
            free_sigma = {c: intrinsic_sigmas(C) for c, C in
                          enumerate(intrinsics_covariance(covariance[0], covariance[1], res.state.intrinsics))
                          if C is not None}
        for c, log in logs.items():
            selection[cam_names[c]].extend(log)
        if reduced is not None:
            res = bundle_adjust(obs, reduced, gauge_cam, gauge_board, fix, inliers=res.inliers)
            solve_s += res.seconds
            covariance = None
    if rerefine is not None:
        t_g = time.perf_counter()
        uv_g, refined, sigma_g = rerefine(obs, res.state, cam_names, frames, board_names)
        timings["guided_s"] = time.perf_counter() - t_g
        res_g, obs_g, refined, s_g, line = _guided_solve(res, obs, uv_g, refined, cam_names, gauge_cam, gauge_board,
                                                         fix)
        solve_s += s_g
        notes.append(line)
        if res_g is not None:
            res, obs, covariance = res_g, obs_g, None
            if sigma_det is not None:
                sigma_det = np.where(refined, sigma_g, sigma_det)
    noise = None
    if weight_corners and sigma_det is not None:
        res, obs, noise, s_w = weighted_solve(res, obs, sigma_det, gauge_cam, gauge_board, fix)
        solve_s += s_w
        if obs.weight is not None:
            covariance = None
    timings["solve_s"] = solve_s
    if not res.converged:
        notes.append("bundle adjustment stopped at its iteration limit before converging")

    # 5. body frame and outputs
    T_body_cam_solve = np.array([geo.inv_T(T) for T in res.state.T_cam_body])
    T_out_solve = reference_transform(T_body_cam_solve, rig, reference)
    cov = _extrinsic_covariance(res, rig, reference, T_body_cam_solve,
                                covariance if covariance is not None else _covariance(res))
    cams = []
    stats = {}
    inl_obs = obs.subset(res.inliers)
    r_all = res.problem.residuals(res.problem.x0()).reshape(-1, 2)
    lost = [n for c, n in enumerate(cam_names) if not np.any(obs.cam[res.inliers] == c)]
    judged = _judged_rms(obs, res, fix, len(cam_names))
    gross = [_gross_rms(n, judged[c], inits[c].rms_px, rig.camera(n).intrinsics.width,
                        rig.camera(n).intrinsics.height) for c, n in enumerate(cam_names)]
    _refuse_gross_rms(gross)
    if lost:
        raise CalibrationError(f"{', '.join(lost)}: every corner was rejected as an outlier; the views of "
                               f"this camera disagree with the rest of the rig (wrong target, or a moved camera?)")
    for c, n in enumerate(cam_names):
        v = res.state.intrinsics[c].values
        declared = rig.camera(n).intrinsics
        model = declared.with_values(v)
        T_bc = T_out_solve @ T_body_cam_solve[c]
        m = inl_obs.cam == c
        rms = float(np.sqrt(np.mean(np.sum(r_all[m] ** 2, axis=1)))) if m.any() else float("nan")
        st = CameraStats(
            name=n, rms_px=rms, observations=int(m.sum()), frames=int(len(np.unique(inl_obs.frame[m]))),
            outliers=int((~res.inliers & (obs.cam == c)).sum()) + int(refused[c]),
            distortion_model=("fisheye" if model.model == "fisheye" else PINHOLE_MODEL_NAMES[len(model.dist)]),
            model_selection=selection[n])
        st.intrinsics_model = intrinsics_model(res.state.intrinsics[c], st.distortion_model, fix_intrinsics)
        if cov is not None:
            blk = cov["extrinsics"][6 * c:6 * c + 6, 6 * c:6 * c + 6]
            sd = np.sqrt(np.clip(np.diag(blk), 0, None))
            st.sigma_rotation_deg = np.degrees(sd[:3])
            st.sigma_position_mm = sd[3:] * 1000.0
            st.sigma_intrinsics = cov["intrinsics"][c]
        if st.sigma_intrinsics is None and own[c] is not None and own[c].cov is not None:
            st.sigma_intrinsics = intrinsic_sigmas(own[c].cov)
        st.sigma_intrinsics_free = free_sigma.get(c)
        stats[n] = st
        cams.append(Camera(n, model, T_bc, None))
    out_rig = replace(rig, cameras=tuple(cams))
    rms_all = float(np.sqrt(np.mean(np.sum(r_all**2, axis=1))))
    timings["total_core_s"] = time.perf_counter() - t0
    return Calibration(out_rig, stats, reference, rms_all, res.sigma_px, res.state, res.problem, obs, res.inliers,
                       frames, board_names, cam_names, T_out_solve,
                       cov["extrinsics"] if cov is not None else None, timings, notes, flips, rig,
                       sigma_det, noise)


def noise_models(res, obs: Observations, sigma_det: np.ndarray) -> list[NoiseModel | None]:
    """Each camera's NoiseModel from a solve's inlier residuals (plain px; divided by
    the solve's redundancy, its share of residual degrees of freedom)."""
    r = res.residuals
    redundancy = max(r.size - res.problem.layout.size, 1) / max(r.size, 1)
    r2 = np.sum(r**2, axis=1) / 2.0 / redundancy
    s_in, cam_in = sigma_det[res.inliers], obs.cam[res.inliers]
    return [fit_noise_model(s_in[cam_in == c], r2[cam_in == c]) for c in range(len(res.state.intrinsics))]


def weighted_solve(res, obs: Observations, sigma_det: np.ndarray, gauge_cam: int, gauge_board: int,
                   fix: np.ndarray) -> tuple:
    """The solve re-done with each corner weighted by its calibrated noise (NoiseModel).

    res: the unweighted solve, whose outlier rejection does not depend on where it started.
    Fit the models on its residuals, re-weight, solve on its inliers; judge the inliers
    once on the weighted residuals (bundle_adjust's rule); fit the models again on that
    solve's residuals, re-weight, solve on that set, frozen. Each step is a function of
    the one before, so the result is too, wherever the first solve started (an iterated
    rejection with weights could settle on either side of a corner near its threshold).
    Returns (result, observations with weights, models, seconds); unchanged and
    unweighted when no camera has enough corners with a sigma."""
    models = noise_models(res, obs, sigma_det)
    if all(m is None for m in models):
        return res, obs, models, 0.0
    seconds = 0.0
    inliers = res.inliers
    for k in range(NOISE_ROUNDS):
        if k:
            models = noise_models(res, obs, sigma_det)
            inliers = judge_inliers(obs, res.state, res.inliers, gauge_cam, gauge_board, fix)
        obs = replace(obs, weight=noise_weights(sigma_det, obs.cam, models))
        res = bundle_adjust(obs, res.state, gauge_cam, gauge_board, fix, inliers=inliers, max_rounds=0)
        seconds += res.seconds
    return res, obs, models, seconds


def rigidity_check(res, inits: list[MonoInit], cam_names: list[str]) -> str | None:
    """A note when the joint solve fits each camera's corners far worse than that camera's
    own-views fit, else None.

    One rigid rig per frame is the joint model's one extra assumption. When it holds, a
    camera's RMS in the joint solve is within some 10-20 % of its own fit (1.0-1.1x on
    the Bumblebee2, OpenCV-sample, wide-angle and trinocular real sets). Cameras triggered in software see a moving
    board at different instants (caliscope's webcams: up to 43 ms; joint 0.88 px against
    0.04-0.08 px alone); the joint solve then bends every camera's intrinsics to absorb
    the motion (focal lengths 10-16 % off). The intrinsics must then come from each
    camera's own views, as tools for such rigs do."""
    r = res.residuals
    cam = res.problem.obs.cam
    ratios = []
    for c, mi in enumerate(inits):
        m = cam == c
        if mi.rms_px is None or mi.mono is None or not m.any() or mi.rms_px <= 0:
            continue
        ratios.append((float(np.sqrt(np.mean(np.sum(r[m] ** 2, axis=1)))), mi.rms_px, cam_names[c]))
    if len(ratios) < 2:
        return None
    factor = float(np.median([j / o for j, o, _ in ratios]))
    if factor <= RIGIDITY_RATIO:
        return None
    detail = ", ".join(f"{n} {j:.2f} vs {o:.2f}" for j, o, n in ratios)
    return (f"the cameras' views disagree with one rigid rig per frame: reprojection RMS in the joint solve is "
            f"{factor:.1f}x each camera's own fit (px: {detail}); are the frames synchronised, and did the rig "
            f"stay rigid? Intrinsics were taken from each camera's own views and held fixed for the extrinsics")


def _judged_rms(obs: Observations, res: SolveResult, fix: np.ndarray, C: int) -> np.ndarray:
    """(C,) each camera's reprojection RMS px for the gross-failure test: over its inlier
    corners, or over all its corners when more than half were rejected. A camera whose
    images are mirrored can otherwise lose nearly every corner as an outlier and pass on
    the few that happen to fit."""
    pb = Problem(obs, res.state, res.problem.gauge_cam, res.problem.gauge_board, fix)
    e2 = np.sum(pb.residuals(pb.x0()).reshape(-1, 2) ** 2, axis=1)
    n_all = np.bincount(obs.cam, minlength=C)
    n_in = np.bincount(obs.cam[res.inliers], minlength=C)
    use = res.inliers | (n_in < 0.5 * n_all)[obs.cam]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.bincount(obs.cam[use], e2[use], minlength=C) / np.bincount(obs.cam[use], minlength=C))


def _gross_rms(name: str, rms: float, own_rms: float | None, width: int, height: int) -> str | None:
    """'name: RMS x px (own views y px)' when a camera's final RMS says its calibration
    failed (GROSS_RMS_*), else None. Its own views' fit tells where to look: small there,
    the rig is at fault (mirrored or unsynchronised images); large, the board or model."""
    limit = max(GROSS_RMS_MIN_PX, GROSS_RMS_FRACTION * float(np.hypot(width, height)))
    if not rms > limit:
        return None
    own = f", its own views alone {own_rms:.2f} px" if own_rms is not None else ""
    return f"{name} {rms:.1f} px (limit {limit:.1f}{own})"


def _refuse_gross_rms(gross: list[str | None]) -> None:
    gross = [g for g in gross if g is not None]
    if gross:
        raise CalibrationError(
            f"the calibration failed: reprojection RMS after the joint solve: {'; '.join(gross)}. The corners do "
            f"not fit one camera model and one rigid rig: check target.yaml (board type, squares, first_marker_id, "
            f"legacy_pattern), the camera models, mirrored or rotated images, and that the frames are "
            f"synchronised; nothing was written")


def _covariance(res) -> tuple | None:
    """camera_covariance(res), or None when the Schur complement is singular."""
    try:
        return camera_covariance(res)
    except np.linalg.LinAlgError:
        return None


def _reduce_models(res, covariance: tuple | None, centres: list, test_k3: bool = True,
                   test_structure: bool = False) -> tuple[State | None, dict[int, list[str]]]:
    """The joint solve's models reduced where the data do not support them: radtan5 without
    k3 (keep_k3) and, with test_structure, fx = fy tied and the principal point held at
    centres[c] (structure_tests) on cameras estimated freely; None when every camera keeps
    its model. covariance: _covariance(res)."""
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


def _detected_sigma(views: list[PosedView]) -> np.ndarray | None:
    """(M,) the detector's own 1-sigma of every corner in _observations' order (NaN where
    unknown), or None when no view has one."""
    if all(v.sigma is None for v in views):
        return None
    return np.concatenate([np.full(len(v.ids), np.nan) if v.sigma is None else np.asarray(v.sigma, float).ravel()
                           for v in views])


def _observations(views: list[PosedView], corners: dict, board_names: list[str]) -> Observations:
    cam = np.concatenate([np.full(len(v.ids), v.cam) for v in views])
    frame = np.concatenate([np.full(len(v.ids), v.frame) for v in views])
    board = np.concatenate([np.full(len(v.ids), v.board) for v in views])
    P = np.concatenate([corners[board_names[v.board]][v.ids] for v in views])
    uv = np.concatenate([np.asarray(v.uv, float).reshape(-1, 2) for v in views])
    view = np.concatenate([np.full(len(v.ids), k) for k, v in enumerate(views)])
    return Observations(cam, frame, board, P, uv, view)


# ----------------------------------------------------------------------------- body frame


def _check_reference(reference: str, rig: Rig) -> None:
    if reference == "aligned":
        return
    if reference.startswith("camera:"):
        name = reference.split(":", 1)[1]
        if name not in rig.names:
            raise InputError(f"--reference: camera {name!r} is not in the rig ({', '.join(rig.names)})")
        return
    raise InputError(f"--reference: expected 'aligned' or 'camera:NAME', got {reference!r}")


def reference_transform(T_body_cam_solve: np.ndarray, rig: Rig, reference: str) -> np.ndarray:
    """T_out_solve: the rigid transform that places the solved rig in the output body frame.

    aligned: least-squares fit of all declared cameras' orientations and positions
    (rotation by the polar decomposition of sum R_decl R_solve^T + sum of centred
    position outer products; translation from the centroids). camera:NAME: that
    camera keeps its declared pose exactly. No declared pose at all: the first camera's
    frame is the body frame (rig-yaml.md)."""
    declared = {c.name: c.T_body_cam for c in rig.cameras if c.T_body_cam is not None}
    names = list(rig.names)
    if reference.startswith("camera:"):
        n = reference.split(":", 1)[1]
        T_decl = declared.get(n, np.eye(4))
        return T_decl @ geo.inv_T(T_body_cam_solve[names.index(n)])
    if not declared:
        return geo.inv_T(T_body_cam_solve[0])
    idx = [names.index(n) for n in declared]
    return fit_rigid_to(T_body_cam_solve[idx], np.array([declared[names[i]] for i in idx]))


def fit_rigid_to(S: np.ndarray, D: np.ndarray) -> np.ndarray:
    """The rigid T minimising sum ||R R_S - R_D||^2 + ||R (t_S - c_S) - (t_D - c_D)||^2 over
    poses S, D (N, 4, 4): rotation by the polar decomposition of the summed rotation and
    centred-position correlations, translation from the centroids. T @ S_i ~ D_i."""
    tD, tS = D[:, :3, 3], S[:, :3, 3]
    cD, cS = tD.mean(0), tS.mean(0)
    M = np.einsum("nij,nkj->ik", D[:, :3, :3], S[:, :3, :3]) + (tD - cD).T @ (tS - cS)
    R = geo.nearest_rotation(M)
    return geo.make_T(R, cD - R @ cS)


# ----------------------------------------------------------------------------- uncertainty


def _pose_error_vector(T_body_cam: np.ndarray, T_ref: np.ndarray) -> np.ndarray:
    """6-vector of a camera pose relative to a reference pose: rotation about body axes (rad), position (m)."""
    return np.concatenate([geo.rotvec_from_R(T_body_cam[:3, :3] @ T_ref[:3, :3].T), T_body_cam[:3, 3]])


def _extrinsic_covariance(res, rig: Rig, reference: str, T_body_cam_solve: np.ndarray, covariance: tuple | None):
    """Covariance of every camera's output pose, propagated from the solver's gauge.

    The solver fixes one camera; the output frame is a function of all cameras (aligned)
    or of one (camera:NAME). Propagating the joint covariance through that function
    (numerically, over the extrinsic parameters only) gives each camera's sigma in the
    frame the user actually receives, so no camera gets a spurious zero. covariance:
    _covariance(res)."""
    if covariance is None:
        return None
    cov, intr_sl, cam_sl = covariance
    C = len(cam_sl)
    T_out = reference_transform(T_body_cam_solve, rig, reference)
    ref_poses = [T_out @ T for T in T_body_cam_solve]

    def outputs(T_cam_body: np.ndarray) -> np.ndarray:
        Tbc = np.array([geo.inv_T(T) for T in T_cam_body])
        To = reference_transform(Tbc, rig, reference)
        return np.concatenate([_pose_error_vector(To @ Tbc[c], ref_poses[c]) for c in range(C)])

    # parameters: delta (left perturbation of R_cam_body) and t_cam_body per non-gauge camera
    free = [c for c in range(C) if cam_sl[c] is not None]
    base_T = res.state.T_cam_body
    G = np.zeros((6 * C, 6 * len(free)))
    h = 1e-7
    for j, c in enumerate(free):
        for k in range(6):
            Tp, Tm = base_T.copy(), base_T.copy()
            d = np.zeros(6)
            d[k] = h
            for T, s in ((Tp, 1), (Tm, -1)):
                if k < 3:
                    T[c, :3, :3] = geo.R_from_rotvec(s * d[:3]) @ base_T[c, :3, :3]
                else:
                    T[c, :3, 3] = base_T[c, :3, 3] + s * d[3:]
            G[:, 6 * j + k] = (outputs(Tp) - outputs(Tm)) / (2 * h)
    idx = np.concatenate([np.arange(cam_sl[c].start, cam_sl[c].stop) for c in free]) if free else np.zeros(0, int)
    Ce = cov[np.ix_(idx, idx)] if len(idx) else np.zeros((0, 0))
    ext = G @ Ce @ G.T if len(idx) else np.zeros((6 * C, 6 * C))
    intr = [None if C is None else intrinsic_sigmas(C)
            for C in intrinsics_covariance(cov, intr_sl, res.state.intrinsics)]
    return {"extrinsics": ext, "intrinsics": intr}
