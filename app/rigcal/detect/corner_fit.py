"""Corners as centres of point symmetry: the estimator every refined corner goes through.

A chessboard corner, and a ChArUco or AprilGrid corner out to its markers, looks the same
turned by 180 degrees about itself, under any affine view and any symmetric blur. So the
corner q is fitted by Gauss-Newton to make pairs of samples at q + d and q - d agree,
with a linear shading gradient alongside, needing no model of the edge profile,
contrast or PSF. refine_symmetric places the pairs on a cross along the grid's local
axes and bends (corner_grid); refine_pairs takes the pairs' placement from the caller
(guided.py: a calibrated camera model; the AprilGrid long-arm pass: a map of the view).
Both return each corner's own 1-sigma error from the fit. Numbers measured with these
settings are in the README (Board detection).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rigcal.detect.corner_grid import unit_normals

# Arm length of the cross, in squares.
ARM_SQUARES = 0.6
# Blur margin: the cross keeps this far off the markers' edges, 3 sigma of a typical blur
# (lens and the pixel's area). Closer, the markers' blurred edges reach into the cross;
# that cancels between the two sides of a frontal corner, but on a board seen at an
# angle the far side's gap is narrower, which biases corners towards the board's near
# side and so scales a whole rig (docs/decisions.md, "Corners are refined by point symmetry"). The price is
# a little more corner noise on frontal views (a narrower cross). Where the gap is too
# narrow for that, the margin shrinks to MIN_MARGIN_PX so the cross keeps CROSS_KEEP_PX
# (as many corners are refined as with a 1 px margin).
MARGIN_PX = 2.5
MIN_MARGIN_PX = 1.0
CROSS_KEEP_PX = 1.0
STEP_PX = 0.8
MAX_SAMPLES_PER_ARM = 24
# A cross shorter than this many STEP_PX steps (an AprilGrid's box around a tag corner under
# ~20 px tags: +-1.6 px at 16 px) is sampled this densely instead: at 0.8 px steps it held 4
# pairs for 4 unknowns and a 16 px tag's corners did not converge (fisheye room, README).
MIN_SAMPLES_PER_ARM = 3
# Edge bends (lens distortion): arms end where the bend displaces them by this much.
BEND_REACH_PX = 0.3


def cross_offsets(half: float, arm: float, delta: float) -> np.ndarray:
    """(P, 2) offsets (u, v) in squares on a delta grid inside the cross |u| <= half or
    |v| <= half, |u|, |v| <= arm; one of each +-d pair (v > 0, or v == 0 and u > 0)."""
    k = int(math.ceil(arm / delta))
    t = np.arange(-k, k + 1) * delta
    U, V = np.meshgrid(t, t)
    U, V = U.ravel(), V.ravel()
    keep = ((np.abs(U) <= half) | (np.abs(V) <= half)) & ((V > 0) | ((V == 0) & (U > 0)))
    return np.column_stack([U[keep], V[keep]])


def cell_px(ax: np.ndarray, ay: np.ndarray) -> np.ndarray:
    """(N,) the image's size (px, square root of the area) of one board cell at each corner,
    whose axes ax, ay (N, 2) are its images of one cell along board x and y."""
    return np.sqrt(np.abs(ax[:, 0] * ay[:, 1] - ax[:, 1] * ay[:, 0]))


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


@dataclass(frozen=True)
class _Cross:
    """Where refine_symmetric samples around the corners it can refine (rows idx of its input):
    offsets u, v (1, P) in squares, weights w (M, P) float32 (the cross, less the blur margin,
    with arms shortened where the lines bend strongly), their pixel offsets dx, dy (M, P), the
    arms' unit normals n_u, n_v (M, 2) and the square's size sq (M,) in px."""

    idx: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    n_u: np.ndarray
    n_v: np.ndarray
    sq: np.ndarray


def _symmetric_cross(ax: np.ndarray, ay: np.ndarray, bend_u: np.ndarray, bend_v: np.ndarray, half: float,
                     arm: float, margin_px: float) -> _Cross | None:
    """refine_symmetric's cross for each corner with room for one (None: no corner has)."""
    sq = cell_px(ax, ay)
    good = np.isfinite(sq) & (sq > 4.0) & np.isfinite(bend_u) & np.isfinite(bend_v)
    sq_safe = np.where(good, sq, 1.0)
    margin_k = np.clip(half * sq_safe - CROSS_KEEP_PX, min(MIN_MARGIN_PX, margin_px), margin_px)
    half_k = np.where(half >= arm, arm, half - margin_k / sq_safe)
    good &= half_k * sq >= 0.5
    if not good.any():
        return None
    idx = np.flatnonzero(good)
    sq_g, half_g = sq[idx], half_k[idx]
    delta = max(STEP_PX / float(np.median(sq_g)), arm / MAX_SAMPLES_PER_ARM)
    if arm < MIN_SAMPLES_PER_ARM * delta:
        # the last sample on the arm's end, a hair inside: at arm / MIN_SAMPLES_PER_ARM
        # rounding put it just outside as often as not
        delta = arm / (MIN_SAMPLES_PER_ARM + 1e-6)
    uvo = cross_offsets(min(half, arm), arm, delta)  # (P, 2)
    u, v = uvo[None, :, 0], uvo[None, :, 1]
    w = ((np.abs(u) <= half_g[:, None]) | (np.abs(v) <= half_g[:, None]))  # (M, P)
    # strongly bent lines (fisheye): shorter arms, so the bend's own error matters less
    bend_max = np.maximum(np.abs(bend_u[idx]), np.abs(bend_v[idx]))
    arm_k = np.minimum(arm, np.sqrt(BEND_REACH_PX / np.maximum(bend_max, 1e-9)))
    w &= np.maximum(np.abs(u), np.abs(v)) <= arm_k[:, None]
    dx = u * ax[idx, None, 0] + v * ay[idx, None, 0]  # (M, P) pixel offsets of the samples
    dy = u * ax[idx, None, 1] + v * ay[idx, None, 1]
    return _Cross(idx, u, v, w.astype(np.float32), dx, dy, unit_normals(ax[idx]), unit_normals(ay[idx]), sq_g)


def _add_bend_prior(H: np.ndarray, g: np.ndarray, wa: np.ndarray, r: np.ndarray, bends: np.ndarray,
                    prior: np.ndarray, sig2: np.ndarray) -> None:
    """Hold the fitted bends (parameters 4, 5) to the grid's, prior +- sqrt(sig2), weighed
    against the residual variance of the samples; H and g in place."""
    var = (wa * r * r).sum(1) / np.maximum(wa.sum(1), 1.0)
    lam = var[:, None] / sig2
    H[:, 4, 4] += lam[:, 0]
    H[:, 5, 5] += lam[:, 1]
    g[:, 4:] += lam * (bends - prior)


# Longer than ~60 lines by its docstring (the model it fits); the code is one batched
# Gauss-Newton loop of ~45 lines whose steps share the cross's arrays.
def refine_symmetric(stack: np.ndarray, uv: np.ndarray, ax: np.ndarray, ay: np.ndarray, bend_u: np.ndarray,
                     bend_v: np.ndarray, half: float, arm: float = ARM_SQUARES, margin_px: float = MARGIN_PX,
                     iters: int = 25, tol: float = 2e-3, bend_spread: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners as centres of point symmetry: q minimising sum_d (I(q + b(d) + d) - I(q + b(d) - d))^2.

    d runs over a cross of half-width `half` squares (less `margin_px` of blur) around the
    two edge lines, `arm` squares long, placed with the local axes ax, ay; `margin_px`
    (down to MIN_MARGIN_PX where the gap is narrow) keeps it off the markers' blurred
    edges, which are not point-symmetric once perspective narrows the far gap. Lens
    distortion bends the edge lines, and a bent line is not point-symmetric: b(d) =
    bend_u u^2 n_u + bend_v v^2 n_v moves each pair's centre along the arm normals n_u,
    n_v by the bends the corner grid shows (corner_grid), fitted alongside when
    bend_spread (N, 2) gives how far they may move. A linear shading gradient (vignetting,
    light) is estimated with q: I(q + d) ~ (1 + s.d) S(d).

    stack: image_gradients(gray); uv, ax, ay: (N, 2); bend_u, bend_v: (N,). Returns (N, 2)
    corners, (N,) bool: True where refined, False where the start was kept (too little
    room, no convergence, moved too far, or under half the cross in the image; pairs
    with a point outside the image are left out), and (N,) sigma: each refined corner's
    own 1-sigma error (px, per axis), residual variance x (J^T W J)^-1 where the fit
    stopped, NaN where not refined. Sigma grows with image noise, blur, low contrast,
    fewer or shorter samples and any misfit of the model (markers, wrong bends)."""
    n = len(uv)
    out, ok = uv.astype(np.float64).copy(), np.zeros(n, bool)
    sigma = np.full(n, np.nan)
    c = None if n == 0 else _symmetric_cross(ax, ay, bend_u, bend_v, half, arm, margin_px)
    if c is None:
        return out, ok, sigma
    idx, w, dx, dy, n_u, n_v = c.idx, c.w, c.dx, c.dy, c.n_u, c.n_v
    u2, v2 = (c.u ** 2).astype(np.float32), (c.v ** 2).astype(np.float32)
    uf, vf = c.u.astype(np.float32), c.v.astype(np.float32)
    fit_bend = bend_spread is not None
    p = np.zeros((len(idx), 6 if fit_bend else 4))  # q_x, q_y, shading gradient s_u, s_v[, bend_u, bend_v]
    p[:, :2] = uv[idx]
    prior = np.column_stack([bend_u[idx], bend_v[idx]])
    sig2 = np.maximum(bend_spread[idx], 1e-6) ** 2 if fit_bend else None
    if fit_bend:
        p[:, 4:] = prior
    fit = FitProgress(len(idx))
    for _ in range(iters):
        act = fit.act
        pa = p[act]
        ba = pa[:, 4:] if fit_bend else prior[act]
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
            _add_bend_prior(H, g, wa, r, pa[:, 4:], prior[act], sig2[act])
        step, bad = newton_steps(H, g)
        step[:, :2] = np.clip(step[:, :2], -0.5, 0.5)
        if fit_bend:
            step[:, 4:] = np.clip(step[:, 4:], -2.0, 2.0)
        p[act] += step
        if not fit.retire(step, bad, H, wa, r, tol):
            break
    # A corner whose cross is mostly outside the image, or that wandered off, keeps its start.
    q = p[:, :2]
    fit.store(out, ok, sigma, idx, q, np.linalg.norm(q - uv[idx], axis=1) < np.maximum(1.0, 0.15 * c.sq))
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
