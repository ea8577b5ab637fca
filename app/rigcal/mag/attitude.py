"""Orientation from the gyroscope alone, in windows, and the rotation-rate alignment of a
magnetometer to its IMU.

Windows: the recording is cut into windows of `window_s` seconds; in each, the IMU's
orientation relative to the window's first sample is the gyroscope's integral

    R_w0_imu(t) = prod_j Exp((gyro_j - b_g) dt_j)         (midpoint rates)

and, to first order in a change db of the gyroscope bias (Forster et al. 2017),
R(b + db) = R(b) Exp(J(t) db) with J(t_{j+1}) = dR_j.T J(t_j) - dt_j I. A window's own
orientation in the world is the estimator's unknown; within it the gyroscope says how the
field must turn.

Rotation-rate alignment: a field fixed in the world turns in the magnetometer's axes as
dc/dt = c x (R_imu_mag.T omega_imu), which is linear in the nine entries of R_imu_mag.T;
their least-squares solution, projected on the rotations, is the closed-form start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.core import geometry as geo


@dataclass(frozen=True)
class Windows:
    """Gyro integrals at query times t (N,) seconds (IMU clock): window (N,) index, dR (N, 3, 3)
    = R_w0_imu(t) (orientation relative to the window's start), J (N, 3, 3) its bias Jacobian,
    bias (3,) the gyroscope bias it was integrated with; n windows, start (n,) their start times."""

    window: np.ndarray
    dR: np.ndarray
    J: np.ndarray
    bias: np.ndarray
    start: np.ndarray

    @property
    def n(self) -> int:
        return len(self.start)


def integrate_windows(t_imu: np.ndarray, gyro: np.ndarray, t_query: np.ndarray, window_s: float,
                      bias: np.ndarray | None = None) -> Windows:
    """Integrate the gyroscope (t_imu (M,) s, gyro (M, 3) rad/s) within windows of window_s from
    t_imu[0] and evaluate at t_query (N,) (inside the IMU stream), vectorised over windows."""
    return integrate_windows_at(t_imu, gyro, (t_query,), window_s, bias)[0]


def integrate_windows_at(t_imu: np.ndarray, gyro: np.ndarray, queries: tuple[np.ndarray, ...], window_s: float,
                         bias: np.ndarray | None = None) -> tuple[Windows, ...]:
    """integrate_windows at several sets of query times from one integration of the stream
    (the estimator queries it at the magnetometer's and the accelerometer rows' times). The
    loop runs over the sample index inside a window (window_s times the IMU rate, 400 at 200 Hz
    and 2 s), every window at once; a log-depth scan over all samples measured 4x slower."""
    bias = np.zeros(3) if bias is None else np.asarray(bias, float)
    t0 = t_imu[0]
    n_win = max(int(np.floor((t_imu[-1] - t0) / window_s)), 1)
    start = t0 + window_s * np.arange(n_win)
    # IMU sample index at which each window starts, and the window of every IMU interval
    first = np.searchsorted(t_imu, start)
    M = len(t_imu)
    dt = np.diff(t_imu)
    w = 0.5 * (gyro[1:] + gyro[:-1]) - bias  # midpoint rate on each interval j -> j+1
    step = geo.R_from_rotvec(w * dt[:, None])
    R = np.empty((M, 3, 3))
    J = np.empty((M, 3, 3))
    R[first] = np.eye(3)
    J[first] = 0.0
    last = np.append(first[1:], M)  # one past the window's last sample (the next window's first)
    for k in range(int((last - first).max()) - 1):
        j = first + k  # interval j -> j+1 of every window still running
        ok = j + 1 < last
        j = j[ok]
        R[j + 1] = R[j] @ step[j]
        J[j + 1] = np.transpose(step[j], (0, 2, 1)) @ J[j] - dt[j, None, None] * np.eye(3)
    out = []
    for t_query in queries:
        # query times: from the preceding IMU sample of the same window, at its rate
        idx = np.clip(np.searchsorted(t_imu, t_query, side="right") - 1, 0, M - 2)
        win = np.minimum(np.floor((t_query - t0) / window_s).astype(int), n_win - 1)
        idx = np.maximum(idx, first[win])
        tau = t_query - t_imu[idx]
        e = geo.R_from_rotvec(w[idx] * tau[:, None])
        dR = R[idx] @ e
        Jq = np.transpose(e, (0, 2, 1)) @ J[idx] - tau[:, None, None] * np.eye(3)
        out.append(Windows(win, dR, Jq, bias, start))
    return tuple(out)


def corrected(w: Windows, db: np.ndarray) -> np.ndarray:
    """dR (N, 3, 3) for the gyroscope bias w.bias + db, to first order in db."""
    return w.dR @ geo.R_from_rotvec(w.J @ db)


def rate_alignment(t: np.ndarray, c: np.ndarray, omega_imu: np.ndarray, smooth_s: float = 0.25) -> np.ndarray:
    """R_imu_mag (3, 3) from calibrated field directions c (N, 3, magnetometer axes) and the
    IMU's angular rates omega_imu (N, 3, rad/s) at the same uniformly spaced times t (N,):
    the least-squares solution of dc/dt = c x (R.T omega), projected on the rotations. Both
    signals are smoothed (Savitzky-Golay, smooth_s) before c is differentiated."""
    dt = float(np.median(np.diff(t)))
    n = max(int(round(smooth_s / dt)) | 1, 5)
    cs = savgol(c, n, 3)
    dc = savgol(c, n, 3, deriv=1, delta=dt)
    ws = savgol(omega_imu, n, 3)
    # c x (X w) = -skew(X w) c = skew(c) X w ... written as rows acting on X's 9 entries (row-major)
    K = geo.skew(cs)  # (N, 3, 3)
    # (X w)_i = sum_j X_ij w_j: d(Xw)/dX_ij = e_i w_j
    A = np.einsum("nik,nj->nikj", K, ws).reshape(len(t), 3, 9)
    Xv = np.linalg.lstsq(A.reshape(-1, 9), dc.reshape(-1), rcond=None)[0]
    # dc = c x (X w) = skew(c) X w -> X = R_imu_mag.T
    return geo.nearest_rotation(Xv.reshape(3, 3)).T


def savgol(x: np.ndarray, n: int, order: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Savitzky-Golay smoothing (or its deriv-th derivative) of x (N, D) along axis 0 over odd
    windows of n samples, the first and last n // 2 samples from the polynomial fitted to the
    first and last n: scipy.signal.savgol_filter's default (mode "interp"), in numpy alone
    (importing scipy.signal costs more than a 10-minute recording's whole fit)."""
    x = np.asarray(x, float)
    half = n // 2
    z = np.arange(n, dtype=float) - half
    fit = np.linalg.pinv(z[:, None] ** np.arange(order + 1))  # (order + 1, n): polynomial coefficients
    # the deriv-th derivative at z of the fitted polynomial, as weights on the n samples
    powers = np.arange(deriv, order + 1)
    scale = np.array([np.prod(np.arange(k - deriv + 1, k + 1)) for k in powers], float) / delta ** deriv
    at = (z[:, None] ** (powers - deriv)) * scale  # (n, order + 1 - deriv)
    weights = at @ fit[deriv:]  # (n, n): row i gives the value at sample i of the window
    out = np.empty_like(x)
    windows = np.lib.stride_tricks.sliding_window_view(x, n, axis=0)  # (N - n + 1, D, n)
    out[half:len(x) - half] = windows @ weights[half]
    out[:half] = weights[:half] @ x[:n]
    out[len(x) - half:] = weights[n - half:] @ x[len(x) - n:]
    return out
