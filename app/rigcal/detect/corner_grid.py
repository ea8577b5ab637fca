"""The local image of a board's corner grid at each detected corner: where the
point-symmetry fit (corner_fit) puts its cross.

For every corner: ax, ay, the image vectors of one square along board x and y, and
bend_u, bend_v, how far the board lines through the corner curve off their tangent
(lens distortion: a homography keeps lines straight, so perspective gives none). They
come from finite differences along the detected grid (local_grid); a corner with no
neighbour along a board axis (markers missed beside it) takes them from a quadratic fit
of the corners around it, else a homography of its nearest corners, else the view's
homography (corner_grid).
"""

from __future__ import annotations

import cv2
import numpy as np

from rigcal.core.target import Board

# Each bend is fitted with the corner (corner_fit.refine_symmetric), held to the grid's by
# a prior of spread BEND_SIGMA + BEND_REL * |bend| px per square^2 (BEND_UNKNOWN + ...
# where the grid shows none). Chosen on exact renders (pinhole, strong radial, fisheye):
# a tighter prior biases fisheye corners (the grid's bend spans +-1..2 squares, the cross
# +-0.6), none at all is noisier.
BEND_REL = 1.0
BEND_SIGMA = 1.0
BEND_UNKNOWN = 1.0
# A corner with no neighbour along a board axis takes its axes and bends from a quadratic
# fit of the detected corners within this many squares (a 5x5 block at most).
LOCAL_FIT_SQUARES = 2
LOCAL_H_CORNERS = 8  # ... else a homography of the nearest 8 corners gives its axes


def unit_normals(axis: np.ndarray) -> np.ndarray:
    """(N, 2) unit normals (the vectors turned +90 degrees) of (N, 2) image vectors; 0 for a zero vector."""
    v = np.column_stack([-axis[:, 1], axis[:, 0]])
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0)


def local_grid(ids: np.ndarray, uv: np.ndarray, grid: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """The local image of the board grid at each corner, by finite differences along the
    corner grid.

    ax, ay: image vectors of one square along board x and y (central differences;
    second-order one-sided ones at the edge of what was detected, first-order where
    only one neighbour exists). bend_u, bend_v: how far the board-x and board-y lines
    through the corner curve off their tangent per square^2, along their normals
    (half the second difference; lens distortion - a homography keeps lines straight,
    so perspective gives none), borrowed from the next corner on the line at an edge.

    ids: (N,) row-major ids on a grid of (nx, ny) corners; uv: (N, 2). Returns ax, ay
    (N, 2), NaN where the corner has no neighbour along that axis; bend_u, bend_v (N,),
    0 where the line shows no curvature; and bend_spread (N, 2), how far each bend may
    be off (px per square^2)."""
    nx, ny = grid
    G = np.full((ny + 4, nx + 4, 2), np.nan)  # two rings of padding: at(+-2) never leaves the array
    r, c = ids // nx + 2, ids % nx + 2
    G[r, c] = uv

    def along(dr: int, dc: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        at = lambda k: G[r + k * dr, c + k * dc]  # noqa: E731 - the k-th neighbour along the axis
        # fourth-order central differences where two neighbours each side exist (a
        # fisheye's lines change curvature within a square), then lower orders
        axis = (8.0 * (at(1) - at(-1)) - (at(2) - at(-2))) / 12.0
        for alt in (0.5 * (at(1) - at(-1)), -0.5 * at(2) + 2.0 * at(1) - 1.5 * at(0),
                    1.5 * at(0) - 2.0 * at(-1) + 0.5 * at(-2), at(1) - at(0), at(0) - at(-1)):
            axis = np.where(np.isnan(axis), alt, axis)
        normal = unit_normals(axis)
        bend_of = lambda second: 0.5 * np.einsum("nk,nk->n", second, normal)  # noqa: E731
        b5 = bend_of((16.0 * (at(1) + at(-1)) - (at(2) + at(-2)) - 30.0 * at(0)) / 12.0)
        b3 = bend_of(at(1) - 2.0 * at(0) + at(-1))
        b_side = bend_of(at(2) - 2.0 * at(1) + at(0))
        b_side = np.where(np.isnan(b_side), bend_of(at(0) - 2.0 * at(-1) + at(-2)), b_side)
        bend = np.where(np.isfinite(b5), b5, np.where(np.isfinite(b3), b3, b_side))
        # How far to trust it: differences over +-1..2 squares miss how the curvature
        # changes within them, which grows with the curvature itself (fisheye); one-sided
        # differences are twice as far off.
        spread = BEND_REL * np.abs(np.where(np.isfinite(b3) | np.isfinite(b5), bend, 2.0 * bend))
        spread = np.where(np.isfinite(spread), spread, BEND_UNKNOWN) + BEND_SIGMA
        return axis, np.nan_to_num(bend), spread

    ax, bend_u, spread_u = along(0, 1)
    ay, bend_v, spread_v = along(1, 0)
    return ax, ay, bend_u, bend_v, np.column_stack([spread_u, spread_v])


def homography_axes(xy_board: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """ax, ay (N, 2) from the Jacobian of the least-squares board->image homography; xy_board
    in squares. None with fewer than 4 points."""
    if len(uv) < 4:
        return None
    H, _ = cv2.findHomography(xy_board.astype(np.float64), uv.astype(np.float64), 0)
    if H is None:
        return None
    X = np.column_stack([xy_board, np.ones(len(xy_board))])
    w = X @ H[2]
    # a degenerate fit can put a point on the horizon (w = 0): its axes come out
    # non-finite and refine_corners leaves the view unrefined
    with np.errstate(divide="ignore", invalid="ignore"):
        p = (X @ H[:2].T) / w[:, None]
        # d(p)/d(x_board) = (H[:2, j] - p * H[2, j]) / w
        ax = (H[:2, 0][None] - p * H[2, 0]) / w[:, None]
        ay = (H[:2, 1][None] - p * H[2, 1]) / w[:, None]
    return ax, ay


def quadratic_axes(cr: np.ndarray, uv: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, ...]:
    """The local image of the grid at corners `at` from a quadratic fit of the detected
    corners within LOCAL_FIT_SQUARES of each (board squares): uv ~ c + J d + (d^T B d).

    A corner with no neighbour along a board axis (markers missed beside it) has no
    finite difference for it; one homography for the whole view is no substitute through
    a fisheye, whose local scale and axes change by 2x and 30 degrees across a board.

    cr: (N, 2) grid (column, row) of every detected corner; uv: (N, 2); at: (M,) rows of
    the corners to fit. Returns ax, ay (M, 2), bend_u, bend_v (M,) as local_grid's, and
    (M,) bool: False where the neighbours cannot hold a quadratic (too few, or all on
    one line); those rows are NaN."""
    d = cr[None, :, :] - cr[at, None, :]  # (M, N, 2) neighbours' offsets in squares
    near = (np.abs(d) <= LOCAL_FIT_SQUARES).all(-1)
    A = np.stack([np.ones(d.shape[:2]), d[..., 0], d[..., 1], d[..., 0] ** 2, d[..., 0] * d[..., 1],
                  d[..., 1] ** 2], axis=-1) * near[..., None]  # (M, N, 6), far corners zeroed
    H = A.transpose(0, 2, 1) @ A
    # each axis needs three distinct offsets for its curvature, and the cross term a 2-D spread
    ev = np.linalg.eigvalsh(H)
    fits = (near.sum(1) >= 8) & (ev[:, 0] > 1e-6 * np.maximum(ev[:, -1], 1e-12))
    coef = np.full((len(at), 6, 2), np.nan)
    if fits.any():
        coef[fits] = np.linalg.solve(H[fits], A[fits].transpose(0, 2, 1) @ uv[None, :, :])
    ax, ay = coef[:, 1], coef[:, 2]
    n_u = unit_normals(ax)
    n_v = unit_normals(ay)
    bend_u = np.einsum("nk,nk->n", coef[:, 3], n_u)  # half the second derivative along the line
    bend_v = np.einsum("nk,nk->n", coef[:, 5], n_v)
    return ax, ay, bend_u, bend_v, fits


def local_homography_axes(cr: np.ndarray, uv: np.ndarray, at: np.ndarray, k: int = LOCAL_H_CORNERS
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ax, ay (M, 2) at corners `at` from a homography of the k corners nearest each in
    the grid (DLT), and (M,) bool, False where those are (nearly) collinear (rows NaN).
    For corners whose neighbourhood is too sparse for quadratic_axes.

    cr: (N, 2) grid (column, row) of every detected corner; uv: (N, 2)."""
    d = cr[None, :, :] - cr[at, None, :]  # (M, N, 2)
    # nearest by the grid's ring (Chebyshev distance), the straight neighbours first
    order = np.argsort(np.abs(d).max(-1) + 1e-3 * np.linalg.norm(d, axis=-1), axis=1)[:, :min(k, len(cr))]
    x = np.take_along_axis(d, order[..., None], axis=1)  # (M, K, 2) squares
    y = uv[order] - uv[at, None, :]  # (M, K, 2) px
    s = np.sqrt(np.mean(np.sum(y ** 2, -1), axis=1, keepdims=True))[..., None]
    y = y / np.maximum(s, 1e-9)
    one = np.ones(x.shape[:2])
    X = np.stack([x[..., 0], x[..., 1], one], -1)  # (M, K, 3)
    Z = np.zeros_like(X)
    rows_u = np.concatenate([X, Z, -y[..., :1] * X], -1)
    rows_v = np.concatenate([Z, X, -y[..., 1:] * X], -1)
    _, sv, vt = np.linalg.svd(np.concatenate([rows_u, rows_v], axis=1))
    H = vt[:, -1].reshape(-1, 3, 3)
    ok = (sv[:, -2] > 1e-6 * sv[:, 0]) & (np.abs(H[:, 2, 2]) > 1e-12) & (x.shape[1] >= 4)
    # at the corner itself (board offset 0): p0 = H[:2, 2] / H[2, 2], dp/dx_j = (H[:2, j] - p0 H[2, j]) / H[2, 2]
    h22 = np.where(ok, H[:, 2, 2], 1.0)[:, None]
    p0 = H[:, :2, 2] / h22
    ax = s[:, 0] * (H[:, :2, 0] - p0 * H[:, 2, 0, None]) / h22
    ay = s[:, 0] * (H[:, :2, 1] - p0 * H[:, 2, 1, None]) / h22
    return np.where(ok[:, None], ax, np.nan), np.where(ok[:, None], ay, np.nan), ok


def corner_grid(ids: np.ndarray, uv: np.ndarray, board: Board) -> tuple[np.ndarray, ...]:
    """local_grid; where a corner has no neighbour along a board axis, its axes and bends
    come from a quadratic fit of the corners around it (quadratic_axes), else its axes
    from a homography of its nearest corners (local_homography_axes; no bend), else the
    view's homography."""
    ax, ay, bu, bv, spread = local_grid(ids, uv, board.inner_corners)
    missing = ~(np.isfinite(ax).all(1) & np.isfinite(ay).all(1))
    if not missing.any():
        return ax, ay, bu, bv, spread
    at = np.flatnonzero(missing)
    nx = board.inner_corners[0]
    cr = np.column_stack([ids % nx, ids // nx]).astype(float)
    fx, fy, fbu, fbv, fits = quadratic_axes(cr, uv, at)
    k = at[fits]
    ax[k], ay[k], bu[k], bv[k] = fx[fits], fy[fits], fbu[fits], fbv[fits]
    # as uncertain as local_grid's one-sided differences
    spread[k] = BEND_REL * 2.0 * np.abs(np.column_stack([fbu[fits], fbv[fits]])) + BEND_SIGMA
    at = at[~fits]
    if len(at):
        hx, hy, hok = local_homography_axes(cr, uv, at)
        ax[at[hok]], ay[at[hok]] = hx[hok], hy[hok]
        at = at[~hok]
    if len(at):
        h = homography_axes(board.corners[ids, :2] / board.square_length, uv)
        if h is not None:
            ax[at], ay[at] = h[0][at], h[1][at]
    return ax, ay, bu, bv, spread
