"""The start of the camera-IMU calibration: clock offset and camera-IMU rotation
from rotation rates, and a refusal of recordings that cannot determine them.

Inputs are a camera's poses at its frame times (from PnP on the board views, or any other
source) and the IMU's gyroscope. Between two frames the camera turns by
Log(R_world_cam_k^T R_world_cam_k+1) (camera axes); over the same interval on the IMU
clock the gyroscope integrates to the same rotation in IMU axes (to second order in the
small inter-frame angle). Their magnitudes do not depend on the unknown camera-IMU
rotation, so the clock offset comes first (Kalibr's cross-correlation of rates), then the
rotation by Kabsch on the rate vectors (a hand-eye on angular velocities).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import CalibrationError

SEARCH_WINDOW_S = 0.2  # clock offsets searched within +- this of the declared one
SEARCH_STEP_S = 5e-4
MIN_SECOND_AXIS_RATE = np.radians(3.0)  # rad/s RMS about the second most excited rotation axis
MIN_ACCELERATION = 0.2  # m/s^2 RMS of the body's acceleration (gravity excluded)


@dataclass(frozen=True)
class RateStart:
    """A camera's start: time_offset_s (t_imu = t_cam + offset), R_imu_cam, the peak
    normalised correlation of the rate magnitudes, and the RMS rate residual (rad/s) of
    the rotation fit."""

    time_offset_s: float
    R_imu_cam: np.ndarray
    correlation: float
    rate_rms: float


def camera_rates(t_cam: np.ndarray, R_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_start (K,), t_end (K,), omega_cam (K, 3)) between consecutive frames: the mean
    angular velocity in camera axes over each interval."""
    rv = geo.rotvecs_from_R(np.swapaxes(R_world_cam[:-1], 1, 2) @ R_world_cam[1:])
    dt = np.diff(t_cam)
    return t_cam[:-1], t_cam[1:], rv / dt[:, None]


def gyro_means(t_imu: np.ndarray, gyro: np.ndarray, t_a: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    """Mean gyroscope vector over each interval [t_a, t_b] (any shape S), (S..., 3), from the
    trapezoid integral interpolated at the ends."""
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_imu)[:, None], axis=0)])
    W = lambda t: np.stack([np.interp(t, t_imu, cum[:, k]) for k in range(3)], axis=-1)  # noqa: E731
    return (W(t_b) - W(t_a)) / (t_b - t_a)[..., None]


def _correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised correlation of a (K,) with each row of b (T, K)."""
    a = a - a.mean()
    b = b - b.mean(axis=1, keepdims=True)
    return (b @ a) / np.maximum(np.linalg.norm(b, axis=1) * np.linalg.norm(a), 1e-300)


def time_offset_from_rates(t_cam: np.ndarray, R_world_cam: np.ndarray, t_imu: np.ndarray, gyro: np.ndarray,
                           guess_s: float = 0.0, window_s: float = SEARCH_WINDOW_S) -> tuple[float, float]:
    """(offset, peak correlation): the t_imu = t_cam + offset maximising the correlation of
    |camera rate| with |mean gyroscope| over the same intervals, searched on a grid within
    guess +- window and refined by a parabola through the peak. Raises CalibrationError when
    the peak lies on the window's edge (the offset is outside it) or the frames do not
    overlap the IMU stream."""
    ta, tb, w_cam = camera_rates(t_cam, R_world_cam)
    taus = guess_s + np.arange(-window_s, window_s + SEARCH_STEP_S / 2, SEARCH_STEP_S)
    inside = (ta + taus.min() >= t_imu[0]) & (tb + taus.max() <= t_imu[-1])
    if inside.sum() < 10:
        raise CalibrationError(f"only {int(inside.sum())} camera frame intervals overlap the IMU stream within the "
                               f"+-{window_s:g} s offset search; expected at least 10")
    ta, tb, rate = ta[inside], tb[inside], np.linalg.norm(w_cam[inside], axis=1)
    imu_rate = np.linalg.norm(gyro_means(t_imu, gyro, ta[None] + taus[:, None], tb[None] + taus[:, None]), axis=-1)
    c = _correlation(rate, imu_rate)
    k = int(np.argmax(c))
    if k == 0 or k == len(taus) - 1:
        raise CalibrationError(f"the camera-IMU clock offset lies outside the search window {guess_s:+.3f} "
                               f"+- {window_s:g} s; declare time_offset_s nearer the truth or widen the window")
    den = c[k - 1] - 2 * c[k] + c[k + 1]
    frac = 0.5 * (c[k - 1] - c[k + 1]) / den if den < 0 else 0.0
    return float(taus[k] + frac * SEARCH_STEP_S), float(c[k])


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising sum |a_k - R b_k|^2 for a, b (K, 3)."""
    return geo.nearest_rotation(a.T @ b)


def check_rotation_excitation(omega: np.ndarray, what: str) -> None:
    """Refuse rates (K, 3) that turn about fewer than two axes: the RMS rate about the
    second principal axis must reach MIN_SECOND_AXIS_RATE."""
    s = np.linalg.svd(omega, compute_uv=False) / np.sqrt(max(len(omega), 1))
    if len(s) < 2 or s[1] < MIN_SECOND_AXIS_RATE:
        raise CalibrationError(
            f"{what}: the recording turns about fewer than two axes (RMS rates about the principal axes "
            f"{', '.join(f'{np.degrees(x):.2f}' for x in s)} deg/s; the second must reach "
            f"{np.degrees(MIN_SECOND_AXIS_RATE):.0f} deg/s): the camera-IMU rotation and time offset are not "
            f"determined; record again turning about at least two axes")


def check_acceleration(a_world: np.ndarray, what: str) -> None:
    """Refuse a trajectory (accelerations (K, 3), gravity excluded) that never accelerates:
    the lever arms and gravity's direction need it."""
    rms = float(np.sqrt(np.mean(np.sum((a_world - a_world.mean(axis=0)) ** 2, axis=1))))
    if rms < MIN_ACCELERATION:
        raise CalibrationError(f"{what}: the recording hardly accelerates (RMS {rms:.3f} m/s^2, need "
                               f"{MIN_ACCELERATION:g}): camera-IMU translations are not determined; record again "
                               f"moving the rig back and forth along its axes")


def rate_start(t_cam: np.ndarray, R_world_cam: np.ndarray, t_imu: np.ndarray, gyro: np.ndarray,
               guess_s: float = 0.0, window_s: float = SEARCH_WINDOW_S, what: str = "camera") -> RateStart:
    """Clock offset, then R_imu_cam, of one camera from its poses at frame times t_cam
    (camera clock) and the gyroscope; refuses a recording whose gyroscope, over the camera's
    span, turns about one axis only."""
    ta, tb, w_cam = camera_rates(t_cam, R_world_cam)
    # judged on the gyroscope: pose noise differentiated at the frame rate (~1-3 deg/s for
    # PnP) would pass a one-axis recording
    span = (t_imu >= t_cam[0] + guess_s - window_s) & (t_imu <= t_cam[-1] + guess_s + window_s)
    if span.sum() < 10:
        raise CalibrationError(f"{what}: its frames ({t_cam[0]:.3f} .. {t_cam[-1]:.3f} s, offset {guess_s:+.3f} "
                               f"+- {window_s:g} s) do not overlap the IMU stream ({t_imu[0]:.3f} .. {t_imu[-1]:.3f} s)")
    check_rotation_excitation(gyro[span], what)
    offset, corr = time_offset_from_rates(t_cam, R_world_cam, t_imu, gyro, guess_s, window_s)
    inside = (ta + offset >= t_imu[0]) & (tb + offset <= t_imu[-1])
    w_imu = gyro_means(t_imu, gyro, ta[inside] + offset, tb[inside] + offset)
    R = kabsch(w_imu, w_cam[inside])
    rms = float(np.sqrt(np.mean(np.sum((w_imu - w_cam[inside] @ R.T) ** 2, axis=1))))
    return RateStart(offset, R, corr, rms)


# ----------------------------------------------------------------------------- knot spacing

# the spacings tried, coarsest first: 0.05 s (20 knots/s) was the simulator's long-standing
# default, 0.01 s (Kalibr's 100 knots/s) what hand-waved motion needs
KNOT_CANDIDATES_S = (0.05, 0.04, 0.03, 0.025, 0.02, 0.015, 0.01, 0.0075, 0.005)
KNOT_TARGET = 1.5  # the spline must fit the IMU within this factor of its declared noise
KNOT_MIN_GAIN = 0.9  # or: a finer spacing that lowers the worse ratio by less than 10 % is not taken
FIT_DEGREE = 2  # a cubic pose spline's angular rate (and, nearly, its specific force) is quadratic per segment
MIN_SAMPLES_PER_KNOT = 2.0  # finer spacings fit the noise, not the motion


@dataclass(frozen=True)
class KnotChoice:
    """The chosen spline knot spacing (s), why (`reason`), and per spacing tried (dt, gyroscope
    ratio, accelerometer ratio): the RMS of a free spline fit's residuals over the declared
    noise (1 = the spline follows the motion as well as the sensor can tell)."""

    knot_dt: float
    tried: tuple
    reason: str

    def line(self) -> str:
        dt, g, a = self.tried[-1]
        return (f"knot spacing {self.knot_dt:g} s ({1 / self.knot_dt:.0f} knots/s), chosen from the IMU: a spline "
                f"with that spacing fits the gyroscope to {g:.2f}x and the accelerometer to {a:.2f}x their "
                f"declared noise ({self.reason}; --knot-spacing overrides)")


def spline_fit_ratio(t: np.ndarray, y: np.ndarray, dt: float, sigma: float) -> float:
    """How well a spline with knots every dt can follow a signal y (N, D) sampled at times t
    (N,): the RMS residual of a least-squares B-spline of FIT_DEGREE over sigma, with the
    degrees of freedom the fit absorbs taken out (sum r^2 / (N - coefficients) per channel),
    so pure white noise of sigma reads 1 at any spacing. Gaps in t are allowed (a tiny ridge
    keeps knots without samples determined). Linear in N."""
    from scipy.interpolate import BSpline
    import scipy.sparse as sps
    import scipy.sparse.linalg as spsla

    k = FIT_DEGREE
    inner = np.arange(t[0] + dt, t[-1] - 0.5 * dt, dt)
    knots = np.r_[[t[0]] * (k + 1), inner, [t[-1]] * (k + 1)]
    A = BSpline.design_matrix(np.clip(t, t[0], t[-1]), knots, k).tocsc()
    n = A.shape[1]
    H = (A.T @ A).tocsc()
    H = H + sps.identity(n, format="csc") * (1e-9 * float(H.diagonal().max()))
    c = spsla.splu(H).solve(np.asarray(A.T @ y))
    r = y - A @ c
    dof = max(len(t) - n, 1)
    return float(np.sqrt(np.sum(r ** 2) / (dof * y.shape[1]))) / sigma


def choose_knot_spacing(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, sigma_gyro: float, sigma_accel: float,
                        update_rate: float) -> KnotChoice:
    """The coarsest of KNOT_CANDIDATES_S at which a free spline follows the IMU's gyroscope
    and accelerometer to within KNOT_TARGET of their declared (discrete) noise; when none
    does (the noise declared too low, or vibration the spline cannot follow), the spacing
    where refining stops paying (the worse ratio falls by less than 1 - KNOT_MIN_GAIN),
    never finer than MIN_SAMPLES_PER_KNOT IMU samples per knot. On EuRoC's imu_april
    (200 Hz) the ratios at 0.05 s are 7.7x / 6.4x (the estimator's were 7.6x / 6.6x) and
    0.01 s is chosen."""
    floor = MIN_SAMPLES_PER_KNOT / update_rate
    cands = [dt for dt in KNOT_CANDIDATES_S if dt >= floor - 1e-12] or [max(KNOT_CANDIDATES_S[0], floor)]
    tried = []
    for dt in cands:
        g, a = spline_fit_ratio(t, gyro, dt, sigma_gyro), spline_fit_ratio(t, accel, dt, sigma_accel)
        if tried and max(g, a) > KNOT_MIN_GAIN * max(tried[-1][1:]):
            prev = tried[-1][0]
            return KnotChoice(prev, tuple(tried), f"finer, {dt:g} s, fits little better: {max(g, a):.2f}x; the "
                                                  f"declared noise may be too low")
        tried.append((dt, g, a))
        if max(g, a) <= KNOT_TARGET:
            return KnotChoice(dt, tuple(tried), f"the coarsest within {KNOT_TARGET:g}x")
    return KnotChoice(cands[-1], tuple(tried), f"the finest allowed ({MIN_SAMPLES_PER_KNOT:g} IMU samples per knot)")
