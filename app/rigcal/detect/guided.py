"""Model-guided corner refinement: a second pass over the images once the rig is calibrated.

The detector's point-symmetry fit (corner_fit.refine_symmetric) places each corner's cross
by axes and edge bends it estimates from the neighbouring detected corners. Where the
lens bends the grid strongly (a fisheye's periphery) that local model is poor: the
grid's finite differences span 1-2 squares where the cross spans 0.6, its arms are
shortened so a wrong bend matters less, and corners missing neighbours borrow a fit of
the corners around them. Those corners come out 2-3x noisier than the centre's, with
errors shared by neighbours, and they weigh most on a pair's relative rotation.

After a first calibration the camera model and each view's board pose give the image of
every point near a corner. Each sample pair of the cross is placed at the images of
P + d and P - d (P the corner on the board, d an offset in the board plane), which are
point-symmetric on the board whatever the lens does, so the only unknowns are the
corner's pixel (where the pattern's symmetry centre lies in this image) and a shading
gradient. The model sets where the samples go, never where the corner is: a model
error moves a corner only through the shape of its cross, a second-order effect.

What it gains on fisheye renders, and why it is on for fisheye cameras only by default,
is measured in the README (Accuracy: the guided pass; `python -m bench.archive.guided`).
"""

from __future__ import annotations

import os

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from rigcal.core.camera import CameraModel
from rigcal.detect.corner_fit import (ARM_SQUARES, CROSS_KEEP_PX, MARGIN_PX, MAX_SAMPLES_PER_ARM, MIN_MARGIN_PX,
                                      STEP_PX, cell_px, cross_offsets, image_gradients, refine_pairs)
from rigcal.detect.corner_refine import symmetric_half_width
from rigcal.data.image_read import read_gray
from rigcal.core.workers import interrupts_deferred, pool

# A corner the guided fit moves further than this from the detector's is left as the
# detector placed it: on a rendered fisheye the two agree within 0.1 px, so a larger move
# means the model is wrong there (or the fit slid onto a marker edge).
MAX_MOVE_PX = 1.0
FD_STEP = 1e-3  # squares: finite-difference step for the local scale of the board's image


@dataclass(frozen=True)
class BoardCorners:
    """One board view in one image: where the calibration puts it and its detected corners."""

    T_cam_board: np.ndarray  # (4, 4)
    p_board: np.ndarray  # (N, 3) corners on the board, metres
    uv: np.ndarray  # (N, 2) the detector's pixels (the fit's start)
    square: float  # square length, metres
    half: float  # cross half-width in squares (corner_refine.symmetric_half_width)


@dataclass(frozen=True)
class ImageTask:
    """One image for the guided pass: its file, the calibrated camera model and the boards it shows."""

    path: str
    model: CameraModel
    boards: tuple[BoardCorners, ...]


def _project(model: CameraModel, T_cam_board: np.ndarray, p_board: np.ndarray) -> np.ndarray:
    p_cam = p_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    return model.project(p_cam)[0]


def cross_samples(model: CameraModel, bc: BoardCorners, arm: float = ARM_SQUARES
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cross of every corner as the model images it.

    Returns offsets (P, 2) in squares (one of each +-d pair, corner_fit.cross_offsets),
    Dp and Dm (N, P, 2): the pixel offsets of P + d and P - d from P's own image, and
    w (N, P) float32: 1 for pairs inside the corner's cross (the white gap less the blur
    margin, as corner_fit.refine_symmetric sets it, with full-length arms) and imaged by the
    model, else 0.

    The two samples of a pair are not at equal pixel distances from the edge between them
    where the board's scale changes, and blur acts in pixels. Equalising them (feet on the
    edge, the same offset across it) made the corners cleaner (0.0064 against 0.0108 px on
    the independent renderer's fisheye scenes) but the pair's rotation worse (0.00089
    against 0.00068 deg, 12 seeds; docs/accuracy.md, The guided pass), so the exact images stay."""
    P, s, n = bc.p_board, bc.square, len(bc.p_board)
    # The cross's size depends on the local scale, its samples on the size: two projections.
    c0, du, dv = _project(model, bc.T_cam_board, np.concatenate(
        [P, P + [FD_STEP * s, 0.0, 0.0], P + [0.0, FD_STEP * s, 0.0]])).reshape(3, n, 2)
    ax, ay = (du - c0) / FD_STEP, (dv - c0) / FD_STEP  # px per square along the board's axes
    sq = cell_px(ax, ay)
    sq = np.where(np.isfinite(sq) & (sq > 0), sq, np.nan)
    margin = np.clip(bc.half * sq - CROSS_KEEP_PX, MIN_MARGIN_PX, MARGIN_PX)
    half_k = bc.half - margin / sq
    med = float(np.nanmedian(sq)) if np.isfinite(sq).any() else 1.0
    delta = max(STEP_PX / med, arm / MAX_SAMPLES_PER_ARM)
    cross = cross_offsets(min(bc.half, arm), arm, delta)
    m = len(cross)
    off = np.zeros((m, 3))
    off[:, :2] = cross * s
    pm = _project(model, bc.T_cam_board, np.concatenate([(P[:, None, :] + off).reshape(-1, 3),
                                                         (P[:, None, :] - off).reshape(-1, 3)]))
    Dp, Dm = pm.reshape(2, n, m, 2) - c0[None, :, None]
    with np.errstate(invalid="ignore"):
        inside = (np.abs(cross[None, :, 0]) <= half_k[:, None]) | (np.abs(cross[None, :, 1]) <= half_k[:, None])
        usable = (sq > 4.0) & (half_k * sq >= 0.5)
    w = inside & usable[:, None] & np.isfinite(Dp).all(2) & np.isfinite(Dm).all(2)
    return cross, np.nan_to_num(Dp), np.nan_to_num(Dm), w.astype(np.float32)


def refine_guided(stack: np.ndarray, uv: np.ndarray, cross: np.ndarray, Dp: np.ndarray, Dm: np.ndarray,
                  w: np.ndarray, iters: int = 25, tol: float = 2e-3, max_move: float = MAX_MOVE_PX
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners q minimising sum_d w (I(q + Dp(d)) - I(q + Dm(d)) - shading)^2, Gauss-Newton
    (corner_fit.refine_pairs, every pair point-symmetric).

    stack: corner_fit.image_gradients of the image; uv (N, 2) the starts; cross, Dp, Dm, w from
    cross_samples. The shading term is corner_fit.refine_symmetric's: I(q + d) ~ (1 + s.d) S(d).
    Returns (N, 2) corners, (N,) bool refined (False: the start is kept: too few samples,
    no convergence, under half the cross inside the image, or a move beyond max_move) and
    (N,) each refined corner's 1-sigma (px per axis; residual variance x (J^T W J)^-1)."""
    return refine_pairs(stack, uv, cross, Dp, Dm, w, iters=iters, tol=tol, max_move=max_move)


def refine_image(gray: np.ndarray, task: ImageTask) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Every board view of one image: [(uv, refined, sigma)] in task.boards' order."""
    samples = [cross_samples(task.model, bc) for bc in task.boards]
    # gradients only over the box the crosses can reach (start + sample offsets + a
    # step's worth of travel + the kernel), not the whole image
    lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])
    for bc, (_, Dp, Dm, w) in zip(task.boards, samples):
        if len(bc.uv) and w.any():
            reach = np.abs(np.concatenate([Dp[w > 0], Dm[w > 0]])).max(0)
            lo = np.minimum(lo, bc.uv.min(0) - reach)
            hi = np.maximum(hi, bc.uv.max(0) + reach)
    out = [(bc.uv.astype(np.float64).copy(), np.zeros(len(bc.uv), bool), np.full(len(bc.uv), np.nan))
           for bc in task.boards]
    if not np.isfinite(lo).all():
        return out
    h, w_img = gray.shape
    pad = MAX_MOVE_PX + 4.0
    x0, y0 = max(0, int(np.floor(lo[0] - pad))), max(0, int(np.floor(lo[1] - pad)))
    x1, y1 = min(w_img, int(np.ceil(hi[0] + pad)) + 1), min(h, int(np.ceil(hi[1] + pad)) + 1)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return out
    stack, origin = image_gradients(gray[y0:y1, x0:x1]), np.array([x0, y0], float)
    for k, (bc, smp) in enumerate(zip(task.boards, samples)):
        if len(bc.uv):
            q, ok, sigma = refine_guided(stack, bc.uv - origin, *smp)
            out[k] = (q + origin, ok, sigma)
    return out


def _work(task: ImageTask):
    gray, _ = read_gray(task.path)
    if gray is None:  # read at detection, gone or changed since: the detector's corners stand
        return None
    return refine_image(gray, task)


def _init_worker() -> None:
    cv2.setNumThreads(1)  # the processes are the parallelism


def refine_images(tasks: Sequence[ImageTask], jobs: int = 1, scheduler: str | None = None) -> list:
    """refine_image over every task, in parallel over processes when jobs > 1 (or on the
    Dask cluster at `scheduler`, see detect.detect_dataset); None for an image that can no
    longer be read. Results in task order."""
    if scheduler is None and (jobs <= 1 or len(tasks) < 2 * jobs):
        return [_work(t) for t in tasks]
    chunk = max(1, min(8, len(tasks) // (jobs * 6)))
    with pool(jobs, "rigcal.detect.guided", _init_worker, (), scheduler) as ex:
        with interrupts_deferred():
            results = ex.map(_work, tasks, chunksize=chunk)
        return list(results)


def board_pose(state, c: int, f: int, b: int) -> np.ndarray:
    """T_cam_board of camera c, frame f, board b in the solver's state."""
    return state.T_cam_body[c] @ state.T_body_world[f] @ state.T_world_board[b]


def guided_uv(obs, state, paths: dict[tuple[int, int], str], declared: Sequence[CameraModel],
              boards: Sequence, halves: Sequence[float], jobs: int = 1, scheduler: str | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Re-refine every observation with the calibrated state (solve.State).

    obs: solve.Observations; paths: (camera index, frame index) -> image; declared: per
    camera its declared CameraModel (for model type and size); boards: per board index
    (square length); halves: per board its cross half-width. Returns (M, 2) corners (the
    detector's where the guided fit declined), (M,) bool refined, (M,) sigma (NaN where
    not refined)."""
    uv = obs.uv.astype(np.float64).copy()
    refined = np.zeros(len(obs), bool)
    sigma = np.full(len(obs), np.nan)
    key = obs.cam.astype(np.int64) * (int(obs.frame.max(initial=0)) + 1) + obs.frame
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(key[order]) != 0])
    tasks, rows = [], []
    for a, z in zip(starts, np.r_[starts[1:], len(order)]):
        rr = order[a:z]
        c, f = int(obs.cam[rr[0]]), int(obs.frame[rr[0]])
        if (c, f) not in paths:
            continue
        model = declared[c].with_values(state.intrinsics[c].values)
        bcs, brows = [], []
        for b in np.unique(obs.board[rr]):
            rb = rr[obs.board[rr] == b]
            bcs.append(BoardCorners(board_pose(state, c, f, int(b)), obs.p_board[rb], obs.uv[rb],
                                    float(boards[b].square_length), float(halves[b])))
            brows.append(rb)
        path = str(paths[(c, f)]) if scheduler is None else os.path.abspath(paths[(c, f)])
        tasks.append(ImageTask(path, model, tuple(bcs)))
        rows.append(brows)
    for res, brows in zip(refine_images(tasks, jobs, scheduler), rows):
        if res is None:
            continue
        for (q, ok, s), rb in zip(res, brows):
            uv[rb[ok]] = q[ok]
            refined[rb[ok]] = True
            sigma[rb[ok]] = s[ok]
    return uv, refined, sigma


GUIDED_MODES = ("auto", "on", "off")


def guided_cameras(rig, mode: str) -> list[str]:
    """The cameras whose corners the guided pass re-measures: `on` every camera, `off`
    none, `auto` the fisheye cameras. Measured (docs/accuracy.md): on fisheye pairs it
    cuts the relative-rotation error 2-2.5x, on rigcal's renders and on independently
    rendered images alike; on pinhole cameras it helped rigcal's renders and the real
    chessboard sets (reprojection RMS 8-27 % lower) but not independently rendered
    ChArUco images (corner error 3-12 % higher), so there it is asked for, not assumed."""
    if mode not in GUIDED_MODES:
        raise ValueError(f"guided: expected one of {', '.join(GUIDED_MODES)}, got {mode!r}")
    if mode == "off":
        return []
    return [c.name for c in rig.cameras if mode == "on" or c.intrinsics.model == "fisheye"]


def rerefiner(images, rig, target, jobs: int = 1, mode: str = "auto", scheduler: str | None = None):
    """pipeline.calibrate_views' `rerefine` hook for a dataset (dataset.DatasetImages), or None
    when `mode` (guided_cameras) selects no camera; on the Dask cluster at `scheduler` if given."""
    chosen = set(guided_cameras(rig, mode))
    if not chosen or any(b.type == "aprilgrid" for b in target.boards):
        # the guided cross is a ChArUco/chessboard one; AprilGrid corners keep the detector's
        return None
    by_name = {b.name: b for b in target.boards}

    def rerefine(obs, state, cam_names, frames, board_names):
        paths = {(c, f): images.frames[n][stem] for c, n in enumerate(cam_names) if n in chosen
                 for f, stem in enumerate(frames) if stem in images.frames.get(n, {})}
        boards = [by_name[b] for b in board_names]
        return guided_uv(obs, state, paths, [rig.camera(n).intrinsics for n in cam_names], boards,
                         [symmetric_half_width(b) for b in boards], jobs, scheduler)

    return rerefine
