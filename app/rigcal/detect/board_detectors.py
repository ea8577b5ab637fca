"""Board detectors: every board of a target in one grey image, as OpenCV finds it, then refined.

ChArUco: ArUco markers are found once per dictionary (not once per board), with the
dictionary cut to the target's own ids, and each board interpolates its corners from
its own markers with its own CharucoDetector (legacy layout respected). When (almost)
no marker shows as printed, the inverted image is searched too (white markers on
black), so inverted prints need no key in target.yaml.
AprilGrid (Kalibr's): 36h11 tags found once for all grids (april.AprilGridGroup).
Chessboard: findChessboardCorners, falling back to findChessboardCornersSB; the corner
order is made right-handed and, for boards that are not 180-degree symmetric, turned so
the black top-left square is first. Views of symmetric boards are flagged `ambiguous`
(the solver resolves the order against the other cameras).

Each view's corners are then refined (corner_refine.refine_corners), corners whose
refinement reaches another board's edge in the image are left out (overlap.py), and
views with fewer than `min_corners` corners, or with (nearly) collinear corners, are
dropped and counted.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from rigcal.detect import april
from rigcal.detect.overlap import near_other_boards
from rigcal.detect.corner_refine import REFINE_MODES, refine_corners
from rigcal.core.target import Board, Target

SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
FLAT_STD = 2.0  # grey-level std below which an image cannot hold a board (all black / all white)
COLLINEAR_RATIO = 0.02  # second / first singular value of centred corners below which a view is a line
INVERTED_UNLESS = 4  # markers found as printed, below which the inverted image is searched too


def as_ids(x) -> np.ndarray:
    """OpenCV's id output (None or (N, 1) int32) -> (N,) int64."""
    return np.zeros(0, np.int64) if x is None else np.asarray(x, dtype=np.int64).reshape(-1)


def as_uv(x) -> np.ndarray:
    """OpenCV's corner output (None or (N, 1, 2) float32) -> (N, 2) float64."""
    return np.zeros((0, 2)) if x is None else np.asarray(x, dtype=np.float64).reshape(-1, 2)


class CharucoGroup:
    """Boards sharing one ArUco dictionary: markers are found once for all of them."""

    def __init__(self, dictionary: str, boards: Sequence[Board]):
        full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        # Identification tests every candidate against every code of the dictionary: a
        # dictionary of only the boards' ids is much faster on DICT_*_1000 (docs/accuracy.md,
        # Board detection) and finds the same markers (codes of the full dictionary are further
        # apart than the correction).
        self.ids = np.unique(np.concatenate([b.marker_ids for b in boards])).astype(np.int64)
        sub = cv2.aruco.Dictionary(np.ascontiguousarray(full.bytesList[self.ids]), full.markerSize,
                                   full.maxCorrectionBits)
        self.aruco = cv2.aruco.ArucoDetector(sub, cv2.aruco.DetectorParameters())
        self.boards = list(boards)
        self.detectors = [cv2.aruco.CharucoDetector(b.cv_board()) for b in self.boards]
        self.ranges = [(b.first_marker_id, b.first_marker_id + b.n_markers) for b in self.boards]

    def markers(self, gray: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Marker corners [(1, 4, 2)] and their ids in the full dictionary (M,)."""
        corners, idx, _ = self.aruco.detectMarkers(gray)
        ids = self.ids[as_ids(idx)]
        return [np.asarray(c, np.float32).reshape(1, 4, 2) for c in corners], ids

    def detect(self, gray: np.ndarray) -> list[tuple[Board, np.ndarray, np.ndarray]]:
        found = [self.markers(gray)]
        per_board = [self._select(found[0], r) for r in self.ranges]
        if sum(len(ids) for _, ids in per_board) < INVERTED_UNLESS:
            # (Almost) no marker: maybe the boards are printed inverted (white markers on
            # black). An image that shows a board as printed is not searched again: that
            # pass would double the cost of every multi-board image for a target that
            # mixes both kinds of print, which nobody makes.
            inv = self.markers(cv2.bitwise_not(gray))
            for k, r in enumerate(self.ranges):
                alt = self._select(inv, r)
                if len(alt[1]) > len(per_board[k][1]):
                    per_board[k] = alt
        out = []
        for board, det, (mc, mi) in zip(self.boards, self.detectors, per_board):
            if len(mi) < 2:  # a ChArUco corner needs its two neighbouring markers
                continue
            cc, ci, _, _ = det.detectBoard(gray, markerCorners=mc, markerIds=mi.astype(np.int32).reshape(-1, 1))
            ids, uv = as_ids(ci), as_uv(cc)
            if len(ids):
                out.append((board, ids, uv))
        return out

    @staticmethod
    def _select(found: tuple[list[np.ndarray], np.ndarray], rng: tuple[int, int]):
        corners, ids = found
        keep = np.flatnonzero((ids >= rng[0]) & (ids < rng[1]))
        return tuple(corners[i] for i in keep), ids[keep]


def find_chessboard(gray: np.ndarray, board: Board) -> np.ndarray | None:
    """(N, 2) inner corners in OpenCV's order, or None.

    The classic detector first: on the real sets it finds as many boards as the SB one
    or more, many times faster (docs/accuracy.md, Board detection); SB only where it fails. Both
    only seed the refinement, so their accuracy does not matter."""
    pattern = board.inner_corners
    ok, c = cv2.findChessboardCorners(gray, pattern, flags=CLASSIC_FLAGS)
    if ok:
        return as_uv(c)
    ok, c = cv2.findChessboardCornersSB(gray, pattern, flags=SB_FLAGS)
    if ok:
        return as_uv(c)
    return None


def _sample_mean(gray: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear grey values at (..., 2) points."""
    flat = pts.reshape(-1, 2).astype(np.float32)
    v = cv2.remap(gray.astype(np.float32), flat[:, 0].reshape(1, -1), flat[:, 1].reshape(1, -1),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return v.reshape(pts.shape[:-1])


def chessboard_order(gray: np.ndarray, uv: np.ndarray, board: Board) -> np.ndarray:
    """Reorder OpenCV's chessboard corners to Board.corners' ids: right-handed (board x then
    y as seen from the front), and, unless the board is 180-degree symmetric, with the
    black top-left square first (inner cell (i, j) is black when i + j is even)."""
    nx, ny = board.inner_corners
    G = uv.reshape(ny, nx, 2)
    ex = (G[:, -1] - G[:, 0]).mean(0)
    ey = (G[-1] - G[0]).mean(0)
    if ex[0] * ey[1] - ex[1] * ey[0] < 0:
        G = G[:, ::-1]
    if not board.symmetric:
        a, b, c, d = G[:-1, :-1], G[:-1, 1:], G[1:, :-1], G[1:, 1:]
        centre = (a + b + c + d) / 4.0
        # four points per cell, 30 % of the way in from each corner: clear of codes in the middle
        pts = np.stack([centre + 0.4 * (p - centre) for p in (a, b, c, d)], axis=-2)
        grey = _sample_mean(gray, pts).mean(-1)
        jj, ii = np.mgrid[0:ny - 1, 0:nx - 1]
        black = (ii + jj) % 2 == 0
        if grey[black].mean() > grey[~black].mean():
            G = G[::-1, ::-1]
    return G.reshape(-1, 2)


def is_degenerate(ids: np.ndarray, uv: np.ndarray, board: Board) -> bool:
    """True when a view's corners lie on one line: on the board (exactly) or in the image (nearly)."""
    for pts, ratio in ((board.corners[ids, :2], 1e-9), (uv, COLLINEAR_RATIO)):
        s = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
        if s[0] <= 0 or s[1] <= ratio * s[0]:
            return True
    return False


class BoardDetector:
    """Every board of a target in one grey image. Build once per process (holds OpenCV objects)."""

    def __init__(self, target: Target, min_corners: int = 6, refine: str = "symmetric"):
        if refine not in REFINE_MODES:
            raise ValueError(f"refine: expected one of {', '.join(REFINE_MODES)}, got {refine!r}")
        self.target = target
        self.min_corners = int(min_corners)
        self.refine = refine
        by_dict: dict[str, list[Board]] = {}
        for b in target.boards:
            if b.type == "charuco":
                by_dict.setdefault(b.dictionary, []).append(b)
        self.groups = [CharucoGroup(d, bs) for d, bs in by_dict.items()]
        grids = [b for b in target.boards if b.type == "aprilgrid"]
        if grids:
            self.groups.append(april.AprilGridGroup(grids))
        self.chessboards = [b for b in target.boards if b.type == "chessboard"]

    def raw(self, gray: np.ndarray) -> list[tuple[Board, np.ndarray, np.ndarray, bool]]:
        """(board, ids, uv, ambiguous) as OpenCV finds them (chessboards already reordered)."""
        out = []
        for g in self.groups:
            out.extend((b, ids, uv, False) for b, ids, uv in g.detect(gray))
        for b in self.chessboards:
            uv = find_chessboard(gray, b)
            if uv is not None:
                out.append((b, np.arange(b.n_corners, dtype=np.int64), chessboard_order(gray, uv, b), b.symmetric))
        return out

    def detect(self, gray: np.ndarray) -> tuple[list[tuple[str, np.ndarray, np.ndarray, bool]], int]:
        """Usable views (board name, ids (N,), uv (N, 2), ambiguous) and how many were dropped."""
        views, dropped = self.detect_with_sigma(gray)
        return [v[:4] for v in views], dropped

    def detect_with_sigma(self, gray: np.ndarray) -> tuple[list[tuple[str, np.ndarray, np.ndarray, bool, np.ndarray]], int]:
        """As detect, each view with (N,) its corners' own 1-sigma errors (refine_corners)."""
        if float(gray.std()) < FLAT_STD:
            return [], 0
        views, dropped = [], 0
        for board, ids, uv, amb in self.raw(gray):
            order = np.argsort(ids, kind="stable")
            ids, uv = ids[order], uv[order]
            if len(ids) < self.min_corners or is_degenerate(ids, uv, board):
                dropped += 1
                continue
            uv, ok, sigma = refine_corners(gray, board, ids, uv, self.refine)
            # A corner the refinement could not place (blurred, occluded, on the image
            # border) is ten times less accurate than the rest: leave it out.
            ids, uv, sigma = ids[ok], uv[ok], sigma[ok]
            if len(ids) < self.min_corners or is_degenerate(ids, uv, board):
                dropped += 1
                continue
            views.append((board, ids, uv, amb, sigma))
        # Corners whose cross reaches another board's edge (one board in front of another) are
        # biased towards it: leave them out (overlap.py). A no-op where boards keep apart.
        out = []
        near_edges = near_other_boards([v[:3] for v in views], gray.shape[::-1])
        for (board, ids, uv, amb, sigma), near in zip(views, near_edges):
            if near.any():
                ids, uv, sigma = ids[~near], uv[~near], sigma[~near]
                if len(ids) < self.min_corners or is_degenerate(ids, uv, board):
                    dropped += 1
                    continue
            out.append((board.name, ids, uv, amb, sigma))
        return out, dropped
