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
from functools import lru_cache

import allantools
import numpy as np
from scipy.signal import fftconvolve

MAX_TAU_FRACTION = 0.1  # the longest tau: a tenth of the recording
MIN_SPAN_CLUSTERS = 4  # a stretch between gaps counts at cluster size m when it holds this many clusters

# Power-law exponent alpha of each noise term seen as frequency data (Greenhall's edf):
# quantisation = white phase (+2), white noise = white frequency (0), bias instability =
# flicker frequency (-1), random walk = random-walk frequency (-2).
ALPHA = {"quantisation": 2, "white": 0, "flicker": -1, "random_walk": -2}


@dataclass(frozen=True)
class AllanCurve:
    """One axis' overlapping Allan deviation: tau (K,) s, adev (K,), m (K,) cluster sizes in
    samples, over n samples at rate_hz (in one stretch, or in `segments` pooled)."""

    tau: np.ndarray
    adev: np.ndarray
    m: np.ndarray
    n: int
    rate_hz: float
    segments: tuple[int, ...] = ()  # the samples of each stretch pooled (pooled_allan_deviation); () = one of n

    def lengths(self) -> tuple[int, ...]:
        return self.segments or (self.n,)


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


def pooled_allan_deviation(parts: list[np.ndarray], rate_hz: float) -> AllanCurve:
    """The overlapping Allan deviation of one axis recorded in stretches between gaps: per
    octave m the mean of every stretch's squared second differences (no cluster spans a gap),
    i.e. each stretch's Allan variance weighted by its number of them; a stretch counts at m
    from MIN_SPAN_CLUSTERS clusters of m. Taus up to a tenth of the longest stretch."""
    parts = [np.asarray(x, np.float64) for x in parts]
    if len(parts) == 1:
        return allan_deviation(parts[0], rate_hz)
    lengths = tuple(len(x) for x in parts)
    m = octave_clusters(max(lengths))
    num, den = np.zeros(len(m)), np.zeros(len(m))
    for x in parts:
        ok = m[MIN_SPAN_CLUSTERS * m <= len(x)]
        if not len(ok):
            continue
        tau, adev, _, _ = allantools.oadev(x - x.mean(), rate=rate_hz, data_type="freq", taus=ok / rate_hz)
        mu = np.rint(np.asarray(tau) * rate_hz).astype(np.int64)
        idx = np.searchsorted(m, mu)
        terms = len(x) + 1 - 2 * mu  # second differences of the n + 1 phase points
        num[idx] += terms * np.asarray(adev, float) ** 2
        den[idx] += terms
    keep = den > 0
    return AllanCurve(m[keep] / rate_hz, np.sqrt(num[keep] / den[keep]), m[keep], int(sum(lengths)), float(rate_hz),
                      lengths)


def curve_edf(alpha: int, curve: AllanCurve, m: np.ndarray) -> np.ndarray:
    """edf of the curve's Allan variance at cluster sizes m: a pooled curve's stretches are
    independent, so their edf add (those with MIN_SPAN_CLUSTERS clusters of m)."""
    m = np.atleast_1d(m)
    if not curve.segments:
        return edf(alpha, m, curve.n)
    out = np.zeros(len(m))
    for n_s in curve.segments:
        ok = MIN_SPAN_CLUSTERS * m <= n_s
        if ok.any():
            out[ok] += edf(alpha, m[ok], n_s)
    return out


# the cluster size the shortest tau of a range is scaled down to in `correlation` (the
# white-noise and random-walk covariances are then within ~1/SCALED_M of their continuum form)
SCALED_M = 32


def _second_difference_filters(m: int) -> tuple[np.ndarray, np.ndarray]:
    """(g, h): the overlapping Allan estimator's second difference of phase at cluster size m,
    D_m(j) = sum_i g(i) y(j+i) over frequency samples y (g = m times -1 then m times +1), and
    the same difference over the increments e of a random-walk y: D_m(j) = sum_u h(u) e(j+u),
    h the triangle 1, 2, ..., m, ..., 1 (h(u) = sum of g(i) for i >= u)."""
    g = np.concatenate([-np.ones(m), np.ones(m)])
    h = np.concatenate([np.arange(1, m + 1), np.arange(m - 1, 0, -1)]).astype(float)
    return g, h


@lru_cache(maxsize=4096)
def _pair_sums(m1: int, m2: int) -> tuple[float, float, float]:
    """(Sww, Swr, Srr): for cluster sizes m1, m2 the sums over lags of R_w^2, R_w R_r and R_r^2,
    R_w and R_r the cross-covariances of their second differences under unit white noise and
    a unit random walk (`correlation`). Filters longer than SCALED_M are scaled down by
    c = min(m1, m2) // SCALED_M (octave sizes: exact): in the continuum limit R_w scales as c
    and R_r as c^3 at lags scaled by c, so the sums scale as c^3, c^5 and c^7."""
    c = max(1, min(m1, m2) // SCALED_M)
    (g1, h1), (g2, h2) = _second_difference_filters(m1 // c), _second_difference_filters(m2 // c)
    rw, rr = fftconvolve(g1, g2[::-1]), fftconvolve(h1, h2[::-1])
    n = max(len(rw), len(rr))
    w, r = np.zeros(n), np.zeros(n)
    w[(n - len(rw)) // 2:(n - len(rw)) // 2 + len(rw)] = rw
    r[(n - len(rr)) // 2:(n - len(rr)) // 2 + len(rr)] = rr
    return float(c ** 3 * np.sum(w * w)), float(c ** 5 * np.sum(w * r)), float(c ** 7 * np.sum(r * r))


def correlation(m: np.ndarray, white_var: float, walk_var: float) -> np.ndarray:
    """(K, K) correlation of the overlapping Allan variance estimates at cluster sizes m (K,)
    of one recording, for white frequency noise of variance white_var per sample plus a
    random walk of variance walk_var per step.

    Derivation: the estimate at m is the mean over j of D_m(j)^2 / (2 m^2), D_m a linear
    filter of Gaussian noise (`_second_difference_filters`). For Gaussian D,
    cov(D1(j)^2, D2(k)^2) = 2 R12(k - j)^2, R12 the filters' cross-covariance, so over M >> m
    shifts cov(est1, est2) ~ 2 / (4 m1^2 m2^2 M) sum_h R12(h)^2 and
    corr = sum R12^2 / sqrt(sum R11^2 sum R22^2); white and random-walk parts add in R
    (independent): R12 = white_var R_w + walk_var R_r, so sum R12^2 is a quadratic form in
    (white_var, walk_var) of the pair's three sums (`_pair_sums`, cached per pair of sizes).
    Their variances come from Greenhall's edf (rigcal.imunoise.allan.edf), exact for few
    clusters; only the correlation is taken from this many-cluster form."""
    m = np.asarray(m, np.int64)
    K = len(m)
    S = np.empty((K, K))
    for i in range(K):
        for j in range(i, K):
            ww, wr, rr = _pair_sums(int(m[i]), int(m[j]))
            S[i, j] = S[j, i] = white_var ** 2 * ww + 2.0 * white_var * walk_var * wr + walk_var ** 2 * rr
    d = np.sqrt(np.diag(S))
    return np.clip(S / np.outer(d, d), 0.0, 1.0)
