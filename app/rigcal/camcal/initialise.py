"""Each camera's start for the rig bundle adjustment, and one corner order per frame.

1. Intrinsics per camera from its own views (cv2.calibrateCamera for pinhole, seeded
   by the declared values; a one-camera bundle adjustment for fisheye), and a
   `T_cam_board` per view by PnP (init_camera); the views PnP posed are PosedViews.
2. 180-degree symmetric chessboards: each view's corner order is made consistent
   with the other cameras of its frame (the relative camera pose is the same in
   every frame; only one of the two orders agrees with it): resolve_flips.
3. When the rig is not rigid per frame, each camera's intrinsics from its own views
   alone (own_views_intrinsics).

The poses of cameras, frames and boards then come from the pose graph (pose_graph.py).
"""

from __future__ import annotations

from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable

import cv2
import numpy as np
# chdtri(k, q): the chi-square quantile with upper tail q; scipy.stats costs 1 s to import
from scipy.special import chdtri

from rigcal.core import geometry as geo
from rigcal.core.camera import PINHOLE_MODEL_NAMES, CameraModel
from rigcal.errors import CalibrationError
from rigcal.camcal.model_selection import forced_structure, keep_k3, refit, select_structure, solve_covariance
from rigcal.core.observations import BoardView
from rigcal.camcal.solve import Intrinsics, Observations, SolveResult, State, bundle_adjust, intrinsics_covariance

# views given to cv2.calibrateCamera (a start and the rational test; the joint solve uses
# every view); the rest get PnP, which keeps init linear in frames. 20 rather than 40
# halves the initialisation (0.9 -> 0.5 s on the 60-frame demo rig).
MAX_INIT_VIEWS = 20
# views given to cv2.calibrateCamera for a camera's own-views intrinsics (a rig whose frames
# are not rigid: unsynchronised cameras, a moving recording): the start of a one-camera
# solve over every view, and its k3 decision. OpenCV's solver is dense in the views: on a
# 30 s recording (600 views a camera) its 15 calls took 270 s of a 313 s calibrate.
MAX_MONO_VIEWS = 150
CHESS_FLIP_DEG = 20.0
PNP_AMBIGUITY = 1.5  # IPPE's two solutions count as ambiguous within this error ratio
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
# The rational model is chosen before the joint solve (it is the richest start); it must
# beat radtan5 by a likelihood ratio at this level, with a coefficient beyond RATIONAL_MIN_Z
# sigmas, and lower the RMS by RATIONAL_MIN_GAIN.
RATIONAL_LEVEL = 1e-4
RATIONAL_MIN_Z = 3.0
RATIONAL_MIN_GAIN = 0.05
# joint / own-views RMS beyond which a rig is judged not rigid per frame (rigidity_check)
RIGIDITY_RATIO = 3.0
MIN_VIEW_CORNERS = 4


@dataclass(frozen=True)
class PosedViews:
    """The views PnP could pose, each with its start pose: what the per-camera start learns.

    views[k] (as detected; a symmetric chessboard's ids possibly reversed by resolve_flips)
    was posed at T_cam_board[k] (4x4) with an RMS of rms_px[k] px; cam, frame, board: its
    indices into the rig's cameras, the sorted frame names and the boards."""

    views: tuple[BoardView, ...]
    cam: tuple[int, ...]
    frame: tuple[int, ...]
    board: tuple[int, ...]
    T_cam_board: tuple[np.ndarray, ...]
    rms_px: tuple[float, ...]


# ----------------------------------------------------------------------------- intrinsics

PINHOLE_FLAGS = {
    2: cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    4: cv2.CALIB_FIX_K3,
    5: 0,
    8: cv2.CALIB_RATIONAL_MODEL,
}


@dataclass(frozen=True)
class MonoFit:
    """One camera's cv2.calibrateCamera fit (fit_pinhole): values with their 1-sigma, RMS,
    corner count, per-view T_cam_board and per-view RMS."""

    values: np.ndarray  # [fx, fy, cx, cy, dist(n)]
    sigma: np.ndarray  # 1-sigma of values (from OpenCV's covariance)
    rms_px: float
    n_points: int
    T_cam_board: list  # per input view (4x4) or None
    view_rms: np.ndarray


def _select_views(n_corners: np.ndarray, limit: int) -> np.ndarray:
    """Indices of at most `limit` views, favouring many corners, spread over the sequence."""
    n = len(n_corners)
    if n <= limit:
        return np.arange(n)
    order = np.argsort(-n_corners, kind="stable")
    # take the best half of the budget by corner count, the rest evenly over time
    best = order[: limit // 2]
    rest = np.setdiff1d(np.arange(n), best)
    spread = rest[np.linspace(0, len(rest) - 1, limit - len(best)).round().astype(int)]
    return np.sort(np.concatenate([best, spread]))


@contextmanager
def opencv_one_thread():
    """Run OpenCV on one thread inside the block. cv2.calibrateCamera's parallel sums add
    per-view terms in the order threads finish, so two runs on the same corners differed
    by up to 1e-5 (relative) in weakly determined distortion terms; one thread makes a
    calibration reproducible run to run, at no measurable cost on these problem sizes."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def fit_pinhole(obj: list[np.ndarray], img: list[np.ndarray], model: CameraModel, n_dist: int) -> MonoFit:
    """cv2.calibrateCameraExtended with the given distortion length; tries Zhang's closed-form
    start and the declared intrinsics as a guess, keeps the better."""
    size = (model.width, model.height)
    objp = [o.astype(np.float32).reshape(-1, 1, 3) for o in obj]
    imgp = [i.astype(np.float32).reshape(-1, 1, 2) for i in img]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    best = None
    for guess in (False, True):
        if guess and best is not None and best[0] < 1.0:
            break  # Zhang's closed-form start fitted well; the declared guess cannot do better
        flags = PINHOLE_FLAGS[n_dist]
        K0 = model.K.copy()
        D0 = np.zeros(8 if n_dist == 8 else 5)
        if guess:
            flags |= cv2.CALIB_USE_INTRINSIC_GUESS
            d = np.array(model.dist[: min(len(model.dist), len(D0))])
            D0[: len(d)] = d
        try:
            with opencv_one_thread():
                out = cv2.calibrateCameraExtended(objp, imgp, size, K0, D0, flags=flags, criteria=crit)
        except cv2.error:
            continue
        rms, K, D, rvecs, tvecs, std_intr, _, per_view = out
        if not np.isfinite(rms) or K[0, 0] <= 0 or K[1, 1] <= 0:
            continue
        if best is None or rms < best[0] - 1e-9:
            best = (rms, K, D.ravel(), rvecs, tvecs, std_intr.ravel(), per_view.ravel())
    if best is None:
        raise CalibrationError("cv2.calibrateCamera failed on every start")
    rms, K, D, rvecs, tvecs, std, per_view = best
    dist = D[:n_dist] if n_dist != 2 else D[:2]
    values = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])
    # OpenCV's std order: fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 s1.. ; select the free ones.
    idx = {2: [0, 1], 4: [0, 1, 2, 3], 5: [0, 1, 2, 3, 4], 8: [0, 1, 2, 3, 4, 5, 6, 7]}[n_dist]
    sigma = np.concatenate([std[:4], std[4:][idx]])
    Ts = [geo.make_T(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs)]
    return MonoFit(values, sigma, float(rms), int(sum(len(o) for o in obj)), Ts, per_view)


def pnp(obj: np.ndarray, uv: np.ndarray, model_values: np.ndarray, model: str,
        rays: np.ndarray | None = None, face: float = -1.0) -> tuple[np.ndarray, float] | None:
    """T_cam_board for one view with known intrinsics: rays -> normalised points -> IPPE + LM.
    Works for fisheye too because it solves on exact unprojected rays. rays: the (N, 3)
    unprojection of uv when the caller has it (see pnp_views). face: the sign of board z on
    the printed side (-1 OpenCV's boards, +1 Kalibr's AprilGrid; camera_faces_print)."""
    if rays is None:
        rays = _camera_model(model_values, model).unproject(uv)
    front = rays[:, 2] > 0.2  # within ~78 degrees of the axis, where x/z stays well conditioned
    if front.sum() < 4:
        return None
    xn = rays[front, :2] / rays[front, 2:3]
    o = obj[front].astype(np.float64)
    best = None
    try:
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(o, xn, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return None
    errs = np.ravel(errs)[: len(rvecs)] if errs is not None and np.size(errs) >= len(rvecs) else np.zeros(len(rvecs))
    for j in np.argsort(errs, kind="stable"):
        # IPPE's second solution is the planar mirror ambiguity, usually several times worse;
        # refining it (the LM polish is 90 % of PnP's time) only pays when the two are close
        if best is not None and errs[j] > PNP_AMBIGUITY * errs.min() + 1e-12:
            break
        r, t = cv2.solvePnPRefineLM(o, xn, np.eye(3), None, rvecs[j].copy(), tvecs[j].copy())
        proj = cv2.projectPoints(o, r, t, np.eye(3), None)[0].reshape(-1, 2)
        err = float(np.sqrt(np.mean(np.sum((proj - xn) ** 2, axis=1))))
        T = geo.make_T(cv2.Rodrigues(r)[0], t.ravel())
        # the corners seen must be in front; the board's origin need not be (a fisheye sees
        # boards that reach past its side, with the origin behind it)
        in_front = bool(np.all(geo.transform(T, o)[:, 2] > 0))
        if in_front and camera_faces_print(T, face) and (best is None or err < best[1]):
            best = (T, err)
    if best is None:
        return None
    return best[0], best[1] * 0.5 * (model_values[0] + model_values[1])


def pnp_views(obj: list[np.ndarray], img: list[np.ndarray], model_values: np.ndarray,
              model: str, faces: list[float] | None = None) -> list[tuple[np.ndarray, float] | None]:
    """pnp() for every view of one camera, with one unprojection of all their corners
    (per-view unprojection was half the initialisation's time)."""
    if not img:
        return []
    rays = _camera_model(model_values, model).unproject(np.concatenate([np.reshape(i, (-1, 2)) for i in img]))
    cuts = np.cumsum([len(o) for o in obj])[:-1]
    faces = faces if faces is not None else [-1.0] * len(obj)
    return [pnp(o, i, model_values, model, r, f) for o, i, r, f in zip(obj, img, np.split(rays, cuts), faces)]


def camera_faces_print(T_cam_board: np.ndarray, face: float = -1.0) -> bool:
    """True when the camera is on the printed side of the board: for OpenCV's boards (face
    -1) board z points into the print, so the camera centre has z < 0 in board coordinates;
    Kalibr's AprilGrid frame (face +1) has z out of the print. A mirrored board (wrong ids,
    a print seen through glass) fits PnP exactly but from behind: this rejects it."""
    return float(geo.inv_T(T_cam_board)[2, 3]) * face > 0.0


def corner_residuals(obj: list[np.ndarray], img: list[np.ndarray], values: np.ndarray, model: str,
                     T_cam_board: list) -> list[np.ndarray]:
    """Per view, per corner reprojection error norms (px) for a mono fit."""
    cm = _camera_model(values, model)
    out = []
    for o, i, T in zip(obj, img, T_cam_board):
        uv, valid = cm.project(geo.transform(T, o))
        e = np.linalg.norm(uv - i, axis=1)
        out.append(np.where(valid, e, np.inf))
    return out


def inlier_masks(errors: list[np.ndarray], k: float = 5.0) -> list[np.ndarray]:
    """Corners within k robust sigmas (Rayleigh median) of the fit, per view."""
    e = np.concatenate(errors)
    sigma = np.median(e[np.isfinite(e)]) / np.sqrt(2 * np.log(2))
    return [x < k * max(sigma, 1e-3) for x in errors]


def _camera_model(values: np.ndarray, model: str, size=(1, 1)) -> CameraModel:
    return CameraModel(model, size[0], size[1], float(values[0]), float(values[1]), float(values[2]),
                       float(values[3]), tuple(float(v) for v in values[4:]))


# ----------------------------------------------------------------------------- one camera's start


def _views_obj_img(views: list[BoardView], corners: dict) -> tuple[list, list]:
    return [corners[v.board][v.ids] for v in views], [v.uv for v in views]


def _faces(views: list[BoardView], faces: dict | None) -> list[float] | None:
    """Per view the sign of board z on the printed side (initialise.camera_faces_print)."""
    return None if faces is None else [float(faces.get(v.board, -1.0)) for v in views]


@dataclass(frozen=True)
class MonoInit:
    """One camera's start: intrinsics, per-view T_cam_board (None where PnP failed), the
    model-selection log, and its own-views fit for the rigidity check (rms_px None when
    the intrinsics were not fitted; mono() gives the values it supports on its own)."""

    values: np.ndarray
    T_cam_board: list
    log: list[str]
    rms_px: float | None = None
    mono: Callable[..., tuple[np.ndarray, str]] | None = None


def init_camera(views: list[BoardView], corners: dict, declared: CameraModel, distortion: str,
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
            # refitted on the camera's views (up to MAX_MONO_VIEWS), cleaned: the k3 decision
            # is kept (radtan4 refitted where k3 is dropped), the values start
            # own_views_intrinsics' solve over every view
            keep_views = _select_views(np.array([len(o) for o in obj]), MAX_MONO_VIEWS)
            own, _, _, o_c, i_c = _clean_fit([obj[i] for i in keep_views], [img[i] for i in keep_views],
                                             declared, n)
            if distortion != "auto" or n != 5:
                return own.values, f"{PINHOLE_MODEL_NAMES[n]} (own views)"
            keep, line = keep_k3(own.values[8], own.sigma[8] ** 2)
            if keep:
                return own.values, f"radtan5 (own views; {line})"
            return fit_pinhole(o_c, i_c, declared, 4).values, f"radtan4 (own views; {line})"
    return MonoInit(values, pnp_views(obj, img, values, declared.model, _faces(views, faces)), notes, rms, mono)


def fixed_intrinsics_misfit(views: list[BoardView], corners: dict, declared: CameraModel, mi: MonoInit,
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
    # each corner's view is its index in obj: view_poses maps the solved frames back to it
    view = np.concatenate([np.full(len(obj[k]), k) for k in sel])
    obs = Observations(np.zeros(len(P), int), frame, np.zeros(len(P), int), P, uv, view)
    state = State([replace(intr, values=intr.values.copy())], np.eye(4)[None],
                  np.array([Ts[pos[k]] for k in sel]), np.eye(4)[None])
    return bundle_adjust(obs, state, gauge_cam=0, gauge_board=0)


def view_poses(res: SolveResult) -> dict[int, np.ndarray]:
    """A one_camera_solve's pose T_cam_board per view it kept (index in its obj list): each
    view is a frame of its own, the camera the body and the board the world."""
    o = res.problem.obs
    frames, first = np.unique(o.frame, return_index=True)
    return {int(o.view[i]): res.state.T_body_world[f] for f, i in zip(frames, first)}


@dataclass(frozen=True)
class OwnViews:
    """One camera's intrinsics from its own views (own_views_intrinsics): the structure
    chosen, the log, the covariance (n, n) of the values as solved and as estimated freely
    before the choice (None when unknown), and per view (frame, board) the pose T_cam_board
    solved with those intrinsics (empty when none could be solved)."""

    intrinsics: Intrinsics
    log: list
    cov: np.ndarray | None
    cov_free: np.ndarray | None
    T_cam_board: dict = field(default_factory=dict)


def own_views_intrinsics(views: list[BoardView], corners: dict, start: Intrinsics, centre, mode: str,
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
    poses = {(views[k].frame, views[k].board): T for k, T in view_poses(res).items()}
    return OwnViews(res.state.intrinsics[0], lines, full, free, poses)


def own_views_start(views: list[BoardView], corners: dict, joint: Intrinsics, distortion: str,
                    faces: dict | None = None) -> tuple[np.ndarray, str] | None:
    """The start of one pinhole camera's own-views solve (own_views_intrinsics) when a
    camera-IMU step re-estimates the intrinsics after it (calibrate_views' imu_start), and
    its log line: as MonoInit.mono()'s, from the same up to MAX_MONO_VIEWS views and the
    same k3 test (auto distortion on radtan5: Wald at K3_LEVEL, k3 dropped from the start
    where it fails), fitted by rigcal's sparse one-camera solve from the joint solve's
    intrinsics `joint` instead of OpenCV's solver, which is dense in the views (on the 30 s
    three-camera recording 0.3 s a camera against 0.6-1.5 s, the same Wald statistics to
    0.1). None when those views cannot be fitted (mono() then)."""
    obj, img = _views_obj_img(views, corners)
    keep = _select_views(np.array([len(o) for o in obj]), MAX_MONO_VIEWS)
    f = _faces(views, faces)
    res = one_camera_solve([obj[i] for i in keep], [img[i] for i in keep],
                           replace(joint, values=joint.values.copy(), tie_focal=False, hold_centre=False),
                           faces=None if f is None else [f[i] for i in keep])
    if res is None:
        return None
    values = res.state.intrinsics[0].values.copy()
    n = len(values) - 4
    if distortion != "auto" or n != 5:
        return values, f"{PINHOLE_MODEL_NAMES[n]} (own views)"
    cov = _intrinsics_cov(res)
    if cov is None:
        return None
    kept, line = keep_k3(values[8], cov[8, 8])
    return (values, f"radtan5 (own views; {line})") if kept else (values[:8], f"radtan4 (own views; {line})")


def _intrinsics_cov(res: SolveResult) -> np.ndarray | None:
    """The (n, n) covariance of a one-camera solve's intrinsic values, or None (singular)."""
    cov = solve_covariance(res)
    return None if cov is None else intrinsics_covariance(cov[0], cov[1], res.state.intrinsics)[0]


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


# ----------------------------------------------------------------------------- chessboard flips


def board_flip(corners: np.ndarray) -> np.ndarray:
    """4x4 rotation by 180 degrees about the board normal through the grid centre:
    maps corner k onto corner N-1-k for a symmetric grid."""
    c = 0.5 * (corners[0] + corners[-1])
    R = np.diag([-1.0, -1.0, 1.0])
    return geo.make_T(R, c - R @ c)


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return geo.rotation_angle_deg(Ra.T @ Rb)


@dataclass(frozen=True)
class FlipResult:
    """resolve_flips' answer: the posed views with consistent corner orders (reversed views
    get new BoardViews and T_cam_board @ board_flip), how many were reversed, and notes."""

    posed: PosedViews
    flips: int
    notes: list[str]


def resolve_flips(posed: PosedViews, n_cams: int, corners_by_board: list[np.ndarray]) -> FlipResult:
    """Make the corner order of ambiguous views (BoardView.ambiguous) consistent within each
    frame: the relative camera pose is the same in every frame, and only one of a view's
    two orders agrees with it."""
    amb = [k for k, v in enumerate(posed.views) if v.ambiguous]
    if not amb:
        return FlipResult(posed, 0, [])
    T = posed.T_cam_board
    by_frame = defaultdict(dict)  # (frame, board) -> camera -> view index
    for k in amb:
        by_frame[(posed.frame[k], posed.board[k])][posed.cam[k]] = k
    R_root, seen_count = _relative_orientations(posed, by_frame, amb, n_cams, corners_by_board)
    views, T_new = list(posed.views), list(T)
    flips = 0
    for group in by_frame.values():
        cams = sorted(group, key=lambda c: (c not in R_root, -seen_count[c]))
        a = cams[0]
        if a not in R_root:
            continue
        for c in cams[1:]:
            if c not in R_root:
                continue
            ka, kc = group[a], group[c]
            expected = R_root[a].T @ R_root[c]
            F = board_flip(corners_by_board[posed.board[ka]])
            same = (T[ka] @ geo.inv_T(T[kc]))[:3, :3]
            flip = (T[ka] @ F @ geo.inv_T(T[kc]))[:3, :3]
            if _angle_deg(expected, flip) < _angle_deg(expected, same):
                views[kc] = views[kc].reversed_order(len(corners_by_board[posed.board[kc]]))
                T_new[kc] = T[kc] @ F
                flips += 1
    notes = [f"symmetric chessboard: {flips} view(s) had their corner order reversed to agree with the other "
             f"cameras"] if flips else []
    return FlipResult(replace(posed, views=tuple(views), T_cam_board=tuple(T_new)), flips, notes)


def _relative_orientations(posed: PosedViews, by_frame: dict, amb: list[int], n_cams: int,
                           corners_by_board: list[np.ndarray]) -> tuple[dict, np.ndarray]:
    """(camera -> R_root_cam for the cameras linked to the most-seen one, views per camera):
    per camera pair the relative rotation that (nearly) every frame supports in one of its
    two orders, chained breadth-first from the root."""
    T = posed.T_cam_board
    # pairwise candidate relative poses T_a_c from every frame both see
    pair_cands = defaultdict(list)
    for group in by_frame.values():
        cams = sorted(group)
        for i, a in enumerate(cams):
            for c in cams[i + 1:]:
                ka, kc = group[a], group[c]
                F = board_flip(corners_by_board[posed.board[ka]])
                pair_cands[(a, c)].append((T[ka] @ geo.inv_T(T[kc]), T[ka] @ F @ geo.inv_T(T[kc])))
    consensus = {}
    for (a, c), cands in pair_cands.items():
        allR = [T_a_c[:3, :3] for pair in cands for T_a_c in pair]
        # the true relative rotation is supported by (nearly) every frame; its mirror by few
        scores = [sum(_angle_deg(R, s[:3, :3]) < CHESS_FLIP_DEG or _angle_deg(R, f[:3, :3]) < CHESS_FLIP_DEG
                      for s, f in cands) for R in allR]
        consensus[(a, c)] = allR[int(np.argmax(scores))]
    # BFS over cameras from the most-seen one: relative orientation to a root
    seen_count = np.bincount([posed.cam[k] for k in amb], minlength=n_cams)
    root = int(np.argmax(seen_count))
    R_root = {root: np.eye(3)}
    frontier = [root]
    while frontier:
        a = frontier.pop(0)
        for (x, y), R in consensus.items():
            for p, q, Rpq in ((x, y, R), (y, x, R.T)):
                if p == a and q not in R_root:
                    R_root[q] = R_root[p] @ Rpq
                    frontier.append(q)
    return R_root, seen_count
