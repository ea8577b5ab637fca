"""Corner refinement, per board type and mode: OpenCV's corners of one view in, better
corners and each one's own 1-sigma out.

Modes (REFINE_MODES): "symmetric" (default) re-estimates every corner as the centre of
point symmetry of the image in a cross around its two edge lines (corner_fit), kept
narrower than the white gap between squares and markers, placed along the grid's local
axes and bends (corner_grid); a corner it cannot place is reported as not refined and
left out by the detector. "subpix" is cv2.cornerSubPix with a window fitted to the gap;
"none" keeps OpenCV's corners. AprilGrid corners are X-junctions refined in boxes and
crosses of their own (see refine_aprilgrid). "long-arms" is "symmetric" with every AprilGrid
corner's last pass run along the view's map of the board with the tag edges out to the next
corner (_aprilgrid_mapped): a study mode, not the default, since on a real print it moves the
corners towards their own tags (april.LONG_ARMS_BELOW_PX). How accurate each mode is, measured
against exact truth, is in the documentation (accuracy, board detection).
"""

from __future__ import annotations

import cv2
import numpy as np

from rigcal.detect import april
from rigcal.detect.corner_fit import (ARM_SQUARES, STEP_PX, cell_px, cross_offsets, image_gradients, refine_pairs,
                                      refine_symmetric)
from rigcal.detect.corner_grid import corner_grid
from rigcal.core.target import Board

REFINE_MODES = ("symmetric", "subpix", "none", "long-arms")
# A corner the AprilGrid box passes left out still places its tag's axes for the last pass
# unless it is farther than this from where the neighbouring tags' corners put it (px, or
# tag sizes): OpenCV's small-tag corners are ~1 px off and still give usable axes.
FAILED_NEAR_PX = 2.0
FAILED_NEAR_TAG = 0.05
MAX_PAIRS_PER_TAG_EDGE = 40  # AprilGrid's last pass: samples along an arm of one tag at most
# A chessboard's cross half-width in squares: keeps clear of dot codes printed inside
# white squares (BoofCV ECoCheck) while using most of a plain chessboard's edges.
CHESS_HALF = 0.2
SYMMETRIC_PASSES = 2  # the second takes the grid's axes and bends from the first's corners


def symmetric_half_width(board: Board) -> float:
    """Half-width, in squares, of the point-symmetric cross around a corner: the white gap
    between a square's edge and its marker (ChArUco), CHESS_HALF for a chessboard."""
    if board.type == "charuco":
        return 0.5 * (board.square_length - board.marker_length) / board.square_length
    return CHESS_HALF


def refine_subpix(gray: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray, half: float) -> np.ndarray:
    """cv2.cornerSubPix with a half-window of `half` squares (>= 2 px) per corner, tight criteria."""
    sq = np.minimum(np.linalg.norm(ax, axis=1), np.linalg.norm(ay, axis=1))
    win = np.clip(np.floor(np.nan_to_num(half * sq, nan=2.0)), 2, 12).astype(int)
    out = uv.astype(np.float64).copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-3)
    for w in np.unique(win):
        k = win == w
        r = cv2.cornerSubPix(gray, np.ascontiguousarray(uv[k], np.float32), (int(w), int(w)), (-1, -1), crit)
        out[k] = np.asarray(r, np.float64).reshape(-1, 2)
    return out


def refine_corners(gray: np.ndarray, board: Board, ids: np.ndarray, uv: np.ndarray,
                   mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Re-estimate a view's corners (see the module docstring): (N, 2) corners, (N,) bool,
    False where "symmetric" could not refine a corner (it keeps OpenCV's estimate), and
    (N,) each corner's own 1-sigma error in px (refine_symmetric; NaN for the other modes).

    "symmetric" runs twice: the second pass takes the grid's axes and bends from the
    corners of the first, which are ten times more accurate than OpenCV's."""
    all_ok = np.ones(len(ids), bool)
    unknown = np.full(len(ids), np.nan)
    if mode == "none" or len(ids) == 0:
        return uv, all_ok, unknown
    if board.type == "aprilgrid":
        return refine_aprilgrid(gray, board, ids, uv, mode)
    half = symmetric_half_width(board)
    if mode == "subpix":
        ax, ay = corner_grid(ids, uv, board)[:2]
        return refine_subpix(gray, uv, ax, ay, half), all_ok, unknown
    q, ok, sigma = uv, ~all_ok, unknown
    stack, origin = None, None
    for _ in range(SYMMETRIC_PASSES):
        ax, ay, bu, bv, spread = corner_grid(ids, q, board)
        if stack is None:
            # Gradients only over the view's bounding box plus the reach of its crosses.
            span_u, span_v = np.abs(ax).sum(1), np.abs(ay).sum(1)
            if np.isnan(span_u).all() or np.isnan(span_v).all():
                return uv, ~all_ok, unknown  # no corner has a grid to refine along (2-corner views)
            reach = ARM_SQUARES * (np.nanmax(span_u) + np.nanmax(span_v)) + 4.0
            if not np.isfinite(reach):
                return uv, ~all_ok, unknown
            h, w = gray.shape
            x0, y0 = (max(0, int(np.floor(uv[:, k].min() - reach))) for k in (0, 1))
            x1 = min(w, int(np.ceil(uv[:, 0].max() + reach)) + 1)
            y1 = min(h, int(np.ceil(uv[:, 1].max() + reach)) + 1)
            # The crop holds every cross with room for the gradient kernel: only true image edges cut one.
            stack, origin = image_gradients(gray[y0:y1, x0:x1]), np.array([x0, y0], float)
        q, ok, sigma = refine_symmetric(stack, q - origin, ax, ay, bu, bv, half, bend_spread=spread)
        q = q + origin
    return q, ok, sigma


def refine_aprilgrid(gray: np.ndarray, board: Board, ids: np.ndarray, uv: np.ndarray,
                     mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """refine_corners for an AprilGrid: each tag corner is an X-junction (tag border and
    corner square one colour, the gaps the other), refined as the centre of point symmetry
    like a ChArUco corner.

    OpenCV's tag corners can be several px off (a tag's outline merges with the blurred
    tips of its corner squares), outside where the symmetric fit converges; so cornerSubPix
    (window: april.symmetric_box) first brings them onto the junction, then refine_symmetric
    fits it in that box, along its own tag's homography axes (april.corner_axes). A corner
    that does not then look like a tag corner (april.looks_like_a_tag_corner: it found
    another junction) is started again from where the neighbouring tags' corners put it
    (april.neighbour_predictions), and left out if it still does not. A last pass fits
    every corner in the full cross with the lattice's bends."""
    n = len(ids)
    ax, ay = april.corner_axes(ids, uv)
    box = april.symmetric_box(board, ax, ay)
    if mode == "subpix":
        return refine_subpix(gray, uv, ax, ay, box), np.ones(n, bool), np.full(n, np.nan)
    h, w = gray.shape
    reach = 2.0 * box * float(np.nanmax(np.abs(np.concatenate([ax, ay])), initial=0.0)) + 8.0
    if not np.isfinite(reach):
        return uv, np.zeros(n, bool), np.full(n, np.nan)
    x0, y0 = (max(0, int(np.floor(uv[:, k].min() - reach))) for k in (0, 1))
    x1, y1 = min(w, int(np.ceil(uv[:, 0].max() + reach)) + 1), min(h, int(np.ceil(uv[:, 1].max() + reach)) + 1)
    crop, origin = gray[y0:y1, x0:x1], np.array([x0, y0], float)
    stack = image_gradients(crop)
    q, ok, sigma, _ = aprilgrid_box_passes(crop, stack, board, ids, uv - origin, ax, ay, box)
    # Once more. Small tags (april.LONG_ARMS_BELOW_PX; every tag in "long-arms" mode) with the tag edges out to the next
    # corner, along the view's map of the board (_aprilgrid_mapped) ...
    # The last pass's axes and bends come from the corners as refined, the failed ones
    # included where they still are near where the neighbouring tags put them. A failed fit
    # can leave a corner far off (18 px in a close pinhole view: its OpenCV quad corner),
    # which would tilt its tag's other crosses (0.5 px errors at 0.03 px sigma); nothing
    # else places those axes well enough (the neighbours' placing of the far corner, the
    # lattice of refined corners, the tag's three others: 0.04-0.28 px), so they keep the
    # box passes' result.
    pred = april.neighbour_predictions(ids, q, board, ok)
    tag_px = cell_px(ax, ay)
    far = ~ok & (np.linalg.norm(q - pred, axis=1) > np.maximum(FAILED_NEAR_PX, FAILED_NEAR_TAG * tag_px))
    placed = np.where(far[:, None], np.nan, q)
    ax2, ay2 = april.corner_axes(ids, placed)
    fine = ok & np.isfinite(ax2).all(axis=1) & np.isfinite(ay2).all(axis=1)
    size = cell_px(ax2, ay2)
    below_px = np.inf if mode == "long-arms" else april.LONG_ARMS_BELOW_PX
    small = fine & (np.nan_to_num(size, nan=np.inf) < below_px)
    if small.any():
        mapped = _aprilgrid_mapped(stack, ids[ok], q[ok], board, small[ok])
        if mapped is not None:
            f = np.flatnonzero(small)
            q3, ok3, sigma3 = mapped
            q[f[ok3]], sigma[f[ok3]] = q3[ok3], sigma3[ok3]
            fine &= ~small
    # ... the others (and every corner of a view too sparse for a map) in the full cross
    # (april.symmetric_cross), along the axes of the refined corners (OpenCV's quads are a
    # pixel or two off) with the lens's bends from the lattice of refined corners, held
    # fixed: fitting them inside so small a cross cost accuracy.
    if fine.any():
        f = np.flatnonzero(fine)
        bu, bv = (np.nan_to_num(b[f]) for b in april.lattice_bends(ids, placed, board))
        half, arm = april.symmetric_cross(board, ax2[f], ay2[f])
        q3, ok3, sigma3 = refine_symmetric(stack, q[f], ax2[f], ay2[f], bu, bv, half, arm=arm)
        q[f[ok3]], sigma[f[ok3]] = q3[ok3], sigma3[ok3]
    sigma = np.where(ok, sigma, np.nan)
    return q + origin, ok, sigma


def aprilgrid_box_passes(gray: np.ndarray, stack: np.ndarray, board: Board, ids: np.ndarray, uv: np.ndarray,
                         ax: np.ndarray, ay: np.ndarray, box: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """refine_aprilgrid's passes in the corner square's box (stack = image_gradients(gray);
    ax, ay = april.corner_axes, box = april.symmetric_box): (N, 2) corners, ok (refined and
    looking like a tag corner), sigma, and restarted ((N,) bool: placed only from where the
    neighbouring tags' corners put it)."""
    q, ok, sigma = _aprilgrid_pass(gray, stack, uv, ax, ay, box)
    contrast, normal = april.junction_contrast(gray, ids, q, ax, ay, box)
    reference = april.contrast_reference(contrast)
    ok &= contrast > max(april.MIN_CONTRAST * reference, 0.0)
    pred = april.neighbour_predictions(ids, q, board, ok)
    redo = ~ok & np.isfinite(pred).all(axis=1)
    restarted = np.zeros(len(ids), bool)
    if redo.any():
        # started again from where the neighbouring tags' corners put them
        r = np.flatnonzero(redo)
        q2, ok2, sigma2 = _aprilgrid_pass(gray, stack, pred[r], ax[r], ay[r], box)
        # the print's polarity and contrast from the first pass: the corners restarted may all be wrong
        ok2 &= april.looks_like_a_tag_corner(gray, ids[r], q2, ax[r], ay[r], box, normal, reference)
        q[r[ok2]], ok[r[ok2]], sigma[r[ok2]], restarted[r[ok2]] = q2[ok2], True, sigma2[ok2], True
    return q, ok, sigma, restarted


def _aprilgrid_mapped(stack: np.ndarray, ids: np.ndarray, uv: np.ndarray, board: Board, sel: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The last AprilGrid pass for the corners sel ((N,) bool) of a view whose refined
    corners (ids, uv) give it a map (april.view_map; None where not): each refined as the centre of point symmetry
    near the junction and of point antisymmetry along the tag edges beyond it
    (april.junction_pattern), each pair's samples at the map's images of P + d and P - d
    (a tag edge is 1 tag long against the corner square's 0.3: the lattice's own bends are
    too rough for it), the edges' offset from the junctions fitted per view
    (april.FIT_EDGE_SHIFT). Returns refine_pairs' (N, 2), ok, sigma."""
    m = april.view_map(ids, uv, board)
    if m is None:
        return None
    ids, uv = ids[sel], uv[sel]
    xy = board.corners[ids, :2]
    c0 = m(xy)
    h = 1e-3 * board.tag_size
    ax, ay = ((m(xy + step) - c0) / 1e-3 for step in ([h, 0.0], [0.0, h]))
    size = cell_px(ax, ay)
    if not np.isfinite(size).all() or size.min() <= 4.0:
        return None
    delta = max(STEP_PX / float(np.median(size)), 1.0 / MAX_PAIRS_PER_TAG_EDGE)
    cross = cross_offsets(min(april.BORDER_FRACTION, board.tag_spacing), 1.0, delta)
    w, anti = april.junction_pattern(ids, board, cross, size)
    sign = np.where(anti, -1.0, 1.0).astype(np.float32)
    inward = april.TOWARDS_TAG[ids % 4]  # (N, 2) board directions of each corner's own tag
    along_u = np.abs(cross[:, 0]) >= np.abs(cross[:, 1])
    n, k = len(ids), len(cross)

    def pairs(shift: float) -> tuple[np.ndarray, np.ndarray]:
        # the antisymmetric pairs centred on the edge lines moved `shift` (metres) towards the tag
        c = np.zeros((n, k, 2))
        c[..., 1] = np.where(anti & along_u, shift * inward[:, None, 1], 0.0)
        c[..., 0] = np.where(anti & ~along_u, shift * inward[:, None, 0], 0.0)
        off = cross * board.tag_size
        ends = m(np.concatenate([(xy[:, None, :] + c + off).reshape(-1, 2), (xy[:, None, :] + c - off).reshape(-1, 2)]))
        Dp, Dm = ends.reshape(2, n, k, 2) - c0[None, :, None]
        return Dp, Dm

    shift = 0.0
    if april.FIT_EDGE_SHIFT:
        # where the edges alone put the corners (both arms long), against the junctions
        both_arms = np.all([(anti & along_u).any(1), (anti & ~along_u).any(1)], axis=0)
        if both_arms.sum() >= 8:
            b = np.flatnonzero(both_arms)
            Dp, Dm = pairs(0.0)
            qe, oke, _ = refine_pairs(stack, uv[b], cross, Dp[b], Dm[b], anti[b].astype(np.float32), sign[b])
            J = np.stack([ax[b], ay[b]], -1)[oke]
            st = np.linalg.solve(J, (qe - uv[b])[oke][..., None])[..., 0]  # tag sizes, board axes
            if len(st) >= 8:
                shift = float(np.median(st * inward[b][oke])) * board.tag_size
    Dp, Dm = pairs(shift)
    return refine_pairs(stack, uv, cross, Dp, Dm, w.astype(np.float32), sign)


def _aprilgrid_pass(gray: np.ndarray, stack: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray,
                    box: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cornerSubPix (a window of the symmetric box) then refine_symmetric: (N, 2), ok, sigma."""
    # cornerSubPix refuses a start outside the image (a prediction past its edge)
    inside = np.all((uv >= 0) & (uv <= np.array(gray.shape[::-1]) - 1), axis=1)
    start = uv.copy()
    start[inside] = refine_subpix(gray, uv[inside], ax[inside], ay[inside], box)
    zero = np.zeros(len(uv))
    q, ok, sigma = refine_symmetric(stack, start, ax, ay, zero, zero, box, arm=box)
    return q, ok & inside, sigma
