"""The overlapping Allan deviation of one IMU axis and its equivalent degrees of freedom.

Conventions: an axis is a rate-like series `x` (N,) sampled at `rate_hz` (gyroscope rad/s,
accelerometer m/s^2); tau in seconds; the deviation in the axis' unit. The deviation
itself is allantools' `oadev` (frequency data: the series is integrated to "phase" inside,
so a constant offset such as gravity drops out). Taus are octave-spaced cluster sizes
m = 1, 2, 4, ... samples up to a tenth of the recording, where an overlapping estimate
still averages about ten independent clusters.
"""

from __future__ import annotations

from dataclasses import dataclass

import allantools
import numpy as np

MAX_TAU_FRACTION = 0.1  # the longest tau: a tenth of the recording

# Power-law exponent alpha of each noise term seen as frequency data (Greenhall's edf):
# quantisation = white phase (+2), white noise = white frequency (0), bias instability =
# flicker frequency (-1), random walk = random-walk frequency (-2).
ALPHA = {"quantisation": 2, "white": 0, "flicker": -1, "random_walk": -2}


@dataclass(frozen=True)
class AllanCurve:
    """One axis' overlapping Allan deviation: tau (K,) s, adev (K,), m (K,) cluster sizes in
    samples, over n samples at rate_hz."""

    tau: np.ndarray
    adev: np.ndarray
    m: np.ndarray
    n: int
    rate_hz: float


def octave_clusters(n: int, fraction: float = MAX_TAU_FRACTION) -> np.ndarray:
    """Cluster sizes m = 1, 2, 4, ... <= fraction * n (at least [1])."""
    top = max(int(np.floor(np.log2(max(fraction * n, 1.0)))), 0)
    return 2 ** np.arange(top + 1, dtype=np.int64)


def allan_deviation(x: np.ndarray, rate_hz: float) -> AllanCurve:
    """The overlapping Allan deviation of one axis x (N,) at octave taus (allantools.oadev)."""
    x = np.asarray(x, np.float64)
    m = octave_clusters(len(x))
    tau, adev, _, _ = allantools.oadev(x - x.mean(), rate=rate_hz, data_type="freq", taus=m / rate_hz)
    m_used = np.rint(np.asarray(tau) * rate_hz).astype(np.int64)
    return AllanCurve(np.asarray(tau, float), np.asarray(adev, float), m_used, len(x), float(rate_hz))


def edf(alpha: int, m: np.ndarray, n: int) -> np.ndarray:
    """Equivalent degrees of freedom of the overlapping Allan variance at cluster sizes m (K,)
    for power-law noise alpha over n samples (Greenhall and Riley's algorithm, allantools).
    The variance estimate is then chi-square distributed: edf * est / true ~ chi2(edf)."""
    # allantools counts n as phase points; frequency data of n samples gives n + 1
    return np.array([float(allantools.edf_greenhall(alpha=alpha, d=2, m=int(k), N=int(n) + 1, overlapping=True))
                     for k in np.atleast_1d(m)])
