"""Start poses of every camera, frame and board: the pose graph (a stage of pipeline.py).

Each posed view links its camera, frame and board through
T_cam_board = T_cam_body T_body_world T_world_board. Starting from one camera and one
board, unknown poses are set from every available observation at once by a robust average
(chordal rotation mean with outlier down-weighting, median translation), so the back
camera joins the front pair through the boards even when no frame shows one board to
both. A camera whose boards no other camera sees is placed by the rig's own motion
(hand-eye, AX = XB) from the frames the others posed. Each step is a pure function of
the poses known so far (KnownPoses), returning the poses it adds.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import CalibrationError

# hand-eye start (a camera whose boards no other camera sees): posed views it needs, the
# views of one board it uses at most (pairs grow as their square), and the rotation (RMS
# over frame pairs) the rig must make about a second axis for the pose to be determined
HAND_EYE_MIN_FRAMES = 4
HAND_EYE_MAX_FRAMES = 40
HAND_EYE_MIN_SPREAD_DEG = 1.0
REFINE_PASSES = 3


class ViewLink(NamedTuple):
    """One posed view as an edge of the graph: the camera, frame and board it links (indices)
    and its T_cam_board (4x4, from PnP)."""

    cam: int
    frame: int
    board: int
    T_cam_board: np.ndarray


class KnownPoses(NamedTuple):
    """The poses known so far, None where still unknown: T_body_cam per camera (body = the
    gauge camera), T_world_body per frame, T_world_board per board (world = the gauge board)."""

    T_body_cam: tuple
    T_world_body: tuple
    T_world_board: tuple


@dataclass(frozen=True)
class PoseGraph:
    """The start of the joint solve: T_cam_body (C, 4, 4), T_body_world (F, 4, 4),
    T_world_board (B, 4, 4) (identity where a frame or board could not be posed),
    frame_posed (F,) bool, the gauge board, the boards no view could link to the rig, and
    the cameras placed by hand-eye."""

    T_cam_body: np.ndarray
    T_body_world: np.ndarray
    T_world_board: np.ndarray
    frame_posed: np.ndarray
    gauge_board: int
    missing_boards: list[int]
    by_hand_eye: list[int]


def pose_graph(links: Sequence[ViewLink], n_cams: int, n_frames: int, n_boards: int, gauge_cam: int,
               cam_names: list[str], board_names: list[str], min_obs: int = 3) -> PoseGraph:
    """Chain poses through the camera-frame-board graph with robust averages per unknown.

    Posed from what is known: first unknowns seen `min_obs` times, then once, then a camera
    by hand-eye; then every pose re-averaged from all views (REFINE_PASSES)."""
    known, gauge_board = _gauges(links, n_cams, n_frames, n_boards, gauge_cam, cam_names)
    by_frame = defaultdict(list)
    for v in links:
        by_frame[v.frame].append(v)
    by_hand_eye: list[int] = []
    while True:
        step = _sweep(links, by_frame, known, min_obs)
        if step is None:
            step = _sweep(links, by_frame, known, 1)
        if step is None:
            placed = _hand_eye_step(links, known)
            if placed is None:
                break
            step, c = placed
            by_hand_eye.append(c)
        known = step
    # The search posed each unknown from whatever was known at that moment (a frame may
    # rest on one view). Re-average everything from all views now that all is known.
    for _ in range(REFINE_PASSES):
        known = _refine_all(links, known, gauge_cam, gauge_board)
    missing_c = [c for c in range(n_cams) if known.T_body_cam[c] is None]
    missing_b = [b for b in range(n_boards) if known.T_world_board[b] is None and any(v.board == b for v in links)]
    if missing_c:
        raise CalibrationError(disconnected_message(links, missing_c, cam_names, board_names))
    return PoseGraph(
        T_cam_body=np.array([geo.inv_T(T) for T in known.T_body_cam]),
        T_body_world=np.array([geo.inv_T(T) if T is not None else np.eye(4) for T in known.T_world_body]),
        T_world_board=np.array([T if T is not None else np.eye(4) for T in known.T_world_board]),
        frame_posed=np.array([T is not None for T in known.T_world_body]),
        gauge_board=gauge_board, missing_boards=missing_b, by_hand_eye=by_hand_eye)


def _gauges(links: Sequence[ViewLink], n_cams: int, n_frames: int, n_boards: int, gauge_cam: int,
            cam_names: list[str]) -> tuple[KnownPoses, int]:
    """The known poses at the start (the gauge camera is the body, the board it sees most
    is the world) and that board."""
    counts = np.bincount([v.board for v in links if v.cam == gauge_cam], minlength=n_boards)
    if counts.max() == 0:
        raise CalibrationError(f"{cam_names[gauge_cam]}: no board views to start from")
    gauge_board = int(np.argmax(counts))
    T_body_cam = [None] * n_cams
    T_body_cam[gauge_cam] = np.eye(4)
    T_world_board = [None] * n_boards
    T_world_board[gauge_board] = np.eye(4)
    return KnownPoses(tuple(T_body_cam), (None,) * n_frames, tuple(T_world_board)), gauge_board


def _sweep(links: Sequence[ViewLink], by_frame: dict, known: KnownPoses, threshold: int) -> KnownPoses | None:
    """One round of posing: every unknown frame seen with a known camera and board, then
    every unknown board and camera with at least `threshold` estimates through the frames
    known now. None when nothing new could be posed."""
    T_body_cam, T_world_board = known.T_body_cam, known.T_world_board
    T_world_body = list(known.T_world_body)
    progress = False
    # frames: T_world_body = T_world_board inv(T_cam_board) inv(T_body_cam)
    for f, vs in by_frame.items():
        if T_world_body[f] is not None:
            continue
        est = [T_world_board[v.board] @ geo.inv_T(v.T_cam_board) @ geo.inv_T(T_body_cam[v.cam])
               for v in vs if T_body_cam[v.cam] is not None and T_world_board[v.board] is not None]
        if est:
            T_world_body[f] = geo.robust_mean_pose(np.array(est))
            progress = True
    # boards: T_world_board = T_world_body T_body_cam T_cam_board
    est_b = defaultdict(list)
    est_c = defaultdict(list)
    for v in links:
        if T_world_body[v.frame] is None:
            continue
        if T_world_board[v.board] is None and T_body_cam[v.cam] is not None:
            est_b[v.board].append(T_world_body[v.frame] @ T_body_cam[v.cam] @ v.T_cam_board)
        # cameras: T_body_cam = inv(T_world_body) T_world_board inv(T_cam_board)
        if T_body_cam[v.cam] is None and T_world_board[v.board] is not None:
            est_c[v.cam].append(geo.inv_T(T_world_body[v.frame]) @ T_world_board[v.board] @ geo.inv_T(v.T_cam_board))
    new_boards, new_cams = list(T_world_board), list(T_body_cam)
    for b, est in est_b.items():
        if len(est) >= threshold:
            new_boards[b] = geo.robust_mean_pose(np.array(est))
            progress = True
    for c, est in est_c.items():
        if len(est) >= threshold:
            new_cams[c] = geo.robust_mean_pose(np.array(est))
            progress = True
    return KnownPoses(tuple(new_cams), tuple(T_world_body), tuple(new_boards)) if progress else None


def _hand_eye_step(links: Sequence[ViewLink], known: KnownPoses) -> tuple[KnownPoses, int] | None:
    """The first unknown camera the rig's own motion places (boards are static, docs/formats.md#dataset),
    as in robot hand-eye calibration: (the poses with it, the camera), or None."""
    T_world_body = known.T_world_body
    for c, T in enumerate(known.T_body_cam):
        if T is not None:
            continue
        by_board = defaultdict(list)
        for v in links:
            if v.cam == c and T_world_body[v.frame] is not None:
                by_board[v.board].append(v)
        # pairs of frames within each board (its pose is unknown but fixed)
        vs = [bv[k] for bv in by_board.values() if len(bv) >= 2
              for k in np.linspace(0, len(bv) - 1, min(len(bv), HAND_EYE_MAX_FRAMES)).round().astype(int)]
        if len(vs) < HAND_EYE_MIN_FRAMES:
            continue
        X = hand_eye(np.array([T_world_body[v.frame] for v in vs]), np.array([v.T_cam_board for v in vs]),
                     np.array([v.board for v in vs]))
        if X is not None:
            cams = list(known.T_body_cam)
            cams[c] = X
            return known._replace(T_body_cam=tuple(cams)), c
    return None


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


def _stacked(Ts: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(which are known (n,) bool, the poses (n, 4, 4) with identity where unknown)."""
    return np.array([T is not None for T in Ts]), np.array([np.eye(4) if T is None else T for T in Ts])


def _refine_all(links: Sequence[ViewLink], known: KnownPoses, gauge_cam: int, gauge_board: int) -> KnownPoses:
    """One pass of robust re-averaging: frames, then boards, then cameras (gauges fixed).
    The per-view products are batched; only the averages loop, once per unknown. *_k: the
    known poses stacked (identity where unknown), T_cam_board_v: every view's."""
    cam = np.array([v.cam for v in links])
    frame = np.array([v.frame for v in links])
    board = np.array([v.board for v in links])
    T_cam_board_v = np.array([v.T_cam_board for v in links])
    known_c, T_body_cam_k = _stacked(known.T_body_cam)
    known_b, T_world_board_k = _stacked(known.T_world_board)
    known_f, _ = _stacked(known.T_world_body)
    ok = known_c[cam] & known_b[board] & known_f[frame]
    est = T_world_board_k[board[ok]] @ geo.inv_T(T_cam_board_v[ok]) @ geo.inv_T(T_body_cam_k[cam[ok]])
    T_world_body = list(known.T_world_body)
    for f, T in _robust_means(frame[ok], est).items():
        T_world_body[f] = T
    _, T_world_body_k = _stacked(tuple(T_world_body))
    est_b = T_world_body_k[frame[ok]] @ T_body_cam_k[cam[ok]] @ T_cam_board_v[ok]
    est_c = geo.inv_T(T_world_body_k[frame[ok]]) @ T_world_board_k[board[ok]] @ geo.inv_T(T_cam_board_v[ok])
    T_world_board, T_body_cam = list(known.T_world_board), list(known.T_body_cam)
    for b, e in _groups(board[ok], est_b):
        if b != gauge_board:
            T_world_board[b] = geo.robust_mean_pose(e)
    for c, e in _groups(cam[ok], est_c):
        if c != gauge_cam:
            T_body_cam[c] = geo.robust_mean_pose(e)
    return KnownPoses(tuple(T_body_cam), tuple(T_world_body), tuple(T_world_board))


def _robust_means(keys: np.ndarray, values: np.ndarray) -> dict[int, np.ndarray]:
    """{key: geo.robust_mean_pose of its values} for each distinct key (_groups), the groups
    with as many values averaged in one batch (geo.robust_mean_poses: the same numbers;
    a motion recording's 600 frames of 2-3 views each took 1.1 ms a call one by one)."""
    by_size = defaultdict(list)
    for k, chunk in _groups(keys, values):
        by_size[len(chunk)].append((k, chunk))
    out = {}
    for items in by_size.values():
        means = geo.robust_mean_poses(np.stack([chunk for _, chunk in items]))
        out.update({k: T for (k, _), T in zip(items, means)})
    return dict(sorted(out.items()))


def _groups(keys: np.ndarray, values: np.ndarray):
    """(key, values of that key in their original order) for each distinct key, ascending."""
    order = np.argsort(keys, kind="stable")
    uniq, start = np.unique(keys[order], return_index=True)
    for k, chunk in zip(uniq, np.split(values[order], start[1:])):
        yield int(k), chunk


def camera_groups(links, n_cams: int) -> list[set[int]]:
    """Cameras linked by a shared frame or a shared (world-fixed) board, as connected
    components (union-find); cameras without views are singletons. links: objects with
    cam, frame and board (ViewLink)."""
    parent = list(range(n_cams))

    def root(c: int) -> int:
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    first = {}
    for v in links:
        for key in (("frame", v.frame), ("board", v.board)):
            other = first.setdefault(key, v.cam)
            parent[root(v.cam)] = root(other)
    groups: dict[int, set[int]] = defaultdict(set)
    for c in range(n_cams):
        groups[root(c)].add(c)
    return list(groups.values())


def disconnected_message(links, missing, cam_names, board_names) -> str:
    """Why the pose graph left cameras out, naming groups rather than measuring from the
    gauge camera: when the gauge sits in the smaller group, the others are not at fault.
    links: objects with cam, frame and board (ViewLink)."""
    seen = {v.cam for v in links}
    groups = [g for g in camera_groups(links, len(cam_names)) if g & seen]

    def boards_of(c: int) -> str:
        return ", ".join(sorted({board_names[v.board] for v in links if v.cam == c}))

    head = "cannot connect every camera to the rig: "
    parts = [f"{cam_names[c]}: no usable board views" for c in missing if c not in seen]
    if len(groups) > 1:
        n_views = defaultdict(int)
        for v in links:
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
