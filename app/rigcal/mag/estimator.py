"""The joint estimate: hard iron, soft iron, R_imu_mag, the field's inclination (and its
magnitude where the site's is declared), the gyroscope and accelerometer biases and one
orientation per window, by nonlinear least squares over

  - every magnetometer reading:  m - (inv(A) R_imu_mag.T R_world_imu(t).T b_world + h), sigma the
    declared per-sample noise;
  - the accelerometer at about the magnetometer's rate:  accel - (R_world_imu(t).T [0, 0, g] + b_a),
    sigma the residuals' own RMS (the hand's accelerations, not the sensor's noise, dominate it),

with R_world_imu(t) = R_world_window(k) dR(t; b_g), the gyroscope's integral inside window k
(attitude.py). The start: the ellipsoid fit (ellipsoid.py), the rotation-rate alignment
(attitude.py) and each window's orientation from its mean field and mean specific force
(TRIAD). Without a declared site field the optimisation holds F at the ellipsoid's value and
the result is rescaled to det A = 1.

The solver: Levenberg-Marquardt on the analytic Jacobian with the window orientations
eliminated by a batched Schur complement (3x3 blocks), so a step costs one pass over the
rows; scipy's least_squares (trf, lsmr) on the same residuals and Jacobian reaches the same
optimum 5-10x slower and is the tests' reference (least_squares_solve).

1-sigma: from the Jacobian at the solution (the inverse of the Schur complement of J.T J:
the globals' covariance with the windows marginalised), with each residual kind's
sigma inflated by its integrated autocorrelation time (correlated residuals carry fewer
independent samples than rows), and the whole covariance scaled by (RMS / declared)^2 where the
magnetometer's residuals exceed its declared noise; `sigma_basis` says which applied.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from threadpoolctl import threadpool_limits

from rigcal.core import geometry as geo
from rigcal.mag import model
from rigcal.mag.attitude import Windows, corrected, integrate_windows_at, rate_alignment
from rigcal.mag.ellipsoid import EllipsoidFit, check_coverage, fit_ellipsoid

GRAVITY = 9.80665
WINDOW_S = 2.0  # each window's orientation is free; inside it the gyroscope holds
N_GLOBAL = 20  # h 3, A 6, dR_imu_mag 3, inclination 1, gyro bias 3, accel bias 3, clock offset 1
OFFSET = 19  # the clock offset's index: seconds added to the declared time_offset_s
ACCEL_SIGMA_START = 0.2  # m/s^2: the first pass's weight, before the residuals give their own


@dataclass(frozen=True)
class MagInput:
    """What the estimator needs: IMU samples t_imu (M,) s, gyro (M, 3), accel (M, 3); the
    magnetometer's t_mag (N,) s on the IMU clock and raw m (N, 3) uT; the IMU's R_body_imu,
    the declared R_body_mag, the per-sample sigma (uT) and the site field (uT) if declared."""

    t_imu: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    t_mag: np.ndarray
    m: np.ndarray
    R_body_imu: np.ndarray
    R_body_mag_declared: np.ndarray
    sigma_uT: float
    earth_field_uT: float | None = None
    label: str = "magnetometer"
    estimate_offset: bool = False  # also estimate the clock offset (the rig declares time_offset_s)


@dataclass(frozen=True)
class MagResult:
    """A magnetometer's calibration (model.py's notation) with 1-sigma and diagnostics."""

    hard_iron: np.ndarray
    soft_iron: np.ndarray
    R_imu_mag: np.ndarray
    R_body_mag: np.ndarray
    field_uT: float
    inclination_deg: float
    residual_rms_uT: float
    residual_rms_declared_uT: float
    sigma_hard_iron: np.ndarray
    sigma_soft_iron: np.ndarray
    sigma_rotation_deg: np.ndarray  # about the body F, L, U axes
    sigma_field_uT: float
    sigma_inclination_deg: float
    heading_sigma_deg: float  # RMS over level headings of the heading 1-sigma the calibration leaves
    sigma_basis: str
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    accel_residual_rms: float
    windows: int
    start: EllipsoidFit
    R_imu_mag_start: np.ndarray
    seconds: float
    residuals_uT: np.ndarray = field(repr=False)  # (N, 3) raw-reading residuals at the solution
    R_world_imu: np.ndarray | None = field(default=None, repr=False)  # (N, 3, 3) at each reading, estimated
    t_mag: np.ndarray | None = field(default=None, repr=False)  # (N,) the readings' times, s (IMU clock)
    time_offset_s: float = 0.0  # the estimated correction to the declared offset (0 when not estimated)
    sigma_time_offset_s: float | None = None  # None when not estimated


@dataclass(frozen=True)
class _Problem:
    inp: MagInput
    wm: Windows  # gyro integrals at the magnetometer's times
    wa: Windows  # ... and at the accelerometer rows used
    accel: np.ndarray
    F: float
    R0: np.ndarray  # R_imu_mag the rotation parameter perturbs
    Rk0: np.ndarray  # (K, 3, 3) window orientations the window parameters perturb
    sigma_a: float
    omega_m: np.ndarray  # (N, 3) the raw gyroscope at the magnetometer's times (for the clock offset)


def _unpack(p: _Problem, x: np.ndarray):
    h, a, dr, incl, bg, ba = x[0:3], x[3:9], x[9:12], x[12], x[13:16], x[16:19]
    Rk = p.Rk0 @ geo.R_from_rotvec(x[N_GLOBAL:].reshape(-1, 3))
    return h, model.sym_from_vec(a), p.R0 @ geo.R_from_rotvec(dr), incl, bg, ba, Rk


def _field_imu(p: _Problem, x: np.ndarray, Rk: np.ndarray, bg: np.ndarray, incl: float):
    """The field in IMU axes at each reading's instant shifted by the clock offset x[OFFSET]:
    (b' (N, 3), b_imu (N, 3) unshifted, E (N, 3, 3) = Exp((omega - b_g) dt) or None where the
    offset is 0 (E = I), Dm (N, 3, 3) the gyro integrals, u (N, 3) the field in each reading's
    window frame). R_world_imu = Rk[window] @ Dm is never formed: b_imu = Dm.T @ u."""
    u = (Rk.transpose(0, 2, 1) @ model.field_world(p.F, incl))[p.wm.window]
    Dm = corrected(p.wm, bg - p.wm.bias)
    b_imu = _mat_T_vec(Dm, u)
    if x[OFFSET] == 0.0:
        return b_imu, b_imu, None, Dm, u
    E = geo.R_from_rotvec((p.omega_m - bg) * x[OFFSET])
    return _mat_T_vec(E, b_imu), b_imu, E, Dm, u


def _mat_T_vec(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R[n].T @ v[n] for R (N, 3, 3), v (N, 3)."""
    return (v[:, None, :] @ R)[:, 0]


def _cross_cols(v: np.ndarray, B: np.ndarray) -> np.ndarray:
    """skew(v[n]) @ B[n] for v (N, 3), B (N, 3, 3): v crossed with each column of B."""
    return np.cross(v[:, :, None], B, axis=1)


def _residuals(x: np.ndarray, p: _Problem) -> np.ndarray:
    h, A, R_im, incl, bg, ba, Rk = _unpack(p, x)
    b_shift = _field_imu(p, x, Rk, bg, incl)[0]
    n = len(b_shift)
    out = np.empty(3 * (n + len(p.accel)))
    rm, ra = out[:3 * n].reshape(n, 3), out[3 * n:].reshape(-1, 3)
    np.matmul(b_shift, (np.linalg.inv(A) @ R_im.T).T, out=rm)
    rm += h - p.inp.m
    rm /= p.inp.sigma_uT
    Da = corrected(p.wa, bg - p.wa.bias)
    np.matmul((GRAVITY * Rk[:, 2, :])[p.wa.window][:, None, :], Da, out=ra[:, None, :])  # R.T [0, 0, g]
    ra += ba - p.accel
    ra /= p.sigma_a
    return out


_E = np.zeros((6, 3, 3))  # d A / d a_k for the 6 symmetric elements (model.SYM_INDEX)
for _k, (_i, _j) in enumerate(model.SYM_INDEX):
    _E[_k, _i, _j] = _E[_k, _j, _i] = 1.0


def _jacobian_blocks(x: np.ndarray, p: _Problem) -> tuple[np.ndarray, np.ndarray]:
    """d residuals / d x, analytic, as G (rows, 20) over the globals and W (rows, 3) over each
    row's window. Rotations are perturbed on the right (R Exp(d));
    the Jacobian is exact where the rotation parameters are zero (the estimate folds them into
    R0 and Rk0 before the covariance) and first-order accurate near it, which only slows the
    iterations a little. Vectorised over the rows: 3x3 products batched, skew products as
    cross products, the (rows, 3, 20) block filled in place."""
    h, A, R_im, incl, bg, ba, Rk = _unpack(p, x)
    Ainv = np.linalg.inv(A)
    db_w = p.F * np.array([0.0, -np.sin(incl), -np.cos(incl)])
    b_sh, b_imu, E, Dm, u = _field_imu(p, x, Rk, bg, incl)
    w = b_sh @ R_im
    y = w @ Ainv.T
    M = Ainv @ R_im.T  # (3, 3)
    n, na = len(b_imu), len(p.accel)
    G = np.zeros((n + na, 3, N_GLOBAL))
    W = np.empty((n + na, 3, 3))
    Gm, Ga = G[:n], G[n:]
    Gm[:, :, 0:3] = np.eye(3)
    Gm[:, :, 3:9] = -np.tensordot(y, np.einsum("ij,kjl->kil", Ainv, _E), axes=([1], [2])).transpose(0, 2, 1)
    Gm[:, :, 9:12] = Ainv @ geo.skew(w)
    d_incl = _mat_T_vec(Dm, (Rk.transpose(0, 2, 1) @ db_w)[p.wm.window])  # d b_imu / d incl
    gyro = _cross_cols(b_imu, _bias_jacobian(p.wm, bg))  # d b_imu / d b_g, up to sign
    wins = -_cross_cols(u, Dm).transpose(0, 2, 1)  # Dm.T skew(u)
    if E is not None:
        ET = E.transpose(0, 2, 1)
        d_incl = (ET @ d_incl[:, :, None])[:, :, 0]
        gyro = ET @ gyro - x[OFFSET] * geo.skew(b_sh)
        wins = ET @ wins
    Gm[:, :, 12] = d_incl @ M.T
    Gm[:, :, 13:16] = M @ gyro
    if p.inp.estimate_offset:
        Gm[:, :, OFFSET] = np.cross(b_sh, p.omega_m - bg) @ M.T
    np.matmul(M, wins, out=W[:n])
    Da = corrected(p.wa, bg - p.wa.bias)
    ga = (GRAVITY * Rk[:, 2, :])[p.wa.window]
    f0 = (ga[:, None, :] @ Da)[:, 0]
    Ga[:, :, 13:16] = _cross_cols(f0, _bias_jacobian(p.wa, bg))
    Ga[:, :, 16:19] = np.eye(3)
    W[n:] = -_cross_cols(ga, Da).transpose(0, 2, 1)  # Da.T skew(ga)
    G[:n] /= p.inp.sigma_uT
    G[n:] /= p.sigma_a
    W[:n] /= p.inp.sigma_uT
    W[n:] /= p.sigma_a
    return G.reshape(-1, N_GLOBAL), W.reshape(-1, 3)


def _row_windows(p: _Problem) -> np.ndarray:
    return np.concatenate([np.repeat(p.wm.window, 3), np.repeat(p.wa.window, 3)])


def _jacobian(x: np.ndarray, p: _Problem) -> sp.csr_matrix:
    """d residuals / d x as one sparse matrix (_jacobian_blocks assembled)."""
    G, W = _jacobian_blocks(x, p)
    win = _row_windows(p)
    rows = np.arange(len(G))
    r = np.concatenate([np.repeat(rows, N_GLOBAL), np.repeat(rows, 3)])
    c = np.concatenate([np.tile(np.arange(N_GLOBAL), len(G)), (N_GLOBAL + 3 * win[:, None] + np.arange(3)).ravel()])
    return sp.csr_matrix((np.concatenate([G.ravel(), W.ravel()]), (r, c)), shape=(len(G), N_GLOBAL + 3 * len(p.Rk0)))


@dataclass(frozen=True)
class _Normal:
    """The normal equations J.T J, J.T r by blocks: globals (19) and one 3x3 block per window."""

    Hgg: np.ndarray  # (19, 19)
    Hgw: np.ndarray  # (K, 19, 3)
    Hww: np.ndarray  # (K, 3, 3)
    bg: np.ndarray  # (19,)
    bw: np.ndarray  # (K, 3)


def _normal(G: np.ndarray, W: np.ndarray, r: np.ndarray, win: np.ndarray, K: int) -> _Normal:
    P = sp.csr_matrix((np.ones(len(win)), (win, np.arange(len(win)))), shape=(K, len(win)))  # window sums
    Hgw = np.stack([(P @ (G * W[:, c:c + 1])) for c in range(3)], axis=2)
    Hww = np.stack([np.stack([P @ (W[:, i] * W[:, j]) for j in range(3)], axis=1) for i in range(3)], axis=1)
    Hgg = G.T @ G
    held = np.flatnonzero(np.diag(Hgg) == 0)  # a parameter not estimated (the clock offset): its step is 0
    Hgg[held, held] = 1.0
    return _Normal(Hgg, Hgw, Hww, G.T @ r, np.stack([P @ (W[:, c] * r) for c in range(3)], axis=1))


def _schur_step(n: _Normal, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """The damped Gauss-Newton step (globals (19,), windows (K, 3)): the windows eliminated
    by a batched Schur complement, Levenberg-Marquardt damping lam on every diagonal."""
    Hww = n.Hww + lam * np.einsum("kii->ki", n.Hww)[:, :, None] * np.eye(3)
    Hinv = np.linalg.inv(Hww)
    HgwHinv = n.Hgw @ Hinv  # (K, 19, 3)
    S = n.Hgg + lam * np.diag(np.diag(n.Hgg)) - np.einsum("kia,kja->ij", HgwHinv, n.Hgw)
    rhs = -n.bg + np.einsum("kia,ka->i", HgwHinv, n.bw)
    dg = np.linalg.solve(S, rhs)
    dw = -np.einsum("kab,kb->ka", Hinv, n.bw + np.einsum("kia,i->ka", n.Hgw, dg))
    return dg, dw


def _global_covariance(n: _Normal) -> np.ndarray:
    """(19, 19) covariance of the globals, the windows marginalised: inv of the Schur complement."""
    Hinv = np.linalg.inv(n.Hww)
    S = n.Hgg - np.einsum("kia,kab,kjb->ij", n.Hgw, Hinv, n.Hgw)
    return np.linalg.inv(S)


def _gauss_newton(p: _Problem, x: np.ndarray, tol: float, max_iter: int = 30) -> np.ndarray:
    """Levenberg-Marquardt on the residuals with the Schur-complement step: the estimate x."""
    K = len(p.Rk0)
    win = _row_windows(p)
    r = _residuals(x, p)
    cost = float(r @ r)
    lam = 1e-4
    for _ in range(max_iter):
        G, W = _jacobian_blocks(x, p)
        n = _normal(G, W, r, win, K)
        while True:
            dg, dw = _schur_step(n, lam)
            x_new = x + np.concatenate([dg, dw.ravel()])
            r_new = _residuals(x_new, p)
            c_new = float(r_new @ r_new)
            if c_new <= cost:
                break
            lam *= 10.0
            if lam > 1e6:
                return x
        done = cost - c_new <= tol * cost
        x, r, cost, lam = x_new, r_new, c_new, max(lam / 10.0, 1e-9)
        if done:
            break
    return x


def _bias_jacobian(w: Windows, bg: np.ndarray) -> np.ndarray:
    """(N, 3, 3) d(rotation vector on the right of corrected(w, db)) / d b_g: w.J through the
    right Jacobian of Exp at phi = J db, to second order (I - skew(phi) / 2)."""
    phi = w.J @ (bg - w.bias)
    return w.J - 0.5 * _cross_cols(phi, w.J)


def least_squares_solve(p: _Problem, x: np.ndarray, tol: float) -> np.ndarray:
    """scipy's least_squares (trf, lsmr) on the same residuals and Jacobian: the reference the
    tests hold _gauss_newton to (5-10x slower on long recordings)."""
    from scipy.optimize import least_squares  # the tests' reference only: its import is not the CLI's to pay

    # one BLAS thread: lsmr's many vector products slow down several-fold when BLAS threads
    # compete for 2 cores (measured: 14 s -> 7 s for a 60 s recording under load)
    with threadpool_limits(1, user_api="blas"):
            return least_squares(_residuals, x, jac=_jacobian, args=(p,), x_scale="jac", method="trf",
                             tr_solver="lsmr", xtol=tol, ftol=tol).x


def _triad(f: np.ndarray, u: np.ndarray, b_w: np.ndarray) -> np.ndarray:
    """R_world_frame (K, 3, 3) from the specific force f (K, 3) (world up) and field u (K, 3)
    seen in each window's frame, world field b_w (3,)."""
    def frame(a, b):
        e1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        e2 = np.cross(a, b)
        e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
        return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)
    W = frame(np.array([0.0, 0.0, 1.0]), b_w)
    return W @ np.transpose(frame(f, u), (0, 2, 1))


def _window_means(w: Windows, v: np.ndarray, K: int) -> np.ndarray:
    """(K, 3) per window the sum of vectors v (N, 3) carried into the window's first frame."""
    out = np.zeros((K, 3))
    np.add.at(out, w.window, np.einsum("nij,nj->ni", w.dR, v))
    return out


def _autocorr_time(r: np.ndarray, max_lag: int = 400) -> float:
    """Integrated autocorrelation time (>= 1, in samples) of residual columns r (N, D), summed
    until the autocorrelation falls below 0.05."""
    r = r - r.mean(axis=0)
    var = (r * r).mean()
    if var <= 0:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, len(r) // 4)):
        rho = (r[k:] * r[:-k]).mean() / var
        if rho < 0.05:
            break
        tau += 2.0 * rho
    return tau


def _start(inp: MagInput) -> tuple[EllipsoidFit, np.ndarray, np.ndarray]:
    """The closed-form start: the ellipsoid fit (refusing poor coverage), the readings it
    calibrates (N, 3, chip axes) and R_imu_mag from the rotation-rate alignment."""
    fit = fit_ellipsoid(inp.m, inp.earth_field_uT, inp.label)
    check_coverage(inp.m, fit, inp.label)
    c = (inp.m - fit.hard_iron) @ fit.soft_iron.T
    omega = np.stack([np.interp(inp.t_mag, inp.t_imu, inp.gyro[:, i]) for i in range(3)], axis=1)
    R_im = rate_alignment(inp.t_mag, c, omega)
    return fit, c, R_im


def _fold(p: _Problem, x: np.ndarray) -> tuple[_Problem, np.ndarray]:
    """The rotation parameters moved into R0 and Rk0 (x's rotation entries zero)."""
    _, _, R_im, _, _, _, Rk = _unpack(p, x)
    K = len(p.Rk0)
    return (_Problem(p.inp, p.wm, p.wa, p.accel, p.F, R_im, Rk, p.sigma_a, p.omega_m),
            np.concatenate([x[:9], np.zeros(3), x[12:N_GLOBAL], np.zeros(3 * K)]))


def estimate(inp: MagInput, window_s: float = WINDOW_S, solve=None) -> MagResult:
    """The joint estimate of one magnetometer against its IMU (module docstring). `solve(p, x,
    tol) -> x`: the least-squares solver (default the Schur-complement Levenberg-Marquardt;
    the tests pass scipy's least_squares, the slow reference). BLAS runs on one thread: its
    products here are small ((N, 3) by (3, 3), (rows, 20) by (20, 20)), and more threads only
    spin against each other (measured on a 10-minute recording: 7.6 s wall, 3.9 s CPU with
    the default threads; 3.0 s wall, 2.0 s CPU with one)."""
    with threadpool_limits(1, user_api="blas"):
        return _estimate(inp, window_s, _gauss_newton if solve is None else solve)


def _estimate(inp: MagInput, window_s: float, solve) -> MagResult:
    t0 = time.perf_counter()
    fit, c, R_im = _start(inp)
    step = max(1, int(round(len(inp.t_imu) / (inp.t_imu[-1] - inp.t_imu[0]) / 50.0)))  # accel rows at ~50 Hz
    ia = np.arange(0, len(inp.t_imu), step)
    ia = ia[(inp.t_imu[ia] >= inp.t_imu[0]) & (inp.t_imu[ia] < inp.t_imu[-1])]
    keep = (inp.t_mag >= inp.t_imu[0]) & (inp.t_mag < inp.t_imu[-1])
    inp = MagInput(**{**inp.__dict__, "t_mag": inp.t_mag[keep], "m": inp.m[keep]})
    c = c[keep]
    bias = np.zeros(3)
    wm, wa = integrate_windows_at(inp.t_imu, inp.gyro, (inp.t_mag, inp.t_imu[ia]), window_s, bias)
    K = wm.n
    u = _window_means(wm, c @ R_im.T, K)
    f = _window_means(wa, inp.accel[ia], K)
    sin_i = -np.einsum("ki,ki->k", u, f) / (np.linalg.norm(u, axis=1) * np.linalg.norm(f, axis=1))
    incl = float(np.arcsin(np.clip(np.median(sin_i), -1, 1)))
    Rk0 = _triad(f, u, model.field_world(fit.field_uT, incl))
    x = np.concatenate([fit.hard_iron, model.vec_from_sym(fit.soft_iron), np.zeros(3), [incl], np.zeros(7),
                        np.zeros(3 * K)])
    # pass 1 with a guessed accelerometer sigma; pass 2 re-linearises the gyro integrals at the
    # bias found and weights the accelerometer by its own residuals (inflated by their correlation)
    omega_m = np.stack([np.interp(inp.t_mag, inp.t_imu, inp.gyro[:, i]) for i in range(3)], axis=1)
    p = _Problem(inp, wm, wa, inp.accel[ia], fit.field_uT, R_im, Rk0, ACCEL_SIGMA_START, omega_m)
    x = solve(p, x, 1e-6)
    ra = _residuals(x, p)[3 * len(inp.t_mag):].reshape(-1, 3) * ACCEL_SIGMA_START
    sigma_a = float(np.sqrt((ra ** 2).mean()) * np.sqrt(_autocorr_time(ra)))
    for tol in (1e-10, 0.0):  # then once more from the folded rotations: the Jacobian there is exact
        p, x = _fold(p, x)
        wm, wa = integrate_windows_at(inp.t_imu, inp.gyro, (inp.t_mag, inp.t_imu[ia]), window_s, x[13:16])
        p = _Problem(inp, wm, wa, inp.accel[ia], fit.field_uT, p.R0, p.Rk0, sigma_a, omega_m)
        if tol:
            x = solve(p, x, tol)
    return _result(p, x, fit, c, t0)


def _result(p: _Problem, x: np.ndarray, fit: EllipsoidFit, c: np.ndarray, t0: float) -> MagResult:
    inp = p.inp
    h, A, R_im, incl, bg, ba, _ = _unpack(p, x)
    n_m = 3 * len(inp.t_mag)
    rm = _residuals(x, p)[:n_m].reshape(-1, 3) * inp.sigma_uT
    rms = float(np.sqrt((rm ** 2).mean()))
    tau_m = _autocorr_time(rm)
    G, W = _jacobian_blocks(x, p)
    C = _global_covariance(_normal(G, W, np.zeros(len(G)), _row_windows(p), len(p.Rk0)))
    ratio = rms / inp.sigma_uT
    # the declared noise is "off" beyond 5 % (the RMS of 10^4 residuals scatters by ~1 %)
    scale = (ratio ** 2 if ratio > 1.05 else 1.0) * (tau_m if tau_m > 1.5 else 1.0)
    basis = ("from the declared noise" if scale == 1.0 else
             f"scaled by the residual fit (x{np.sqrt(scale):.2f}: RMS {ratio:.2f}x the declared noise"
             + (f", autocorrelation time {tau_m:.1f} samples" if tau_m > 1.0 else "") + ")")
    C = C * scale
    # soft iron and field: normalised to det 1 without a declared site field (delta method)
    a = model.vec_from_sym(A)

    def norm(av: np.ndarray) -> np.ndarray:
        if inp.earth_field_uT is not None:
            return np.concatenate([av, [p.F]])
        An, Fn = model.normalise(model.sym_from_vec(av), p.F)
        return np.concatenate([model.vec_from_sym(An), [Fn]])
    G = _numeric_jacobian(norm, a)
    Caf = G @ C[3:9, 3:9] @ G.T
    out = norm(a)
    A_n, F_n = model.sym_from_vec(out[:6]), float(out[6])
    R_body_mag = inp.R_body_imu @ R_im
    C_rot = R_body_mag @ C[9:12, 9:12] @ R_body_mag.T
    heading = _heading_sigma(h, A, R_im, inp.R_body_imu, p.F, incl, C[:12, :12])
    offset_sigma = float(np.sqrt(C[OFFSET, OFFSET])) if inp.estimate_offset else None
    return MagResult(
        hard_iron=h, soft_iron=A_n, R_imu_mag=R_im, R_body_mag=R_body_mag, field_uT=F_n,
        inclination_deg=float(np.degrees(incl)), residual_rms_uT=rms, residual_rms_declared_uT=float(inp.sigma_uT),
        sigma_hard_iron=np.sqrt(np.diag(C[:3, :3])), sigma_soft_iron=model.sym_from_vec(np.sqrt(np.diag(Caf)[:6])),
        sigma_rotation_deg=np.degrees(np.sqrt(np.diag(C_rot))), sigma_field_uT=float(np.sqrt(Caf[6, 6])),
        sigma_inclination_deg=float(np.degrees(np.sqrt(C[12, 12]))), heading_sigma_deg=heading,
        sigma_basis=basis, gyro_bias=bg, accel_bias=ba, accel_residual_rms=p.sigma_a, windows=len(p.Rk0),
        start=fit, R_imu_mag_start=p.R0, seconds=time.perf_counter() - t0, residuals_uT=rm,
        R_world_imu=_unpack(p, x)[6][p.wm.window] @ _field_imu(p, x, _unpack(p, x)[6], bg, incl)[3], t_mag=inp.t_mag,
        time_offset_s=float(x[OFFSET]), sigma_time_offset_s=offset_sigma)


def _numeric_jacobian(fn, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    f0 = fn(x)
    J = np.empty((len(f0), len(x)))
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        J[:, i] = (fn(x + d) - fn(x - d)) / (2 * eps)
    return J


def _heading_sigma(h, A, R_im, R_body_imu, F, incl, C12) -> float:
    """RMS over level headings of the heading 1-sigma (deg) from the covariance C12 of
    (h, A's 6, R_imu_mag's 3): readings predicted by the estimate, calibrated by perturbed
    parameters."""
    psi = model.level_headings()
    m = model.readings(model.level_fields(F, incl, psi), h, A, R_body_imu @ R_im)

    def head(v: np.ndarray) -> np.ndarray:
        R = R_body_imu @ R_im @ geo.R_from_rotvec(v[9:12])
        return model.heading_errors(m, psi, v[:3], model.sym_from_vec(v[3:9]), R)
    Jh = _numeric_jacobian(head, np.concatenate([h, model.vec_from_sym(A), np.zeros(3)]))
    var = np.einsum("ij,jk,ik->i", Jh, C12, Jh)
    return float(np.degrees(np.sqrt(var.mean())))
