"""Corners near another board's edge: two boards of one image that overlap in the view.

A board hanging partly in front of another (boards on walls overlapping in perspective, a
board held up in front of one on the wall) hides the far board along the near board's
sheet edge. A far-board corner whose refinement cross reaches that edge sees the near
sheet's paper or pattern instead of its own squares: its point symmetry is broken and
the fit is pulled towards the edge (0.2-3 px on renders where the rest are within 0.03
px), by more than its own sigma says. Such corners are left out.

The edge can be anywhere between the near board's pattern and the edge of its sheet, and
the sheet's margin is not declared; so every corner whose cross (corner_fit.ARM_SQUARES
of its own squares, an AprilGrid's long arms a whole tag, plus EDGE_BLUR_PX) reaches the
band between another board's pattern outline and that outline grown by
SHEET_MARGIN_SQUARES of that board's squares is dropped. Each board's outline is placed
by its view's homography (board plane -> image, fitted to its refined corners). A corner
deep inside another board's pattern outline is kept: where it is seen, its own board is
the nearer one. The board in front keeps its corners: board A is in front of board B
when more than FRONT_RATIO times as many of B's corners that should show in the image
(B's homography) are missing inside A's grown outline as of A's inside B's (a hidden
board misses many there; the board in front only those its refinement failed on). Where
that is not clear (no corner missing, or both boards missing about as many: sheets that
cross), corners of both are dropped. Views whose regions do not come within reach of each
other are not touched (the same corners, bit for bit).

Not handled: the line where two sheets pass through each other (an occluding edge inside
both outlines), a near board too little of which shows to be detected, a view whose
outline crosses the horizon, and occluders that are not boards (a hand).
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from rigcal.core.target import Board
from rigcal.detect.corner_fit import ARM_SQUARES

# How far a board's sheet may reach past its pattern, in that board's squares (AprilGrid:
# tag pitches). Prints carry about half a square of paper; mounted boards up to a square.
SHEET_MARGIN_SQUARES = 1.0
# What the refinement sees past its cross's last samples: the bilinear sample, the 3x3
# gradient kernel and an edge's blur (px).
EDGE_BLUR_PX = 3.0
MIN_HOMOGRAPHY_CORNERS = 4
FRONT_RATIO = 2  # missing corners, hidden board : board in front, above which the order is clear


def arm_m(board: Board) -> float:
    """How far a corner's refinement samples reach along the board, metres: ARM_SQUARES
    squares (ChArUco, chessboard); an AprilGrid's long arms run to the next tag's corner."""
    if board.type == "aprilgrid":
        return float(board.square_length)
    return ARM_SQUARES * float(board.square_length)


def pattern_rect(board: Board, grow: float = 0.0) -> np.ndarray:
    """(4, 2) board-frame corners of the printed pattern grown by `grow` metres on each side."""
    w, h = board.size_m
    rect = np.array([[-grow, -grow], [w + grow, -grow], [w + grow, h + grow], [-grow, h + grow]])
    p = np.column_stack([rect, np.zeros(4), np.ones(4)]) @ board.T_board_print.T
    return p[:, :2]


def view_homography(board: Board, ids: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """(3, 3) board plane (x, y, 1) -> pixel, least squares over the view's corners; None
    for fewer than MIN_HOMOGRAPHY_CORNERS."""
    if len(ids) < MIN_HOMOGRAPHY_CORNERS:
        return None
    H, _ = cv2.findHomography(board.corners[ids, :2], np.asarray(uv, np.float64), 0)
    return H


def outline_px(H: np.ndarray, rect: np.ndarray) -> np.ndarray | None:
    """(4, 2) float32 image polygon of a board-frame rectangle under H (a homography keeps
    lines straight), None where part of it maps through the horizon (no closed outline)."""
    p = np.column_stack([rect, np.ones(len(rect))]) @ H.T
    if not (p[:, 2] > 0).all() and not (p[:, 2] < 0).all():
        return None
    return (p[:, :2] / p[:, 2:]).astype(np.float32)


def reach_px(board: Board, H: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(N,) how far each corner's refinement sees, px: arm_m along the board's longer image
    axis at the corner (H's Jacobian), plus EDGE_BLUR_PX."""
    xy = board.corners[ids, :2]
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    w = p[:, 2:]
    uv = p[:, :2] / w
    J = [(H[:2, k][None, :] - uv * H[2, k]) / w for k in (0, 1)]  # d uv / d x, d uv / d y
    scale = np.maximum(np.linalg.norm(J[0], axis=1), np.linalg.norm(J[1], axis=1))
    return arm_m(board) * scale + EDGE_BLUR_PX


def signed_distance(poly: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) distance of each point to the polygon's outline, positive inside."""
    return np.array([cv2.pointPolygonTest(poly, (float(u), float(v)), True) for u, v in uv])


def hidden_inside(board: Board, H: np.ndarray, ids: np.ndarray, poly: np.ndarray, size: tuple[int, int],
                  border: float) -> int:
    """How many of the board's corners missing from the view (ids) H puts inside the image
    (`border` px in from its edges, size (w, h)) and inside the polygon."""
    missing = np.setdiff1d(np.arange(len(board.corners)), ids)
    if not len(missing):
        return 0
    p = np.column_stack([board.corners[missing, :2], np.ones(len(missing))]) @ H.T
    front = p[:, 2] > 0
    uv = p[front, :2] / p[front, 2:]
    w, h = size
    inside = np.all((uv >= border) & (uv <= np.array([w - 1 - border, h - 1 - border])), axis=1)
    uv = uv[inside]
    return int((signed_distance(poly, uv) > 0).sum()) if len(uv) else 0


def in_reach(uv: np.ndarray, poly: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(N,) bool: the points uv (N, 2) within their reach (N,) px of the polygon's bounding box."""
    lo, hi = poly.min(0), poly.max(0)
    r = reach[:, None]
    return np.all((uv >= lo - r) & (uv <= hi + r), axis=1)


def near_other_boards(views: Sequence[tuple[Board, np.ndarray, np.ndarray]], size: tuple[int, int]
                      ) -> list[np.ndarray]:
    """Per view (board, ids, uv) of one image of size (w, h), (N,) bool: True for a corner
    whose cross reaches the edge band of another board not known to be behind it (the
    module docstring). All False for a lone view."""
    out = [np.zeros(len(ids), bool) for _, ids, _ in views]
    if len(views) < 2:
        return out
    H = [view_homography(b, ids, uv) for b, ids, uv in views]
    bands, reach = [], []
    for (b, ids, uv), h in zip(views, H):
        band = None
        if h is not None:
            inner = outline_px(h, pattern_rect(b))
            outer = outline_px(h, pattern_rect(b, SHEET_MARGIN_SQUARES * b.square_length))
            band = None if inner is None or outer is None else (inner, outer)
        bands.append(band)
        reach.append(reach_px(b, h, ids) if band is not None else None)
    near = np.zeros((len(views), len(views)), bool)
    for i, (_, _, uv) in enumerate(views):
        for j, band in enumerate(bands):
            if j != i and band is not None and bands[i] is not None:
                near[i, j] = bool(in_reach(uv, band[1], reach[i]).any())
    for i, ((b, ids, uv), h) in enumerate(zip(views, H)):
        for j in np.flatnonzero(near[i]):
            if near[j, i] and bands[j] is not None:
                i_hidden = hidden_inside(b, h, ids, bands[j][1], size, float(np.median(reach[i])))
                j_hidden = hidden_inside(views[j][0], H[j], views[j][1], bands[i][1], size,
                                         float(np.median(reach[j])))
                if j_hidden > FRONT_RATIO * i_hidden:
                    continue  # view i's board is in front of j's: j's edge is behind it
            inner, outer = bands[j]
            r = reach[i]
            k = np.flatnonzero(in_reach(uv, outer, r))
            d_out = signed_distance(outer, uv[k])
            d_in = signed_distance(inner, uv[k])
            out[i][k] |= (d_out > -r[k]) & (d_in < r[k])
    return out
