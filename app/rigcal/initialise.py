"""Initial values for the rig bundle adjustment, robust to cameras that never share a view.

1. Intrinsics per camera from its own views (cv2.calibrateCamera for pinhole, seeded
   by the declared values; a one-camera bundle adjustment for fisheye), and a
   `T_cam_board` per view by PnP.
2. 180-degree symmetric chessboards: each view's corner order is made consistent
   with the other cameras of its frame (the relative camera pose is the same in
   every frame; only one of the two orders agrees with it).
3. A pose graph over cameras, frames and boards. Each view links its camera,
   frame and board through T_cam_board = T_cam_body T_body_world T_world_board.
   Starting from one camera and one board, unknown poses are set from every
   available observation at once by a robust average (chordal rotation mean with
   outlier down-weighting, median translation), so the back camera joins the front
   pair through the boards even when no frame shows one board to both. A camera whose
   boards no other camera sees is placed by the rig's own motion (hand-eye, AX = XB)
   from the frames the others posed.
"""

from __future__ import annotations

from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np

from . import geometry as geo
from .camera import CameraModel
from .errors import CalibrationError

# views given to cv2.calibrateCamera (a start and the rational test; the joint solve uses
# every view); the rest get PnP, which keeps init linear in frames. 20 rather than 40
# halves the initialisation (0.9 -> 0.5 s on the 60-frame demo rig).
MAX_INIT_VIEWS = 20
CHESS_FLIP_DEG = 20.0
PNP_AMBIGUITY = 1.5  # IPPE's two solutions count as ambiguous within this error ratio
# hand-eye start (a camera whose boards no other camera sees): posed views it needs, the
# views of one board it uses at most (pairs grow as their square), and the rotation (RMS
# over frame pairs) the rig must make about a second axis for the pose to be determined
HAND_EYE_MIN_FRAMES = 4
HAND_EYE_MAX_FRAMES = 40
HAND_EYE_MIN_SPREAD_DEG = 1.0


@dataclass(frozen=True, eq=False)
class PosedView:
    """A view with its initial pose. ids/uv as detected (ids possibly re-ordered for flips)."""

    cam: int
    frame: int
    board: int
    ids: np.ndarray
    uv: np.ndarray
    T_cam_board: np.ndarray
    rms_px: float
    sigma: np.ndarray | None = None  # (N,) the detector's own 1-sigma per corner, px (core.ViewIn)


# ----------------------------------------------------------------------------- intrinsics

PINHOLE_FLAGS = {
    2: cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    4: cv2.CALIB_FIX_K3,
    5: 0,
    8: cv2.CALIB_RATIONAL_MODEL,
}


@dataclass(frozen=True)
class MonoFit:
    values: np.ndarray  # [fx, fy, cx, cy, dist(n)]
    sigma: np.ndarray  # 1-sigma of values (from OpenCV's covariance)
    rms_px: float
    n_points: int
    T_cam_board: list  # per input view (4x4) or None
    view_rms: np.ndarray


def _select_views(n_corners: np.ndarray, limit: int, rng_seed: int = 0) -> np.ndarray:
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


# ----------------------------------------------------------------------------- chessboard flips


def board_flip(corners: np.ndarray) -> np.ndarray:
    """4x4 rotation by 180 degrees about the board normal through the grid centre:
    maps corner k onto corner N-1-k for a symmetric grid."""
    c = 0.5 * (corners[0] + corners[-1])
    R = np.diag([-1.0, -1.0, 1.0])
    return geo.make_T(R, c - R @ c)


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return geo.rotation_angle_deg(Ra.T @ Rb)


def resolve_flips(views: list[dict], n_cams: int, corners_by_board: list[np.ndarray]) -> tuple[int, list[str]]:
    """Make the corner order of ambiguous views consistent within each frame.

    views: dicts with cam, frame, board, ids, T (T_cam_board), ambiguous; modified in place.
    Returns (number of views re-ordered, notes)."""
    amb = [v for v in views if v["ambiguous"]]
    notes: list[str] = []
    if not amb:
        return 0, notes
    by_frame = defaultdict(dict)
    for v in amb:
        by_frame[(v["frame"], v["board"])][v["cam"]] = v
    # pairwise candidate relative poses T_a_c from every frame both see
    pair_cands = defaultdict(list)
    for group in by_frame.values():
        cams = sorted(group)
        for i, a in enumerate(cams):
            for c in cams[i + 1:]:
                va, vc = group[a], group[c]
                F = board_flip(corners_by_board[va["board"]])
                same = va["T"] @ geo.inv_T(vc["T"])
                flip = va["T"] @ F @ geo.inv_T(vc["T"])
                pair_cands[(a, c)].append((same, flip))
    consensus = {}
    for (a, c), cands in pair_cands.items():
        allR = [T[:3, :3] for pair in cands for T in pair]
        # the true relative rotation is supported by (nearly) every frame; its mirror by few
        scores = [sum(_angle_deg(R, s[:3, :3]) < CHESS_FLIP_DEG or _angle_deg(R, f[:3, :3]) < CHESS_FLIP_DEG
                      for s, f in cands) for R in allR]
        consensus[(a, c)] = allR[int(np.argmax(scores))]
    # BFS over cameras from the most-seen one: relative orientation to a root
    seen_count = np.bincount([v["cam"] for v in amb], minlength=n_cams)
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
    flips = 0
    for key, group in by_frame.items():
        cams = sorted(group, key=lambda c: (c not in R_root, -seen_count[c]))
        a = cams[0]
        if a not in R_root:
            continue
        for c in cams[1:]:
            if c not in R_root:
                continue
            va, vc = group[a], group[c]
            expected = R_root[a].T @ R_root[c]
            F = board_flip(corners_by_board[va["board"]])
            same = (va["T"] @ geo.inv_T(vc["T"]))[:3, :3]
            flip = (va["T"] @ F @ geo.inv_T(vc["T"]))[:3, :3]
            if _angle_deg(expected, flip) < _angle_deg(expected, same):
                n = len(corners_by_board[vc["board"]])
                vc["ids"] = n - 1 - vc["ids"]
                vc["T"] = vc["T"] @ F
                flips += 1
    if flips:
        notes.append(f"symmetric chessboard: {flips} view(s) had their corner order reversed to agree with the other cameras")
    return flips, notes


# ----------------------------------------------------------------------------- pose graph


def pose_graph(views: list[PosedView], n_cams: int, n_frames: int, n_boards: int, gauge_cam: int,
               cam_names: list[str], board_names: list[str], min_obs: int = 3):
    """Chain poses through the camera-frame-board graph with robust averages per unknown.

    Returns (T_cam_body, T_body_world, T_world_board, frame_posed, gauge_board, missing
    boards, cameras placed by hand-eye)."""
    T_bc = [None] * n_cams  # T_body_cam
    T_wB = [None] * n_frames  # T_world_body
    T_wb = [None] * n_boards  # T_world_board
    T_bc[gauge_cam] = np.eye(4)
    counts = np.bincount([v.board for v in views if v.cam == gauge_cam], minlength=n_boards)
    if counts.max() == 0:
        raise CalibrationError(f"{cam_names[gauge_cam]}: no board views to start from")
    gauge_board = int(np.argmax(counts))
    T_wb[gauge_board] = np.eye(4)
    by_frame = defaultdict(list)
    for v in views:
        by_frame[v.frame].append(v)

    def sweep(threshold: int) -> bool:
        progress = False
        # frames: T_world_body = T_world_board inv(T_cam_board) inv(T_body_cam)
        for f, vs in by_frame.items():
            if T_wB[f] is not None:
                continue
            est = [T_wb[v.board] @ geo.inv_T(v.T_cam_board) @ geo.inv_T(T_bc[v.cam])
                   for v in vs if T_bc[v.cam] is not None and T_wb[v.board] is not None]
            if est:
                T_wB[f] = geo.robust_mean_pose(np.array(est))
                progress = True
        # boards: T_world_board = T_world_body T_body_cam T_cam_board
        est_b = defaultdict(list)
        est_c = defaultdict(list)
        for v in views:
            if T_wB[v.frame] is None:
                continue
            if T_wb[v.board] is None and T_bc[v.cam] is not None:
                est_b[v.board].append(T_wB[v.frame] @ T_bc[v.cam] @ v.T_cam_board)
            # cameras: T_body_cam = inv(T_world_body) T_world_board inv(T_cam_board)
            if T_bc[v.cam] is None and T_wb[v.board] is not None:
                est_c[v.cam].append(geo.inv_T(T_wB[v.frame]) @ T_wb[v.board] @ geo.inv_T(v.T_cam_board))
        for b, est in est_b.items():
            if len(est) >= threshold:
                T_wb[b] = geo.robust_mean_pose(np.array(est))
                progress = True
        for c, est in est_c.items():
            if len(est) >= threshold:
                T_bc[c] = geo.robust_mean_pose(np.array(est))
                progress = True
        return progress

    by_hand_eye: list[int] = []

    def hand_eye_step() -> bool:
        # a camera whose boards no posed camera sees: the rig's own motion places it
        # (boards are static, dataset.md), as in robot hand-eye calibration
        for c in range(n_cams):
            if T_bc[c] is not None:
                continue
            by_board = defaultdict(list)
            for v in views:
                if v.cam == c and T_wB[v.frame] is not None:
                    by_board[v.board].append(v)
            # pairs of frames within each board (its pose is unknown but fixed)
            vs = [bv[k] for bv in by_board.values() if len(bv) >= 2
                  for k in np.linspace(0, len(bv) - 1, min(len(bv), HAND_EYE_MAX_FRAMES)).round().astype(int)]
            if len(vs) < HAND_EYE_MIN_FRAMES:
                continue
            X = hand_eye(np.array([T_wB[v.frame] for v in vs]), np.array([v.T_cam_board for v in vs]),
                         np.array([v.board for v in vs]))
            if X is not None:
                T_bc[c] = X
                by_hand_eye.append(c)
                return True
        return False

    while True:
        if sweep(min_obs):
            continue
        if sweep(1):
            continue
        if not hand_eye_step():
            break
    # The search posed each unknown from whatever was known at that moment (a frame may
    # rest on one view). Re-average everything from all views now that all is known.
    for _ in range(3):
        _refine_all(views, T_bc, T_wB, T_wb, gauge_cam, gauge_board)
    missing_c = [c for c in range(n_cams) if T_bc[c] is None]
    missing_b = [b for b in range(n_boards) if T_wb[b] is None and any(v.board == b for v in views)]
    if missing_c:
        raise CalibrationError(_disconnected_message(views, missing_c, cam_names, board_names))
    posed = np.array([T is not None for T in T_wB])
    T_cam_body = np.array([geo.inv_T(T) for T in T_bc])
    T_body_world = np.array([geo.inv_T(T) if T is not None else np.eye(4) for T in T_wB])
    T_world_board = np.array([T if T is not None else np.eye(4) for T in T_wb])
    return T_cam_body, T_body_world, T_world_board, posed, gauge_board, missing_b, by_hand_eye


def hand_eye(T_world_body: np.ndarray, T_cam_board: np.ndarray, board: np.ndarray | None = None) -> np.ndarray | None:
    """T_body_cam from one camera's views of static boards in frames whose body pose is
    known: AX = XB with A the body's motion and B the camera's between two frames that show
    it the same board (rotation axes aligned by Kabsch, then translation by least squares,
    each once re-fitted without the pairs a bad PnP spoilt). T_world_body, T_cam_board:
    (n, 4, 4); board: (n,) the board of each view (default: all one board).

    None when the rig rotated about one axis only (or barely at all): the camera's rotation
    about that axis and its position along it are then not determined."""
    i, j = np.triu_indices(len(T_world_body), 1)
    if board is not None:
        same = board[i] == board[j]
        i, j = i[same], j[same]
    if len(i) < 3:
        return None
    A = geo.inv_T(T_world_body[j]) @ T_world_body[i]
    B = T_cam_board[j] @ geo.inv_T(T_cam_board[i])
    a, b = geo.rotvecs_from_R(A[:, :3, :3]), geo.rotvecs_from_R(B[:, :3, :3])
    # the body and the camera turn by the same angle between two frames
    gap = np.abs(np.linalg.norm(a, axis=1) - np.linalg.norm(b, axis=1))
    keep = gap <= max(np.deg2rad(2.0), 3.0 * np.median(gap))
    R = None
    for _ in range(2):
        if keep.sum() < 3:
            return None
        U, S, Vt = np.linalg.svd(b[keep].T @ a[keep])
        if np.sqrt(S[1] / keep.sum()) < np.deg2rad(HAND_EYE_MIN_SPREAD_DEG):
            return None
        d = np.sign(np.linalg.det(Vt.T @ U.T))
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
        err = np.linalg.norm(a - b @ R.T, axis=1)
        keep = keep & (err <= 3.0 * np.median(err[keep]) + 1e-9)
    M = A[keep, :3, :3] - np.eye(3)
    rhs = B[keep, :3, 3] @ R.T - A[keep, :3, 3]
    t = np.linalg.lstsq(M.reshape(-1, 3), rhs.reshape(-1), rcond=None)[0]
    res = np.linalg.norm(np.einsum("nij,j->ni", M, t) - rhs, axis=1)
    ok = res <= 3.0 * np.median(res) + 1e-9
    t = np.linalg.lstsq(M[ok].reshape(-1, 3), rhs[ok].reshape(-1), rcond=None)[0]
    return geo.make_T(R, t)


def _refine_all(views, T_bc, T_wB, T_wb, gauge_cam: int, gauge_board: int) -> None:
    """One pass of robust re-averaging: frames, then boards, then cameras (gauges fixed).
    The per-view products are batched; only the averages loop, once per unknown."""
    cam = np.array([v.cam for v in views])
    frame = np.array([v.frame for v in views])
    board = np.array([v.board for v in views])
    T_cb = np.array([v.T_cam_board for v in views])

    def stacked(Ts):
        return np.array([T is not None for T in Ts]), np.array([np.eye(4) if T is None else T for T in Ts])

    known_c, Tbc = stacked(T_bc)
    known_b, Twb = stacked(T_wb)
    known_f, _ = stacked(T_wB)
    ok = known_c[cam] & known_b[board] & known_f[frame]
    est = Twb[board[ok]] @ geo.inv_T(T_cb[ok]) @ geo.inv_T(Tbc[cam[ok]])
    for f, e in _groups(frame[ok], est):
        T_wB[f] = geo.robust_mean_pose(e)
    _, TwB = stacked(T_wB)
    est_b = TwB[frame[ok]] @ Tbc[cam[ok]] @ T_cb[ok]
    est_c = geo.inv_T(TwB[frame[ok]]) @ Twb[board[ok]] @ geo.inv_T(T_cb[ok])
    for b, e in _groups(board[ok], est_b):
        if b != gauge_board:
            T_wb[b] = geo.robust_mean_pose(e)
    for c, e in _groups(cam[ok], est_c):
        if c != gauge_cam:
            T_bc[c] = geo.robust_mean_pose(e)


def _groups(keys: np.ndarray, values: np.ndarray):
    """(key, values of that key in their original order) for each distinct key, ascending."""
    order = np.argsort(keys, kind="stable")
    uniq, start = np.unique(keys[order], return_index=True)
    for k, chunk in zip(uniq, np.split(values[order], start[1:])):
        yield int(k), chunk


def camera_groups(views, n_cams: int) -> list[set[int]]:
    """Cameras linked by a shared frame or a shared (world-fixed) board, as connected
    components (union-find); cameras without views are singletons."""
    parent = list(range(n_cams))

    def root(c: int) -> int:
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    first = {}
    for v in views:
        for key in (("frame", v.frame), ("board", v.board)):
            other = first.setdefault(key, v.cam)
            parent[root(v.cam)] = root(other)
    groups: dict[int, set[int]] = defaultdict(set)
    for c in range(n_cams):
        groups[root(c)].add(c)
    return list(groups.values())


def _disconnected_message(views, missing, cam_names, board_names) -> str:
    """Why the pose graph left cameras out, naming groups rather than measuring from the
    gauge camera: when the gauge sits in the smaller group, the others are not at fault."""
    seen = {v.cam for v in views}
    groups = [g for g in camera_groups(views, len(cam_names)) if g & seen]

    def boards_of(c: int) -> str:
        return ", ".join(sorted({board_names[v.board] for v in views if v.cam == c}))

    head = "cannot connect every camera to the rig: "
    parts = [f"{cam_names[c]}: no usable board views" for c in missing if c not in seen]
    if len(groups) > 1:
        n_views = defaultdict(int)
        for v in views:
            n_views[v.cam] += 1
        main = max(groups, key=lambda g: (len(g), sum(n_views[c] for c in g)))
        names = lambda g: ", ".join(cam_names[c] for c in sorted(g))  # noqa: E731
        for g in groups:
            if g is main:
                continue
            for c in sorted(g):
                if len(g) == 1:
                    parts.append(f"{cam_names[c]}: never in a frame with another camera that sees a board, and its "
                                 f"boards ({boards_of(c)}) are seen by no other camera")
                else:
                    parts.append(f"{cam_names[c]}: linked only to {names(g - {c})}; no frame or board is shared "
                                 f"with {names(main)}")
        return head + "; ".join(parts)
    for c in missing:
        if c not in seen:
            continue
        parts.append(f"{cam_names[c]}: its boards ({boards_of(c)}) are never linked to the rest "
                     f"of the rig (no posed frame shows them to a calibrated camera), and the rig's motion "
                     f"cannot place it either (that needs {HAND_EYE_MIN_FRAMES} or more posed frames showing "
                     f"it its boards, the rig turning about two axes between them)")
    return head + "; ".join(parts)
