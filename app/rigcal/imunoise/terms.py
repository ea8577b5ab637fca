"""The noise terms of one IMU axis from its Allan deviation, each with a confidence interval.

The Allan variance of an IMU axis is modelled as the sum of four terms (IEEE Std 952):

    sigma^2(tau) = 3 Q^2 / tau^2      quantisation (slope -1 in deviation)
                 + N^2 / tau          white noise, density N (slope -1/2; N = the line at tau = 1 s)
                 + (2 ln2 / pi) B^2   bias instability B (flat; deviation 0.664 B)
                 + K^2 tau / 3        random walk K (slope +1/2; K = the line at tau = 3 s)

N and K are Kalibr's `*_noise_density` and `*_random_walk` (continuous time). A MEMS IMU
quantises rates, not angles: its quantisation is white noise, part of N. The angle
quantisation term Q is therefore held at zero (fitted, it trades off against N at the
shortest taus: 0.5 % of N on a simulated 3 h recording); it stays in the model's layout.
How each is read:

1. A joint weighted non-negative least-squares fit of the squared figures N, B, K to the
   measured variance at every tau, each point weighted by the variance of its estimate
   (2 sigma^4 / edf, with Greenhall's edf for the term that dominates there), re-weighted
   three times with the model's own values so low points do not pull the fit.
2. A term *dominates* a tau when it is the largest of the model's terms there
   (`dominates`); its tau range is those taus. The term is then re-fitted on its range
   alone (a line of fixed slope through the measured variance less the other terms' share
   there), each tau weighted by the inverse variance of what it says of the term.
3. Its confidence interval is chi-square with the degrees of freedom of that weighted
   mean's variance (2 value^2 / variance; `fit_term`). The variance counts that octave taus
   of one recording are correlated -- overlapping clusters share samples, so the taus are
   neither independent (adding their edf: too narrow) nor one (the best tau's edf alone:
   too wide for white noise, too narrow for the random walk); the correlation is derived
   from the Allan estimator's filters (rigcal.imunoise.allan.correlation). White noise and
   random walk have exact Allan shapes, so subtracting them adds no error beyond their own.
   The bias instability under another term's range is measured, not assumed: its level
   is the curve's excess over the white-noise and random-walk lines where it dominates
   most; under the white-noise range, where a real bias instability rolls off below the
   band its flicker spans (or, reaching the Nyquist frequency, exceeds its flat level), it
   is that level within the room a band rolled off right there leaves, U (1 - tau /
   tau_level), either way, a bound counted as a rectangular distribution
   (`flicker_bound`). Taus that disagree more than their errors allow (Birge ratio
   R^2 > 1: the model misses the curve there) widen the interval by R.
4. Bias instability: the flat minimum of the deviation / 0.664, its interval chi-square
   with the flicker-noise edf at that tau; `dominant` says whether a flat range exists
   (otherwise the figure is an upper bound set by the white noise and random walk).

A term with no tau where it dominates cannot be read from the recording: TooShort says how
long a recording would show it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls
from scipy.stats import chi2

from rigcal.errors import InputError
from rigcal.imunoise.allan import ALPHA, MAX_TAU_FRACTION, AllanCurve, correlation, curve_edf

TERMS = ("quantisation", "white", "flicker", "random_walk")
FLAT = 2.0 * math.log(2.0) / math.pi  # bias instability's variance factor: sigma = sqrt(FLAT) B = 0.664 B
DOMINANT_SHARE = 0.5  # the bias instability counts as seen where it is over half of the model
CONFIDENCE = 0.95
TARGET_PRECISION = 0.10  # `needed_s`: the recording for a 1-sigma relative error of 10 %
REWEIGHTS = 3
SETTLE_SIGMAS = 3.0  # `settled`: a step in sigma^2 tau is significant over this many standard deviations
MIN_TAUS = 4  # the fewest octave taus a curve is read from
FITTED = (1, 2, 3)  # the columns of `design` fitted: N, B, K (Q held at zero, see above)


class TooShort(InputError):
    """The recording is too short to show a term (exit 2); the message says how long is needed."""


@dataclass(frozen=True)
class TermFit:
    """One term of one axis: value with its CONFIDENCE interval [lo, hi], the tau range used
    (s), the equivalent degrees of freedom behind the interval, and the recording length
    (s) that would give a 1-sigma relative error of TARGET_PRECISION."""

    value: float
    lo: float
    hi: float
    tau_lo: float
    tau_hi: float
    edf: float
    needed_s: float
    dominant: bool = True


@dataclass(frozen=True)
class AxisNoise:
    """One axis: its Allan curve, the joint model's squared figures (Q^2, N^2, B^2, K^2), the
    edf used per tau, and the fitted white noise density, random walk, bias instability."""

    curve: AllanCurve
    model: np.ndarray
    edf: np.ndarray
    white: TermFit
    random_walk: TermFit
    bias_instability: TermFit

    def model_adev(self, tau: np.ndarray) -> np.ndarray:
        return np.sqrt(design(np.asarray(tau, float)) @ self.model)


def design(tau: np.ndarray) -> np.ndarray:
    """(K, 4): each term's Allan variance per unit squared figure at tau (K,)."""
    return np.stack([3.0 / tau ** 2, 1.0 / tau, np.full_like(tau, FLAT), tau / 3.0], axis=1)


def dominates(parts: np.ndarray, k: int) -> np.ndarray:
    """(K,) bool: the taus term k dominates, i.e. where it is the largest of the model's
    terms (parts (K, 4): each term's variance per tau). Where it is the largest, every
    other term is smaller than it, though together they may be more: a tau where the
    random walk and the flat term are near equal belongs to one of them by the model,
    not by the noise of the fitted figures (a range cut at more than half of the model
    moved with the fitted random walk itself: a random walk fitted low lost its most
    precise tau and read 10 % low on average)."""
    return (np.argmax(parts, axis=1) == k) & (parts[:, k] > 0)


def _dominant_alpha(parts: np.ndarray) -> np.ndarray:
    return np.array([ALPHA[TERMS[k]] for k in np.argmax(parts, axis=1)])


def _edf_by_term(curve: AllanCurve, alpha: np.ndarray) -> np.ndarray:
    out = np.empty(len(curve.m))
    for a in np.unique(alpha):
        sel = alpha == a
        out[sel] = curve_edf(int(a), curve, curve.m[sel])
    return out


def joint_fit(curve: AllanCurve) -> tuple[np.ndarray, np.ndarray]:
    """(the four squared figures (4,), edf per tau (K,)): weighted NNLS of the model to adev^2."""
    A, y = design(curve.tau), curve.adev ** 2
    alpha = np.full(len(y), ALPHA["white"])
    model_var = y.copy()
    for _ in range(REWEIGHTS + 1):
        nu = _edf_by_term(curve, alpha)
        sd = np.maximum(model_var, 1e-300) * np.sqrt(2.0 / nu)
        p = np.zeros(4)
        p[list(FITTED)], _ = nnls(A[:, FITTED] / sd[:, None], y / sd)
        parts = A * p
        model_var = np.maximum(parts.sum(axis=1), 1e-300)
        alpha = _dominant_alpha(parts)
    return p, _edf_by_term(curve, alpha)


def _interval(value_sq: float, nu: float) -> tuple[float, float]:
    """CONFIDENCE interval of a figure whose square has nu degrees of freedom."""
    lo_q, hi_q = chi2.ppf([(1 + CONFIDENCE) / 2, (1 - CONFIDENCE) / 2], nu)
    return math.sqrt(nu * value_sq / lo_q), math.sqrt(nu * value_sq / hi_q)


def _needed(duration_s: float, nu: float) -> float:
    """Recording length for a 1-sigma relative error TARGET_PRECISION of the figure: its
    relative error is 1 / sqrt(2 nu) and nu grows about linearly with the recording (the
    systematic part of nu shrinks too, as a longer recording reaches taus where the term
    dominates more: an estimate, not a promise)."""
    return duration_s * (1.0 / (2.0 * TARGET_PRECISION ** 2)) / nu


def flicker_bound(curve: AllanCurve, p: np.ndarray, nu: np.ndarray, sel: np.ndarray, k: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bias instability's (flicker's) Allan variance at the taus of term k's range `sel`
    (1 white noise, 3 random walk), from the data: (mid, half, sd_level) per tau in range --
    the flicker lies in mid +- half there, and the level it is scaled from has the sd
    sd_level (scaled to each tau).

    The level U is the measured excess of the Allan variance over the joint fit's
    white-noise and random-walk lines, max(0, adev^2 - N^2/tau - K^2 tau/3), at the tau tau_j
    between the two ranges where the joint fit's flat term has its largest share; its sd is
    the model's variance there * sqrt(2 / edf). When the ranges touch (the flat term is
    seen nowhere, and the excess next to a range would be the other term's noise) or the
    range reaches the end of the curve, U is the joint fit's flat level (tau_j the first tau
    past the range).

    Short taus (the white-noise range): a bias instability is flicker over a band of
    frequencies, a sum of first-order Gauss-Markov processes; each one's Allan variance
    s(tau) has s/tau non-increasing (s = sigma^2 T^2/tau^2 (2a - 3 + 4e^-a - e^-2a),
    a = tau/T), so the sum g at a fit tau tau_i < tau_j obeys g_i >= U r_i,
    r_i = tau_i/tau_j: a band rolled off right at tau_j lies U (1 - r_i) below the flat
    level. Above it, a band reaching the Nyquist frequency exceeds the flat level at the
    shortest taus (allantools' Kasdin-Walter flicker: 1.44 x at one sample, 1.15 x at two,
    1.05 x at four). The flicker at tau_i is taken as the flat level U, within U (1 - r_i)
    either way: that holds the rolled-off band, the flat floor and the full one. (The middle
    of [U r_i, U] instead reads an accelerometer's N 0.5 % high on the full band, with 44 %
    of its intervals holding the truth.)

    Long taus (the random-walk range): a bias instability is flicker down to frequencies far
    below a recording's (its Allan variance stays flat up to where the random walk takes
    over: IEEE Std 952's model, and the simulator's, whose slowest process is as long as the
    recording), so it is the level U there (half 0). A bound down to U tau_j/tau_i (a band
    ending at tau_j) would move every random walk up by its half: +6 % for the gyroscope
    of bench/imu_noise.py's simulated IMU, whose flicker is flat there."""
    tau = curve.tau
    parts = design(tau) * p
    between = (tau > tau[sel].max()) if k == 1 else (tau < tau[sel].min())
    if not between.any():
        return np.full(int(sel.sum()), FLAT * p[2]), np.zeros(int(sel.sum())), np.zeros(int(sel.sum()))
    other = dominates(parts, 4 - k)  # the other term's range
    flat_side = np.flatnonzero(between & ~other)
    if len(flat_side):
        j = int(flat_side[np.argmax(parts[flat_side, 2] / parts[flat_side].sum(axis=1))])
        level = max(float(curve.adev[j] ** 2 - parts[j, 1] - parts[j, 3]), 0.0)
        sd_level = float(parts[j].sum() * math.sqrt(2.0 / nu[j]))
    else:  # the ranges touch: the flat term is seen nowhere, the excess there would be the other term's noise
        j = int(np.flatnonzero(between)[0 if k == 1 else -1])
        level, sd_level = FLAT * p[2], 0.0
    r = np.minimum(tau[sel] / tau[j], 1.0) if k == 1 else np.ones(int(sel.sum()))
    return np.full(len(r), level), level * (1.0 - r), np.full(len(r), sd_level)


def fit_term(curve: AllanCurve, p: np.ndarray, nu: np.ndarray, k: int, settle_step: float = 0.0
             ) -> TermFit | None:
    """Term k (1 white, 3 random walk) re-fitted on the taus it dominates; None if none.

    Each tau i in range gives the squared figure p_i = (measured variance less the other
    exact term's line and the flicker's estimate, `flicker_bound`) / the term's
    shape. Its error has three parts:
    - statistical: the variance estimate's, sd_i = model variance * sqrt(2 / edf_i) / shape,
      and the estimates at octave taus of one recording are correlated (overlapping clusters
      share samples): rigcal.imunoise.allan.correlation derives rho_ij for the white noise
      and random walk fitted;
    - the flicker's shape: known only to lie within h_i = U (1 - r_i) of U
      (`flicker_bound`), counted as a rectangular distribution (sd h_i / sqrt 3, the GUM's
      rule for a quantity known only between bounds), one unknown for every tau;
    - the flicker's level U, measured at one tau: its sd, scaled to each tau.
    - the sensor filter's deficit left after the taus `settled` left out (settle_step, in
      sigma^2 tau, at the curve's first tau): step m_first / m_i, added back with half of
      it either way as a rectangular bound (the 1 / m law is asymptotic), one unknown for
      every tau.
    White noise and random walk have exact Allan shapes: subtracting them adds no error
    beyond their own. The p_i are averaged with weights 1 / (sd_i^2 + a_i^2 + b_i^2) (a, b:
    the two flicker parts in p units), and the variance of that mean is
    (w' (rho sd sd') w + (w.a)^2 + (w.b)^2) / (sum w)^2; the interval is the chi-square one
    with the degrees of freedom of that variance, 2 value^2 / variance. When the p_i scatter
    more than their own errors allow (the Birge ratio R^2 > 1, counted as if independent),
    the variance is multiplied by R^2."""
    A = design(curve.tau)
    parts = A * p
    total = parts.sum(axis=1)
    sel = dominates(parts, k)
    if not sel.any():
        return None
    other = 4 - k  # the other exact term: random walk (3) under white (1) and back
    mid, half, sd_level = flicker_bound(curve, p, nu, sel, k)
    shape = A[sel, k]
    deficit = settle_step * curve.m[0] / curve.m[sel] / curve.tau[sel]  # the filter's, in variance
    p_i = (curve.adev[sel] ** 2 - parts[sel, other] - mid + deficit) / shape
    sd = total[sel] * np.sqrt(2.0 / nu[sel]) / shape
    a, b = half / math.sqrt(3.0) / shape, sd_level / shape
    c = deficit / 2.0 / math.sqrt(3.0) / shape
    rho = correlation(curve.m[sel], p[1] * curve.rate_hz, p[3] / curve.rate_hz)
    w = 1.0 / (sd ** 2 + a ** 2 + b ** 2 + c ** 2)
    value_sq = max(float(np.sum(w * p_i) / np.sum(w)), 1e-300)
    birge = 1.0
    if sel.sum() > 1:
        birge = max(1.0, float(np.sum(w * (p_i - value_sq) ** 2)) / (sel.sum() - 1))
    var = (float(w @ (rho * np.outer(sd, sd)) @ w) + float(w @ a) ** 2 + float(w @ b) ** 2 + float(w @ c) ** 2) \
        / float(np.sum(w)) ** 2 * birge
    nu_term = 2.0 * value_sq ** 2 / var
    lo, hi = _interval(value_sq, nu_term)
    duration = curve.n / curve.rate_hz
    return TermFit(math.sqrt(value_sq), lo, hi, float(curve.tau[sel].min()), float(curve.tau[sel].max()), nu_term,
                   _needed(duration, nu_term))


def fit_bias_instability(curve: AllanCurve, p: np.ndarray) -> TermFit:
    """The flat minimum of the measured deviation / 0.664, chi-square interval with the
    flicker edf at that tau; `dominant` False when the flat term is more than half of the
    model at no tau (DOMINANT_SHARE; the minimum is then set by the white noise and random
    walk as much as by it, and the figure is an upper bound)."""
    i = int(np.argmin(curve.adev))
    nu = float(curve_edf(ALPHA["flicker"], curve, curve.m[i:i + 1])[0])
    scale = 1.0 / math.sqrt(FLAT)
    lo, hi = _interval(curve.adev[i] ** 2, nu)
    parts = design(curve.tau) * p
    flat = parts[:, 2] / parts.sum(axis=1) > DOMINANT_SHARE
    rng = curve.tau[flat] if flat.any() else curve.tau[i:i + 1]
    return TermFit(float(curve.adev[i]) * scale, lo * scale, hi * scale, float(rng.min()), float(rng.max()), nu,
                   _needed(curve.n / curve.rate_hz, nu), dominant=bool(flat.any()))


def _tau_where_dominant(p: np.ndarray, k: int) -> float | None:
    """The smallest tau (s) at which term k would dominate the model (`dominates`), or None."""
    tau = np.logspace(-3, 8, 2000)
    over = dominates(design(tau) * p, k)
    return float(tau[np.argmax(over)]) if over.any() else None


def _hours(s: float) -> str:
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.0f} min" if s >= 60 else f"{s:.0f} s"


def too_short_message(curve: AllanCurve, p: np.ndarray, k: int, what: str) -> str:
    """A pooled curve's taus reach a tenth of its longest stretch between gaps, not of the
    whole: the length needed is then one stretch's."""
    duration = max(curve.lengths()) / curve.rate_hz
    span = f"the {_hours(duration)} recording" if not curve.segments else \
        f"the longest of its {len(curve.segments)} stretches between gaps, {_hours(duration)}"
    once = "" if not curve.segments else " without a gap"
    tau_max = float(curve.tau.max())
    shape = "rise (slope +1/2)" if k == 3 else "fall (slope -1/2)"
    tx = _tau_where_dominant(p, k)
    if tx is not None and k == 3:
        need = f"record at least {_hours(2 * tx / MAX_TAU_FRACTION)}{once} (it would dominate from tau ~{tx:.0f} s; " \
               f"the longest tau read is a tenth of the recording)"
    else:
        need = f"it is not seen at all: record at least {_hours(4 * duration)}{once}, still and warmed up"
    return (f"too short for the {what}: the Allan deviation shows no {shape} where it dominates up to tau = "
            f"{tau_max:.3g} s (a tenth of {span}); {need}")


def settled(curve: AllanCurve) -> tuple[int, float]:
    """(the index of the first tau the terms are read from, the last step left out): the
    leading taus where the sensor's own filtering holds the Allan variance below the
    white-noise line are left out.

    White noise keeps sigma^2 tau flat. A filter whose memory spans a few samples (an
    averaging or anti-alias filter, a decimation of a faster stream: consecutive samples
    correlated) lowers it at the taus comparable to that memory, and the curve climbs to
    the line by steps that grow while tau is below the filter's time constant and then
    shrink (the deficit falls as 1 / tau beyond it). Bias instability and random walk
    raise sigma^2 tau by steps that only grow (double or quadruple an octave). So the
    leading run of significant steps (each over SETTLE_SIGMAS standard deviations of the
    difference, white-noise edf taken as independent) is left out when it rises and then
    falls, up to where the steps stop being significant or grow again; a run that only
    grows is a term of the model and stays. At least MIN_TAUS taus remain. Read from the
    rest, the white noise density is the flat part's, the density at frequencies well below
    the filter's, which is what integrating the samples accumulates; read from the filtered
    taus it would come out low, and the joint fit would explain their rise with a bias
    instability that is not there.

    The deficit does not end at the first tau kept: beyond the filter's memory it falls as
    C / m (the Allan variance of correlated samples is the white line less a 1 / m^2
    term), so at the first tau kept it is about the last step left out, and at cluster
    size m that step times m_first / m (`fit_term` adds it back)."""
    v = curve.adev ** 2 * curve.tau
    sd = v * np.sqrt(2.0 / curve_edf(ALPHA["white"], curve, curve.m))
    steps = np.diff(v)
    i, falling = 0, False
    while len(v) - (i + 1) >= MIN_TAUS and steps[i] > SETTLE_SIGMAS * math.hypot(sd[i], sd[i + 1]):
        if i and steps[i] > steps[i - 1]:
            if falling:
                break  # growing again: a term of the model
        elif i:
            falling = True
        i += 1
    if not falling:
        return 0, 0.0
    return i, float(steps[i - 1])


def settled_curve(curve: AllanCurve) -> tuple[AllanCurve, float]:
    """(the curve from its first `settled` tau on, the last step left out)."""
    start, step = settled(curve)
    return AllanCurve(curve.tau[start:], curve.adev[start:], curve.m[start:], curve.n, curve.rate_hz,
                      curve.segments), step


def fit_axis(curve: AllanCurve, what: str = "axis") -> AxisNoise:
    """All terms of one axis, read from the taus after the sensor's filtering (`settled`);
    TooShort (naming `what`) when white noise or random walk dominates no tau. The
    AxisNoise keeps the whole curve (edf of the taus left out: white noise's)."""
    if len(curve.tau) < MIN_TAUS:
        raise TooShort(f"too short for the {what}: {curve.n} samples give {len(curve.tau)} octave taus; "
                       f"expected at least {MIN_TAUS} (record at least {_hours(160 / curve.rate_hz)})")
    read, step = settled_curve(curve)
    start = len(curve.tau) - len(read.tau)
    p, nu = joint_fit(read)
    white = fit_term(read, p, nu, 1, step)
    if white is None:
        raise TooShort(too_short_message(read, p, 1, f"{what} white noise"))
    rw = fit_term(read, p, nu, 3, step)
    if rw is None:
        raise TooShort(too_short_message(read, p, 3, f"{what} random walk"))
    nu_all = np.concatenate([curve_edf(ALPHA["white"], curve, curve.m[:start]), nu]) if start else nu
    return AxisNoise(curve, p, nu_all, white, rw, fit_bias_instability(read, p))


def combine(fits: list[TermFit]) -> tuple[int, TermFit]:
    """Kalibr's single figure from the three axes: the largest, with its own interval (and
    the axis index). A filter given one isotropic figure must not be overconfident on any
    axis, so the noisiest axis sets it; the RMS would understate that axis."""
    i = int(np.argmax([f.value for f in fits]))
    return i, fits[i]
