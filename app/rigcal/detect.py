"""Board detection: every image of a dataset -> board views (corner ids and pixels).

Conventions: pixel coordinates are OpenCV's (integer = pixel centre); a view's `ids`
index its board's `Board.corners` (ChArUco: getChessboardCorners order; chessboard:
row-major inner corners, x fastest, from the corner next to the black top-left square;
AprilGrid: Kalibr's 4 * tag + k).

Pipeline per image:

1. Read (any of png/jpg/bmp/tif, 8/16-bit, grey or colour) -> 8-bit grey. Unreadable
   files are skipped and counted; flat (all-black/all-white) images skip detection.
2. ChArUco: ArUco markers are found once per dictionary (not once per board), with the
   dictionary cut to the target's own ids, and each board interpolates its corners
   from its own markers with its own CharucoDetector (legacy layout respected). When
   (almost) no marker shows as printed, the inverted image is searched too (white
   markers on black), so inverted prints need no key in target.yaml.
   AprilGrid (Kalibr's): 36h11 tags with a 2-bit border, found once for all grids
   (april.AprilGridGroup), each tag's corners named by Kalibr's ids; refined as
   X-junctions (_refine_aprilgrid), not by the ChArUco cross of step 3.
   Chessboard: findChessboardCorners, falling back to findChessboardCornersSB; the
   corner order is made right-handed and, for boards that are not 180-degree
   symmetric, turned so the black top-left square is first. Views of symmetric boards
   are flagged `ambiguous` (the solver resolves the order against the other cameras).
3. Corner refinement (`refine`): "symmetric" (default) re-estimates every corner as the
   centre of point symmetry of the image inside a cross around the corner's two edge
   lines, kept narrower than the white gap between squares and markers, with each
   arm's bend (lens distortion) and a shading gradient fitted alongside; a corner it
   cannot place is left out. The cross's axes and bends come from finite differences
   along the corner grid, or, for a corner with no neighbour along a board axis, from
   a fit of the corners around it (corner_grid). "subpix" is cv2.cornerSubPix with a window fitted to the
   gap; "none" keeps OpenCV's corners. Measured against exact truth (README, bench/
   bench_detect.py --accuracy): OpenCV's ChArUco corners are off by 0.04-0.08 px RMS
   on `rigcal simulate` renders (0.15 fisheye) with a per-view common offset of up to
   0.04 px; "symmetric" 0.011 px (0.018 fisheye), per-view offset 0.002-0.003.
   "symmetric" also estimates each corner's own 1-sigma error (BoardView.sigma: the fit's
   residual variance x its inverse normal matrix). On fisheye renders it tracks the true
   error (0.007-0.03 px); on pinhole renders it spreads 2.2x where the true error spreads
   1.3x. Calibrated per camera on the residuals (solve.NoiseModel) it can weight the
   corners, but only on request (core.calibrate_views(weight_corners=True)): it did not
   help every rig (README, Accuracy and speed).
4. Views with fewer than `min_corners` corners, or with (nearly) collinear corners,
   are dropped and counted.

Work is spread over processes (`jobs`, forkserver workers); each builds its OpenCV
detectors once from the plain Target. Output order does not depend on scheduling.
"""

from __future__ import annotations

import math
import os
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import cv2
import numpy as np

from . import april
from .observations import BoardView
from .target import Board, Target
from .workers import interrupts_deferred, pool

REFINE_MODES = ("symmetric", "subpix", "none")
SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
FLAT_STD = 2.0  # grey-level std below which an image cannot hold a board (all black / all white)
COLLINEAR_RATIO = 0.02  # second / first singular value of centred corners below which a view is a line
# Symmetric refinement: arm length in squares, blur margin kept off the markers, sampling.
ARM_SQUARES = 0.6
# The margin is 3 sigma of a typical blur (lens and the pixel's area: 0.65-0.8 px).
# At 1 px the markers' blurred edges reach into the cross (~5 % of the contrast); that
# cancels between the two sides of a frontal corner, but on a board seen at an angle
# the far side's gap is narrower: a bias towards the board's near side (0.001 px on
# surround-6 rendered rooms, 0.005 px on close wide-angle views) that moves every
# oblique board's PnP range by ~+10 ppm and the rig's scale by +200 ppm (+6 ppm at
# 2-2.5 px; bench/bias_detect.py). The cost is 5 % more corner noise on frontal
# views (a narrower cross). Where the gap is too narrow for that,
# the margin shrinks to MIN_MARGIN_PX so the cross keeps CROSS_KEEP_PX (as many corners
# are refined as before).
MARGIN_PX = 2.5
MIN_MARGIN_PX = 1.0
CROSS_KEEP_PX = 1.0
STEP_PX = 0.8
MAX_SAMPLES_PER_ARM = 24
MAX_PAIRS_PER_TAG_EDGE = 40  # AprilGrid's last pass: samples along an arm of one tag at most
# A chessboard's cross half-width in squares: keeps clear of dot codes printed inside
# white squares (BoofCV ECoCheck) while using most of a plain chessboard's edges.
CHESS_HALF = 0.2
SYMMETRIC_PASSES = 2  # the second takes the grid's axes and bends from the first's corners
# Edge bends (lens distortion): arms end where the bend displaces them by this much ...
BEND_REACH_PX = 0.3
# ... and each arm's bend is fitted with the corner, held to the grid's by a prior of
# spread BEND_SIGMA + BEND_REL * |bend| px per square^2 (BEND_UNKNOWN + ... where the
# grid shows none). Chosen on exact renders (pinhole, strong radial, fisheye): a
# tighter prior biases fisheye corners (the grid's bend spans +-1..2 squares, the
# cross +-0.6), none at all is noisier.
BEND_REL = 1.0
BEND_SIGMA = 1.0
BEND_UNKNOWN = 1.0
# A corner with no neighbour along a board axis takes its axes and bends from a quadratic
# fit of the detected corners within this many squares (a 5x5 block at most).
LOCAL_FIT_SQUARES = 2
LOCAL_H_CORNERS = 8  # ... else a homography of the nearest 8 corners gives its axes

INVERTED_UNLESS = 4  # markers found as printed, below which the inverted image is searched too
MIN_CLAIM_MARKERS = 3  # a lone decode in clutter or noise does not name a dictionary
DIAGNOSE_DICTIONARIES = (
    "DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000",
    "DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000",
    "DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000",
    "DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12",
)


@dataclass
class DetectionResult:
    views: list[BoardView]
    cameras: tuple[str, ...]
    frames: tuple[str, ...]
    image_size: dict[str, tuple[int, int]]  # per camera (w, h) as read (the first readable image)
    n_images: dict[str, int]
    unreadable: list[tuple[str, str]]  # (path, reason)
    no_board: dict[str, int]  # images read fine with no usable board
    dropped: dict[str, int]  # views dropped: too few corners or collinear
    size_mismatch: list[tuple[str, str, tuple, tuple]]  # (camera, path, got (w, h), expected (w, h))
    seconds: float
    jobs: int = 1  # worker processes actually used
    unreadable_by_camera: dict[str, int] = field(default_factory=dict)

    def views_of(self, camera: str) -> list[BoardView]:
        return [v for v in self.views if v.camera == camera]

    def summary(self) -> str:
        """A few lines for the console: per camera images, views, corners and what was skipped."""
        n = sum(self.n_images.values())
        rate = n / self.seconds if self.seconds > 0 else float("inf")
        lines = [f"detection: {n} images, {len(self.views)} board views in {self.seconds:.1f} s "
                 f"({rate:.1f} images/s, {self.jobs} process{'es' if self.jobs > 1 else ''})"]
        bad = self.unreadable_by_camera
        for cam in self.cameras:
            vs = self.views_of(cam)
            frames = len({v.frame for v in vs})
            corners = sum(len(v.ids) for v in vs)
            amb = sum(v.ambiguous for v in vs)
            extra = [f"{self.no_board.get(cam, 0)} without a board"]
            if self.dropped.get(cam, 0):
                n = self.dropped[cam]
                extra.append(f"{n} view{'s' if n != 1 else ''} dropped (too few or collinear corners)")
            if bad.get(cam):
                extra.append(f"{bad[cam]} unreadable")
            if amb:
                extra.append(f"{amb} with a 180-degree ambiguous order")
            size = self.image_size.get(cam)
            size_s = f"{size[0]}x{size[1]}" if size else "-"
            lines.append(f"  {cam}: {self.n_images.get(cam, 0)} images ({size_s}), {len(vs)} views in {frames} "
                         f"frames, {corners} corners; " + ", ".join(extra))
        for path, reason in self.unreadable:
            lines.append(f"  skipped {path}: {reason}")
        for cam, path, got, expected in self.size_mismatch:
            lines.append(f"  {path}: camera {cam}: {got[0]}x{got[1]}, rig says {expected[0]}x{expected[1]}")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- reading


def read_gray(path: str | Path) -> tuple[np.ndarray | None, str | None]:
    """8-bit grey image of a file, or (None, reason). Never raises for a bad file.

    16-bit and float images are scaled by their maximum (a 12-bit sensor in a 16-bit
    container keeps its contrast); colour is converted with OpenCV's luma weights."""
    try:
        buf = np.fromfile(str(path), dtype=np.uint8)
    except FileNotFoundError:
        return None, "file not found (broken link?)"
    except OSError as e:
        return None, f"cannot read ({e.strerror or e})"
    if buf.size == 0:
        return None, "empty file"
    if buf[:8].tobytes() == PNG_SIGNATURE:
        problem = png_problem(buf.data)
        if problem is not None:
            return None, problem
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if img is None or img.size == 0:
        return None, "not a readable image (truncated or corrupt?)"
    return to_gray8(img), None


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: memoryview | bytes) -> str | None:
    """Why libpng would refuse this PNG file, or None. Checked before decoding because
    libpng reports a truncated or damaged file on the process's stderr by itself (one
    'libpng error' line per image, past any logging setting), and the file is skipped
    with a warning anyway. Walks the chunks up to IEND: each must be whole, and a
    critical one (upper-case first letter) must match its CRC; libpng only warns about
    and drops a damaged ancillary chunk."""
    data = memoryview(data).cast("B")
    pos, n = len(PNG_SIGNATURE), len(data)
    while pos + 12 <= n:
        length = int.from_bytes(data[pos:pos + 4], "big")
        end = pos + 12 + length
        if end > n:
            break
        kind = bytes(data[pos + 4:pos + 8])
        critical = not kind[0] & 0x20
        if critical and zlib.crc32(data[pos + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            return f"corrupt PNG (the {kind.decode('latin-1')!r} chunk fails its CRC check)"
        if kind == b"IEND":
            return None
        pos = end
    return "truncated PNG (the file ends before its IEND chunk)"


def to_gray8(img: np.ndarray) -> np.ndarray:
    """Any decoded image (H, W[, C]) of any depth -> uint8 (H, W).

    Signed data (a TIFF of int16 or float with negatives) is stretched from its minimum."""
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)  # cvtColor takes 8U, 16U and 32F only (a float64 colour TIFF)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            img = cv2.cvtColor(img[:, :, :4] if img.shape[2] > 4 else img, code)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    f = img.astype(np.float32)
    f[~np.isfinite(f)] = 0
    low = min(float(f.min()), 0.0) if f.size else 0.0
    top = float(f.max()) - low if f.size else 0.0
    if top <= 0:
        return np.zeros(img.shape[:2], np.uint8)
    return np.clip((f - low) * (255.0 / top) + 0.5, 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- corner geometry


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
        normal = _unit(np.column_stack([-axis[:, 1], axis[:, 0]]))
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
    n_u = _unit(np.column_stack([-ax[:, 1], ax[:, 0]]))
    n_v = _unit(np.column_stack([-ay[:, 1], ay[:, 0]]))
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


def symmetric_half_width(board: Board) -> float:
    """Half-width, in squares, of the point-symmetric cross around a corner: the white gap
    between a square's edge and its marker (ChArUco), CHESS_HALF for a chessboard."""
    if board.type == "charuco":
        return 0.5 * (board.square_length - board.marker_length) / board.square_length
    return CHESS_HALF


def _cross_offsets(half: float, arm: float, delta: float) -> np.ndarray:
    """(P, 2) offsets (u, v) in squares on a delta grid inside the cross |u| <= half or
    |v| <= half, |u|, |v| <= arm; one of each +-d pair (v > 0, or v == 0 and u > 0)."""
    k = int(math.ceil(arm / delta))
    t = np.arange(-k, k + 1) * delta
    U, V = np.meshgrid(t, t)
    U, V = U.ravel(), V.ravel()
    keep = ((np.abs(U) <= half) | (np.abs(V) <= half)) & ((V > 0) | ((V == 0) & (U > 0)))
    return np.column_stack([U[keep], V[keep]])


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0)


def image_gradients(gray: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: grey, d/dx, d/dy (Scharr, per pixel), stacked for one remap per sample set."""
    f = gray.astype(np.float32)
    gx = cv2.Scharr(f, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
    gy = cv2.Scharr(f, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
    return cv2.merge([f, gx, gy])


def symmetry_terms(stack: np.ndarray, xp: np.ndarray, yp: np.ndarray, xm: np.ndarray, ym: np.ndarray,
                   shading: np.ndarray, u: np.ndarray, v: np.ndarray, sign: np.ndarray | None = None
                   ) -> tuple[np.ndarray, ...]:
    """One Gauss-Newton evaluation of a point-symmetry fit, wherever its sample pairs were put:
    (xp, yp) and (xm, ym) (A, P) float32 pixels of the two halves of each pair, shading (A, 2)
    the gradient s, u, v (1, P) float32 the pairs' offsets in squares. Returns r (A, P) =
    I(+) - I(-) - (I(+) + I(-)) s.d, the Jacobian columns for the corner's x, y and s_u, s_v,
    and inside (A, P): both halves in the image (pairs outside are given no weight).

    sign (A, P) float32, +1 or -1 per pair, when given: -1 marks a point-antisymmetric pair
    (black against white: I(+) + I(-) is the sum of the two grey levels), whose r is
    I(+) + I(-) - (I(+) - I(-)) s.d; the caller fits that sum (refine_pairs)."""
    h, wid = stack.shape[:2]
    inside = ((np.minimum(xp, xm) >= 0) & (np.maximum(xp, xm) <= wid - 1)
              & (np.minimum(yp, ym) >= 0) & (np.maximum(yp, ym) <= h - 1))
    sp = cv2.remap(stack, xp, yp, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    sm = cv2.remap(stack, xm, ym, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if sign is not None:
        sm = sm * sign[..., None]
    both = sp[..., 0] + sm[..., 0]
    shade = (shading[:, 0, None] * u + shading[:, 1, None] * v).astype(np.float32)
    r = sp[..., 0] - sm[..., 0] - both * shade
    cols = [sp[..., 1] - sm[..., 1], sp[..., 2] - sm[..., 2], -both * u, -both * v]
    return r, cols, inside


def normal_equations(cols: list, r: np.ndarray, wa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J^T W J + 1e-9 I, J^T W r) per corner, float64, J the stacked columns."""
    J = np.stack(cols, axis=-1)
    Jw = (J * wa[..., None]).transpose(0, 2, 1)  # (A, n_par, P)
    H = (Jw @ J).astype(np.float64)  # batched matmul: several times faster than einsum here
    g = (Jw @ r[..., None])[..., 0].astype(np.float64)
    return H + 1e-9 * np.eye(len(cols)), g


def newton_steps(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched Gauss-Newton steps -H^-1 g: (steps, bad), a zero step where a system is
    singular or its step not finite."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        try:
            step = -np.linalg.solve(H, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.full(g.shape, np.nan)
    bad = ~np.isfinite(step).all(1)
    return np.where(bad[:, None], 0.0, step), bad


def corner_covariance(H: np.ndarray, wa: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(K, 2, 2) a point-symmetry fit's covariance of its corner where it stopped: the
    residual variance (per degree of freedom) x (J^T W J)^-1's corner block; NaN if singular."""
    var = (wa * r * r).sum(1) / np.maximum(wa.sum(1) - H.shape[-1], 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        try:
            Hq = np.linalg.inv(H)[:, :2, :2]
        except np.linalg.LinAlgError:
            Hq = np.full((len(H), 2, 2), np.nan)
    return var[:, None, None] * Hq


class FitProgress:
    """Per-corner bookkeeping of a batched point-symmetry fit (refine_symmetric,
    guided.refine_guided): the corners still moving (act), those whose step failed
    (singular or not finite), those that stopped, whether at least half the cross lay in the
    image (full), and each corner's covariance where it stopped."""

    def __init__(self, m: int):
        self.act = np.arange(m)
        self.done, self.failed, self.full = (np.zeros(m, bool) for _ in range(3))
        self.cov_q = np.full((m, 2, 2), np.nan)

    def retire(self, step: np.ndarray, bad: np.ndarray, H: np.ndarray, wa: np.ndarray, r: np.ndarray,
               tol: float) -> bool:
        """After a step of the corners in act: those whose step failed or moved the corner by
        under tol stop. The covariance is the fit's own, residual variance x (J^T W J)^-1,
        inverted only for the corners that stopped (not every corner at every iteration).
        True while some corner still moves."""
        act = self.act
        self.failed[act[bad]] = True
        stop = bad | (np.abs(step[:, :2]).max(1) < tol)
        fin = stop & ~bad
        if fin.any():
            self.cov_q[act[fin]] = corner_covariance(H[fin], wa[fin], r[fin])
        self.done[act[stop]] = True
        self.act = act[~stop]
        return len(self.act) > 0

    def store(self, out: np.ndarray, ok: np.ndarray, sigma: np.ndarray, idx: np.ndarray, q: np.ndarray,
              near: np.ndarray) -> None:
        """Write the corners idx that converged, had their cross mostly inside the image and
        stayed `near` their start into out, ok and sigma (px per axis); the rest keep theirs."""
        accept = self.done & ~self.failed & self.full & near
        out[idx[accept]] = q[accept]
        ok[idx[accept]] = True
        sigma[idx[accept]] = np.sqrt(0.5 * np.trace(self.cov_q[accept], axis1=1, axis2=2))


def refine_symmetric(stack: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray, bend_u: np.ndarray,
                     bend_v: np.ndarray, half: float, arm: float = ARM_SQUARES, margin_px: float = MARGIN_PX,
                     iters: int = 25, tol: float = 2e-3, bend_spread: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners as centres of point symmetry: q minimising sum_d (I(q + b(d) + d) - I(q + b(d) - d))^2.

    A chessboard corner, and a ChArUco corner out to its markers, looks the same turned
    by 180 degrees about itself; that holds under any affine view and any symmetric blur,
    so the estimate needs no model of the edge profile, contrast or PSF. d runs over a
    cross of half-width `half` squares (less `margin_px` of blur) around the two edge
    lines, `arm` squares long, placed with the local axes ax, ay; `margin_px` (down to
    MIN_MARGIN_PX where the gap is narrow) keeps it off the markers' blurred edges, which
    are not point-symmetric once perspective narrows the far gap. Lens distortion bends
    the edge lines, and a bent line is not point-symmetric: b(d) = bend_u u^2 n_u +
    bend_v v^2 n_v moves each pair's centre along the arm normals n_u, n_v by the bends
    the corner grid shows (local_grid). A linear shading gradient (vignetting, light) is
    estimated with q: I(q + d) ~ (1 + s.d) S(d). Gauss-Newton.

    stack: image_gradients(gray); uv, ax, ay: (N, 2); bend_u, bend_v: (N,). Returns (N, 2)
    corners and (N,) bool: True where refined, False where the start was kept (too
    little room, no convergence, moved too far, or under half the cross in the image).
    Pairs of samples with a point outside the image are left out.

    Also returns (N,) sigma: each refined corner's own 1-sigma error (px, per axis), the
    fit's covariance residual variance x (J^T W J)^-1 where it stopped, NaN where not
    refined. It grows with image noise, blur, low contrast, fewer or shorter samples
    (small, foreshortened or cut crosses) and with any misfit of the model (markers,
    wrong bends). On rendered fisheye views it tracks the true error (0.007 px in the
    lowest tenth, 0.030 px in the highest; README, bench/fisheye_excess.py)."""
    n = len(uv)
    out, ok = uv.astype(np.float64).copy(), np.zeros(n, bool)
    sigma = np.full(n, np.nan)
    if n == 0:
        return out, ok, sigma
    sq = np.sqrt(np.abs(ax[:, 0] * ay[:, 1] - ax[:, 1] * ay[:, 0]))
    good = np.isfinite(sq) & (sq > 4.0) & np.isfinite(bend_u) & np.isfinite(bend_v)
    sq_safe = np.where(good, sq, 1.0)
    margin_k = np.clip(half * sq_safe - CROSS_KEEP_PX, min(MIN_MARGIN_PX, margin_px), margin_px)
    half_k = np.where(half >= arm, arm, half - margin_k / sq_safe)
    good &= half_k * sq >= 0.5
    if not good.any():
        return out, ok, sigma
    idx = np.flatnonzero(good)
    sq_g, half_g = sq[idx], half_k[idx]
    delta = max(STEP_PX / float(np.median(sq_g)), arm / MAX_SAMPLES_PER_ARM)
    uvo = _cross_offsets(min(half, arm), arm, delta)  # (P, 2)
    u, v = uvo[None, :, 0], uvo[None, :, 1]
    w = ((np.abs(u) <= half_g[:, None]) | (np.abs(v) <= half_g[:, None]))  # (M, P)
    # strongly bent lines (fisheye): shorter arms, so the bend's own error matters less
    bend_max = np.maximum(np.abs(bend_u[idx]), np.abs(bend_v[idx]))
    arm_k = np.minimum(arm, np.sqrt(BEND_REACH_PX / np.maximum(bend_max, 1e-9)))
    w &= np.maximum(np.abs(u), np.abs(v)) <= arm_k[:, None]
    w = w.astype(np.float32)
    dx = u * ax[idx, None, 0] + v * ay[idx, None, 0]  # (M, P) pixel offsets of the samples
    dy = u * ax[idx, None, 1] + v * ay[idx, None, 1]
    n_u = _unit(np.column_stack([-ax[idx, 1], ax[idx, 0]]))
    n_v = _unit(np.column_stack([-ay[idx, 1], ay[idx, 0]]))
    u2, v2 = (u ** 2).astype(np.float32), (v ** 2).astype(np.float32)
    uf, vf = u.astype(np.float32), v.astype(np.float32)
    fit_bend = bend_spread is not None
    n_par = 6 if fit_bend else 4
    p = np.zeros((len(idx), n_par))  # q_x, q_y, shading gradient s_u, s_v[, bend_u, bend_v]
    p[:, :2] = uv[idx]
    prior = np.column_stack([bend_u[idx], bend_v[idx]])
    sig2 = np.maximum(bend_spread[idx], 1e-6) ** 2 if fit_bend else None
    bends = prior.copy()
    if fit_bend:
        p[:, 4:] = prior
    fit = FitProgress(len(idx))
    for _ in range(iters):
        act = fit.act
        pa = p[act]
        ba = pa[:, 4:] if fit_bend else bends[act]
        cx = pa[:, 0, None] + ba[:, 0, None] * u2 * n_u[act, 0, None] + ba[:, 1, None] * v2 * n_v[act, 0, None]
        cy = pa[:, 1, None] + ba[:, 0, None] * u2 * n_u[act, 1, None] + ba[:, 1, None] * v2 * n_v[act, 1, None]
        xp, yp = (cx + dx[act]).astype(np.float32), (cy + dy[act]).astype(np.float32)
        xm, ym = (cx - dx[act]).astype(np.float32), (cy - dy[act]).astype(np.float32)
        r, cols, inside = symmetry_terms(stack, xp, yp, xm, ym, pa[:, 2:4], uf, vf)
        fit.full[act] = (w[act] * inside).sum(1) >= 0.5 * w[act].sum(1)
        if fit_bend:
            jx, jy = cols[:2]
            cols += [(jx * n_u[act, 0, None] + jy * n_u[act, 1, None]) * u2,
                     (jx * n_v[act, 0, None] + jy * n_v[act, 1, None]) * v2]
        wa = w[act] * inside
        H, g = normal_equations(cols, r, wa)
        if fit_bend:
            # prior bend_* +- bend_spread, weighed against the residual variance of the samples
            var = (wa * r * r).sum(1) / np.maximum(wa.sum(1), 1.0)
            lam = var[:, None] / sig2[act]
            H[:, 4, 4] += lam[:, 0]
            H[:, 5, 5] += lam[:, 1]
            g[:, 4:] += lam * (pa[:, 4:] - prior[act])
        step, bad = newton_steps(H, g)
        step[:, :2] = np.clip(step[:, :2], -0.5, 0.5)
        if fit_bend:
            step[:, 4:] = np.clip(step[:, 4:], -2.0, 2.0)
        p[act] += step
        if not fit.retire(step, bad, H, wa, r, tol):
            break
    # A corner whose cross is mostly outside the image, or that wandered off, keeps its start.
    q = p[:, :2]
    fit.store(out, ok, sigma, idx, q, np.linalg.norm(q - uv[idx], axis=1) < np.maximum(1.0, 0.15 * sq_g))
    return out, ok, sigma


def refine_pairs(stack: np.ndarray, uv: np.ndarray, cross: np.ndarray, Dp: np.ndarray, Dm: np.ndarray,
                 w: np.ndarray, sign: np.ndarray | None = None, iters: int = 25, tol: float = 2e-3,
                 max_move: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners q minimising sum_d w (I(q + Dp(d)) - sign I(q + Dm(d)) - level - shading)^2,
    Gauss-Newton, where each pair's two samples were placed by a map of the pattern around
    the corner (Dp, Dm (N, P, 2): pixel offsets of the images of P + d and P - d from P's).

    cross (P, 2): the offsets d in squares (the shading term's coordinates: refine_symmetric's
    I(q + d) ~ (1 + s.d) S(d)); w (N, P) float32 weights. sign (N, P) float32, when given,
    -1 on point-antisymmetric pairs (symmetry_terms), whose level sum is one more unknown per
    corner. Returns (N, 2) corners, (N,) bool refined (False: the start is kept: under 8
    pairs, no convergence, under half of them inside the image, or a move beyond max_move px)
    and (N,) each refined corner's 1-sigma (px per axis; residual variance x (J^T W J)^-1)."""
    n = len(uv)
    out, ok, sigma = uv.astype(np.float64).copy(), np.zeros(n, bool), np.full(n, np.nan)
    good = w.sum(1) >= 8
    if not good.any():
        return out, ok, sigma
    idx = np.flatnonzero(good)
    Dp, Dm, w = Dp[idx], Dm[idx], w[idx]
    sign = None if sign is None else sign[idx]
    u, v = cross[None, :, 0].astype(np.float32), cross[None, :, 1].astype(np.float32)
    p = np.zeros((len(idx), 4 if sign is None else 5))  # q_x, q_y, shading s_u, s_v[, level sum]
    p[:, :2] = uv[idx]
    fit = FitProgress(len(idx))
    for it in range(iters):
        act = fit.act
        pa = p[act]
        xp, yp = (pa[:, 0, None] + Dp[act, :, 0]).astype(np.float32), (pa[:, 1, None] + Dp[act, :, 1]).astype(np.float32)
        xm, ym = (pa[:, 0, None] + Dm[act, :, 0]).astype(np.float32), (pa[:, 1, None] + Dm[act, :, 1]).astype(np.float32)
        r, cols, inside = symmetry_terms(stack, xp, yp, xm, ym, pa[:, 2:4], u, v,
                                         None if sign is None else sign[act])
        fit.full[act] = (w[act] * inside).sum(1) >= 0.5 * w[act].sum(1)
        wa = w[act] * inside
        if sign is not None:
            anti = (sign[act] < 0).astype(np.float32)
            if it == 0:  # the level sum is linear: start it at its mean over the antisymmetric pairs
                wa_anti = wa * anti
                p[act, 4] = (wa_anti * r).sum(1) / np.maximum(wa_anti.sum(1), 1.0)
            r = r - anti * p[act, 4, None].astype(np.float32)
            cols.append(-anti)
        H, g = normal_equations(cols, r, wa)
        step, bad = newton_steps(H, g)
        step[:, :2] = np.clip(step[:, :2], -0.5, 0.5)
        p[act] += step
        if not fit.retire(step, bad, H, wa, r, tol):
            break
    q = p[:, :2]
    fit.store(out, ok, sigma, idx, q, np.linalg.norm(q - uv[idx], axis=1) < max_move)
    return out, ok, sigma


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
        return _refine_aprilgrid(gray, board, ids, uv, mode)
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


def _refine_aprilgrid(gray: np.ndarray, board: Board, ids: np.ndarray, uv: np.ndarray,
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
    ax, ay = april.corner_axes(ids, uv, board)
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
    # Once more. Small tags (april.LONG_ARMS_BELOW_PX) with the tag edges out to the next
    # corner, along the view's map of the board (_aprilgrid_mapped) ...
    ax2, ay2 = april.corner_axes(ids, q, board)
    fine = ok & np.isfinite(ax2).all(axis=1) & np.isfinite(ay2).all(axis=1)
    size = np.sqrt(np.abs(ax2[:, 0] * ay2[:, 1] - ax2[:, 1] * ay2[:, 0]))
    small = fine & (np.nan_to_num(size, nan=np.inf) < april.LONG_ARMS_BELOW_PX)
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
        bu, bv = (np.nan_to_num(b[f]) for b in april.lattice_bends(ids, q, board))
        half, arm = april.symmetric_cross(board, ax2[f], ay2[f])
        q3, ok3, sigma3 = refine_symmetric(stack, q[f], ax2[f], ay2[f], bu, bv, half, arm=arm)
        q[f[ok3]], sigma[f[ok3]] = q3[ok3], sigma3[ok3]
    sigma = np.where(ok, sigma, np.nan)
    return q + origin, ok, sigma


def aprilgrid_box_passes(gray: np.ndarray, stack: np.ndarray, board: Board, ids: np.ndarray, uv: np.ndarray,
                         ax: np.ndarray, ay: np.ndarray, box: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """_refine_aprilgrid's passes in the corner square's box (stack = image_gradients(gray);
    ax, ay = april.corner_axes, box = april.symmetric_box): (N, 2) corners, ok (refined and
    looking like a tag corner), sigma, and restarted ((N,) bool: placed only from where the
    neighbouring tags' corners put it)."""
    q, ok, sigma = _aprilgrid_pass(gray, stack, uv, ax, ay, box)
    ok &= april.looks_like_a_tag_corner(gray, ids, q, ax, ay, box)
    pred = april.neighbour_predictions(ids, q, board, ok)
    redo = ~ok & np.isfinite(pred).all(axis=1)
    restarted = np.zeros(len(ids), bool)
    if redo.any():
        # started again from where the neighbouring tags' corners put them
        r = np.flatnonzero(redo)
        q2, ok2, sigma2 = _aprilgrid_pass(gray, stack, pred[r], ax[r], ay[r], box)
        ok2 &= april.looks_like_a_tag_corner(gray, ids[r], q2, ax[r], ay[r], box)
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
    size = np.sqrt(np.abs(ax[:, 0] * ay[:, 1] - ax[:, 1] * ay[:, 0]))
    if not np.isfinite(size).all() or size.min() <= 4.0:
        return None
    delta = max(STEP_PX / float(np.median(size)), 1.0 / MAX_PAIRS_PER_TAG_EDGE)
    cross = _cross_offsets(min(april.BORDER_FRACTION, board.tag_spacing), 1.0, delta)
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


def is_degenerate(ids: np.ndarray, uv: np.ndarray, board: Board) -> bool:
    """True when a view's corners lie on one line: on the board (exactly) or in the image (nearly)."""
    for pts, ratio in ((board.corners[ids, :2], 1e-9), (uv, COLLINEAR_RATIO)):
        s = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
        if s[0] <= 0 or s[1] <= ratio * s[0]:
            return True
    return False


# ----------------------------------------------------------------------------- detectors


def _as_ids(x) -> np.ndarray:
    return np.zeros(0, np.int64) if x is None else np.asarray(x, dtype=np.int64).reshape(-1)


def _as_uv(x) -> np.ndarray:
    return np.zeros((0, 2)) if x is None else np.asarray(x, dtype=np.float64).reshape(-1, 2)


class _CharucoGroup:
    """Boards sharing one ArUco dictionary: markers are found once for all of them."""

    def __init__(self, dictionary: str, boards: Sequence[Board]):
        full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        # Identification tests every candidate against every code of the dictionary: a
        # dictionary of only the boards' ids is ~15x faster on DICT_*_1000 and finds the
        # same markers (codes of the full dictionary are further apart than the correction).
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
        ids = self.ids[_as_ids(idx)]
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
            ids, uv = _as_ids(ci), _as_uv(cc)
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
    or more (81 of 90 ECoCheck images together, 78 alone, SB 76) at 20-70x the speed;
    SB only where it fails. Both only seed the refinement, so their accuracy does not matter."""
    pattern = board.inner_corners
    ok, c = cv2.findChessboardCorners(gray, pattern, flags=CLASSIC_FLAGS)
    if ok:
        return _as_uv(c)
    ok, c = cv2.findChessboardCornersSB(gray, pattern, flags=SB_FLAGS)
    if ok:
        return _as_uv(c)
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
        self.groups = [_CharucoGroup(d, bs) for d, bs in by_dict.items()]
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
            views.append((board.name, ids, uv, amb, sigma))
        return views, dropped


def detect_image(gray: np.ndarray, target: Target, min_corners: int = 6, refine: str = "symmetric",
                 detector: BoardDetector | None = None) -> list[tuple[str, np.ndarray, np.ndarray, bool]]:
    """Boards in one grey (or colour, any depth) image: [(board name, ids, uv, ambiguous)]."""
    detector = detector or BoardDetector(target, min_corners, refine)
    return detector.detect(to_gray8(np.asarray(gray)))[0]


# ----------------------------------------------------------------------------- datasets


@dataclass
class _ImageOut:
    size: tuple[int, int] | None
    reason: str | None
    views: list
    dropped: int


_WORKER: BoardDetector | None = None


def _init_worker(target: Target, min_corners: int, refine: str) -> None:
    global _WORKER
    cv2.setNumThreads(1)  # the processes are the parallelism
    _WORKER = BoardDetector(target, min_corners, refine)


def _work(path: str) -> _ImageOut:
    gray, reason = read_gray(path)
    if gray is None:
        return _ImageOut(None, reason, [], 0)
    views, dropped = _WORKER.detect_with_sigma(gray)
    return _ImageOut((gray.shape[1], gray.shape[0]), None, views, dropped)


def _detect_serial(paths: list[str], target: Target, min_corners: int, refine: str, bar) -> list[_ImageOut]:
    global _WORKER
    keep = _WORKER
    _WORKER = BoardDetector(target, min_corners, refine)
    try:
        bar.start()
        out = []
        for p in paths:
            out.append(_work(p))
            bar.advance()
        return out
    finally:
        _WORKER = keep


def _detect_parallel(paths: list[str], target: Target, jobs: int, min_corners: int, refine: str,
                     bar, scheduler: str | None = None) -> list[_ImageOut]:
    chunk = max(1, min(8, len(paths) // (jobs * 6)))
    with pool(jobs, "rigcal.detect", _init_worker, (target, min_corners, refine), scheduler) as ex:
        with interrupts_deferred():  # a worker interrupted while it starts prints a traceback
            results = ex.map(_work, paths, chunksize=chunk)  # submits all, workers start now; yields in order
        bar.start()  # after the workers started: no progress-bar thread is copied into them
        out = []
        for r in results:
            out.append(r)
            bar.advance()
    return out


class _Progress:
    """rich progress bar on stderr with counts and rate, or nothing."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, bool(enabled) and total > 0
        self.bar = None

    def start(self) -> None:
        if not self.enabled or self.bar is not None:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(TextColumn("detecting"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                            console=Console(stderr=True), transient=False)
        self.task = self.bar.add_task("detect", total=self.total, rate="")
        self.t0, self.done = time.perf_counter(), 0
        self.bar.start()

    def advance(self) -> None:
        if self.bar is not None:
            self.done += 1
            dt = time.perf_counter() - self.t0
            self.bar.update(self.task, advance=1, rate=f"{self.done / dt:.1f} img/s" if dt > 0 else "")

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def detect_dataset(images, target: Target, rig=None, jobs: int | None = None, progress: bool = True,
                   min_corners: int = 6, refine: str = "symmetric", scheduler: str | None = None) -> DetectionResult:
    """Detect every board in every image of a dataset (dataset.DatasetImages).

    rig: when given, each image's size is checked against the camera's resolution
    (mismatches are listed in `size_mismatch`, not raised). jobs: worker processes
    (default os.cpu_count()). scheduler: a Dask scheduler's address; its workers do the
    work instead, reading the images at their absolute paths (a file system they share).
    The result is the same whatever `jobs` or `scheduler` is."""
    if refine not in REFINE_MODES:
        raise ValueError(f"refine: expected one of {', '.join(REFINE_MODES)}, got {refine!r}")
    t0 = time.perf_counter()
    jobs = max(1, int(jobs if jobs is not None else (os.cpu_count() or 1)))
    items = images.items()
    paths = [str(p) for _, _, p in items]
    bar = _Progress(len(paths), progress)
    try:
        if scheduler is not None:
            outs = _detect_parallel([os.path.abspath(p) for p in paths], target, jobs, min_corners, refine, bar,
                                    scheduler)
        elif jobs <= 1 or len(paths) < 2 * jobs:
            jobs = 1
            outs = _detect_serial(paths, target, min_corners, refine, bar)
        else:
            outs = _detect_parallel(paths, target, jobs, min_corners, refine, bar)
    finally:
        bar.stop()
    expected = {}
    if rig is not None:
        for cam in images.cameras:
            m = rig.camera(cam).intrinsics
            expected[cam] = (int(m.width), int(m.height))
    res = DetectionResult(views=[], cameras=tuple(images.cameras), frames=tuple(images.all_frames),
                          image_size={}, n_images={c: 0 for c in images.cameras}, unreadable=[],
                          no_board={c: 0 for c in images.cameras}, dropped={c: 0 for c in images.cameras},
                          size_mismatch=[], seconds=0.0, jobs=jobs)
    for (cam, frame, path), o in zip(items, outs):
        res.n_images[cam] += 1
        if o.size is None:
            res.unreadable.append((str(path), o.reason))
            res.unreadable_by_camera[cam] = res.unreadable_by_camera.get(cam, 0) + 1
            continue
        res.image_size.setdefault(cam, o.size)
        if cam in expected and o.size != expected[cam]:
            res.size_mismatch.append((cam, str(path), o.size, expected[cam]))
        res.dropped[cam] += o.dropped
        if not o.views:
            res.no_board[cam] += 1
        for name, ids, uv, amb, sigma in o.views:
            res.views.append(BoardView(cam, frame, name, ids, uv, amb, sigma))
    res.seconds = time.perf_counter() - t0
    return res


# ----------------------------------------------------------------------------- diagnosis


def _markers_of(gray: np.ndarray, dictionary: str, polarities: tuple[bool, ...] = (False, True)) -> np.ndarray:
    """Marker ids of a dictionary found in the image or (polarity True) in its inverse."""
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)),
                                  cv2.aruco.DetectorParameters())
    best = np.zeros(0, np.int64)
    for inverted in polarities:
        ids = _as_ids(det.detectMarkers(cv2.bitwise_not(gray) if inverted else gray)[1])
        if len(ids) > len(best):
            best = ids
    return best


def _corner_count(gray: np.ndarray, board: Board) -> int:
    try:
        return sum(len(ids) for _, ids, _ in _CharucoGroup(board.dictionary, [board]).detect(gray))
    except (cv2.error, ValueError):
        return 0


def _best_other_dictionary(grays: list[np.ndarray], wanted: set[str]) -> tuple[str, int, int] | None:
    """The common dictionary, other than `wanted`, with the most markers in these images:
    (name, markers found, highest id), or None. A big dictionary costs 0.2-0.8 s an image,
    so all are tried on the first image showing any marker (as printed, else inverted),
    and only those that found some on the rest, in that polarity. On a tie the later,
    bigger dictionary of a family wins (the smaller ones are its first codes, so both
    read the print)."""
    others = [d for d in DIAGNOSE_DICTIONARIES if d not in wanted]
    hits: list[str] = []
    for k, g in enumerate(grays):
        for polarity in ((False,), (True,)):
            first = {d: _markers_of(g, d, polarity) for d in others}
            hits = [d for d in others if len(first[d])]
            if hits:
                break
        if hits:
            break
    else:
        return None
    best = None
    for d in hits:
        ids = np.concatenate([first[d]] + [_markers_of(g, d, polarity) for g in grays[k + 1:]])
        if best is None or len(ids) >= best[1]:
            best = (d, len(ids), int(ids.max()))
    return best


def diagnose_no_detection(paths: Iterable[str | Path], target: Target, max_images: int = 4) -> str:
    """The most likely reason no board of `target` shows in these images, in words.

    Tries, on a few readable images: the target's dictionary (normal and inverted) and
    whether its markers carry other ids; the other legacy_pattern; the squares swapped;
    every other common dictionary; a plain chessboard. Slow (seconds): for error paths."""
    from dataclasses import replace

    grays = []
    for p in paths:
        g, _ = read_gray(p)
        if g is not None and float(g.std()) >= FLAT_STD:
            grays.append(g)
        if len(grays) >= max_images:
            break
    if not grays:
        return "none of the images tried could be read or shows anything (all flat)"
    n = len(grays)
    charuco = [b for b in target.boards if b.type == "charuco"]
    wanted = {b.dictionary for b in charuco}
    found = {d: np.concatenate([_markers_of(g, d) for g in grays]) for d in wanted}
    in_range = sum(int(np.isin(found[b.dictionary], b.marker_ids).sum()) for b in charuco)
    # markers of the boards in every image: the dictionary is right (scanning the others takes seconds)
    best = _best_other_dictionary(grays, wanted) if in_range < 3 * n else None
    grids = [b.name for b in target.boards if b.type == "aprilgrid"]
    says = ("target.yaml says " + ", ".join(sorted(wanted) + [f"AprilGrid {n} (AprilTag 36h11)" for n in grids])
            if wanted or grids else "target.yaml describes a chessboard")
    # A wrong dictionary still decodes a few stray markers in the real ones' bit patterns
    # (DICT_4X4_1000 read in DICT_5X5_1000 prints): judge it by how many more the other finds.
    if (best is not None and best[1] >= MIN_CLAIM_MARKERS
            and best[1] > 2 * max((len(v) for v in found.values()), default=0)):
        return f"markers of {best[0]} found ({best[1]} in {n} images, ids up to {best[2]}); {says}"
    hints = []
    for b in charuco:
        ids = found[b.dictionary]
        if len(ids) == 0:
            continue
        lo, hi = b.first_marker_id, b.first_marker_id + b.n_markers - 1
        inside = ids[(ids >= lo) & (ids <= hi)]
        if len(inside) == 0:
            return (f"markers of {b.dictionary} found with ids {ids.min()}..{ids.max()}, but board {b.name} uses ids "
                    f"{lo}..{hi}: check first_marker_id and squares")
        for change, alt in ((f"legacy_pattern: {str(not b.legacy_pattern).lower()}",
                             replace(b, legacy_pattern=not b.legacy_pattern)),
                            (f"squares: [{b.squares[1]}, {b.squares[0]}]", replace(b, squares=b.squares[::-1]))):
            if sum(_corner_count(g, alt) for g in grays):
                return f"board {b.name}: its markers are found and corners appear with {change}"
        hints.append(f"markers of board {b.name} ({b.dictionary}, ids {inside.min()}..{inside.max()}) are found "
                     f"but no corners: check squares, marker_length and legacy_pattern")
    if hints:
        return "; ".join(hints)
    for b in target.boards:
        if b.type == "aprilgrid":
            continue  # its corner lattice is no chessboard
        nx, ny = b.inner_corners
        # the board as declared (a ChArUco printed without markers), or one off along either axis;
        # OpenCV needs at least 3 inner corners each way (it raises below that)
        patterns = sorted({(nx + i, ny + j) for i in (-1, 0, 1) for j in (-1, 0, 1)},
                          key=lambda q: (abs(q[0] - nx) + abs(q[1] - ny), q))
        for pattern in patterns:
            if b.type == "chessboard" and pattern == (nx, ny):
                continue
            if min(pattern) < 3:
                continue
            if any(cv2.findChessboardCorners(g, pattern, flags=CLASSIC_FLAGS)[0] for g in grays):
                what = "squares" if b.type == "charuco" else "inner_corners"
                return (f"a plain chessboard with {pattern[0]}x{pattern[1]} inner corners is found "
                        f"(target.yaml: board {b.name}, {b.type}, {what} {list(b.squares if b.type == 'charuco' else b.inner_corners)})")
    return (f"no ArUco markers of any common dictionary and no chessboard found in the {n} images tried "
            "(blurred, too dark, or the board too small?)")
