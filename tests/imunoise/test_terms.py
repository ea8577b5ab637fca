"""Known answers for the Allan deviation and its noise terms on synthetic series of known
white noise density N and random walk K (rate-like axis sampled at RATE)."""

import numpy as np
import pytest

from rigcal.imunoise.allan import allan_deviation, edf, octave_clusters
from rigcal.imunoise.terms import TooShort, combine, fit_axis, fit_term, joint_fit, settled

RATE = 200.0
N = 1.7e-4  # rad/s/sqrt(Hz)
K = 2.0e-5  # rad/s^2/sqrt(Hz)


def series(seconds: float, n_density: float, k_walk: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n, dt = int(seconds * RATE), 1.0 / RATE
    white = n_density / np.sqrt(dt) * rng.standard_normal(n)
    walk = np.cumsum(k_walk * np.sqrt(dt) * rng.standard_normal(n)) if k_walk else 0.0
    return 0.3 + white + walk  # a constant offset (a bias, gravity) must not matter


def test_octave_clusters_reach_a_tenth_of_the_recording():
    m = octave_clusters(10_000)
    assert m[0] == 1 and np.all(m[1:] == 2 * m[:-1])
    assert m[-1] <= 1000 < 2 * m[-1]


def test_white_noise_deviation_is_density_over_sqrt_tau():
    c = allan_deviation(series(600, N, 0.0, seed=1), RATE)
    nu = edf(0, c.m, c.n)
    # each point within 4 sigma of its chi-square spread (relative sd of a deviation: 1/sqrt(2 edf))
    rel = c.adev * np.sqrt(c.tau) / N - 1
    assert np.all(np.abs(rel) < 4 / np.sqrt(2 * nu))


def test_white_noise_density_and_its_interval():
    c = allan_deviation(series(1800, N, 0.0, seed=2), RATE)
    p, nu = joint_fit(c)
    white = fit_term(c, p, nu, 1)
    assert white.value == pytest.approx(N, rel=0.01)
    assert white.lo < N < white.hi
    assert white.tau_lo == pytest.approx(1 / RATE)
    assert fit_term(c, p, nu, 3) is None  # no random walk to dominate anywhere


def test_white_and_random_walk_from_two_hours():
    a = fit_axis(allan_deviation(series(7200, N, K, seed=3), RATE), "gyroscope x")
    assert a.white.value == pytest.approx(N, rel=0.01)
    assert a.random_walk.value == pytest.approx(K, rel=0.25)
    assert a.random_walk.lo < K < a.random_walk.hi
    assert a.white.tau_hi < a.random_walk.tau_lo  # the ranges do not overlap
    assert a.random_walk.needed_s > a.white.needed_s


def test_white_density_interval_covers_the_truth_for_most_seeds():
    covered = 0
    for seed in range(20):
        c = allan_deviation(series(300, N, 0.0, seed=100 + seed), RATE)
        p, nu = joint_fit(c)
        w = fit_term(c, p, nu, 1)
        covered += w.lo < N < w.hi
    assert covered >= 16  # 95 % intervals: fewer than 16 of 20 has probability 3e-4


@pytest.mark.parametrize("kind", ["moving average", "one pole"])
def test_a_filtered_imu_reads_the_density_below_its_filter(kind):
    """A real IMU's samples are filtered: the Allan deviation at the shortest taus lies below
    the white-noise line (here 0.5-0.56 of it at one sample). Those taus are left out and
    the deficit they show is added back beyond them: the density read is the one at low
    frequencies (within 3 %; the joint fit on every tau made up a bias instability and
    found no random walk in the same hour)."""
    from tests.support.imu_static import filtered_axis

    x, truth = filtered_axis(3600, RATE, N, K, kind, seed=7)
    c = allan_deviation(x, RATE)
    start, step = settled(c)
    assert c.adev[0] * np.sqrt(c.tau[0]) < 0.6 * truth
    assert start >= 3 and step > 0
    a = fit_axis(c, "gyroscope x")
    assert a.white.value == pytest.approx(truth, rel=0.03)
    assert a.white.tau_lo == pytest.approx(c.tau[start])
    assert a.random_walk.value == pytest.approx(K, rel=0.5)
    assert len(a.edf) == len(c.tau)  # the whole curve kept for the plot


def test_white_noise_leaves_no_tau_out():
    for seed in range(6):
        c = allan_deviation(series(1800, N, K, seed=200 + seed), RATE)
        assert settled(c) == (0, 0.0)


def test_too_short_with_gaps_names_the_longest_stretch():
    """A pooled curve's taus reach a tenth of its longest stretch, so the length needed is
    one stretch's, not the sum of them."""
    from rigcal.imunoise.allan import pooled_allan_deviation

    x = series(1800, N, K / 10, seed=5)  # the random walk would dominate from about 150 s
    pooled = pooled_allan_deviation([x[:120_000], x[120_000:240_000], x[240_000:]], RATE)
    with pytest.raises(TooShort) as e:
        fit_axis(pooled, "gyroscope x")
    msg = str(e.value)
    assert "a tenth of the longest of its 3 stretches between gaps, 10 min" in msg
    assert "without a gap" in msg and "30 min" not in msg


def test_too_short_for_the_random_walk_says_how_long():
    with pytest.raises(TooShort, match=r"too short for the gyroscope x random walk.*record at least"):
        fit_axis(allan_deviation(series(120, N, K, seed=4), RATE), "gyroscope x")


def test_combine_takes_the_largest_axis():
    a = fit_axis(allan_deviation(series(7200, N, K, seed=5), RATE), "x")
    b = fit_axis(allan_deviation(series(7200, 2 * N, K, seed=6), RATE), "y")
    i, w = combine([a.white, b.white])
    assert i == 1 and w.value == pytest.approx(2 * N, rel=0.01)


def _avar_replicas(make, m: np.ndarray, reps: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([allan_deviation(make(rng), 1.0).adev[np.searchsorted(octave_clusters(4096), m)] ** 2
                     for _ in range(reps)])


@pytest.mark.parametrize("noise", ["white", "random_walk"])
def test_correlation_of_the_estimates_across_taus_matches_replicas(noise):
    """The derived correlation of the overlapping Allan variances at octave taus against the
    sample correlation of 300 seeded replicas (its standard error: (1 - rho^2) / sqrt(300) < 0.06)."""
    from rigcal.imunoise.allan import correlation

    m = np.array([4, 8, 16, 64])
    make = (lambda r: r.standard_normal(4096)) if noise == "white" else (lambda r: np.cumsum(r.standard_normal(4096)))
    est = _avar_replicas(make, m, 300, seed=11 if noise == "white" else 12)
    sample = np.corrcoef(est.T)
    rho = correlation(m, 1.0, 0.0) if noise == "white" else correlation(m, 0.0, 1.0)
    assert np.allclose(np.diag(rho), 1.0)
    assert np.all(np.abs(rho - sample) < 0.2)
    if noise == "white":  # octave neighbours about half correlated, four octaves apart nearly independent
        assert 0.35 < rho[0, 1] < 0.65 and rho[0, 3] < 0.1
    else:  # a random walk's estimates are far more alike
        assert rho[0, 1] > 0.8 and rho[0, 3] > 0.3


def test_interval_widths_match_the_errors_over_seeds():
    """Over 40 seeded recordings of white noise + random walk (10 Hz, crossing at 1.7 s, so the
    random walk dominates 6 octaves in 2000 s), each figure's error in units of its interval's
    sigma has a spread near 1: intervals neither too narrow nor (as a fixed allowance for the
    model's shape made them) several times too wide."""
    z_n, z_k = [], []
    for seed in range(40):
        rng = np.random.default_rng([31, seed])
        n_dens, k_walk, rate, n = 1e-3, 1e-3, 10.0, 20_000
        x = n_dens * np.sqrt(rate) * rng.standard_normal(n) + np.cumsum(k_walk / np.sqrt(rate) * rng.standard_normal(n))
        a = fit_axis(allan_deviation(x, rate), "x")
        z_n.append((a.white.value - n_dens) / ((a.white.hi - a.white.lo) / 3.92))
        z_k.append((a.random_walk.value - k_walk) / ((a.random_walk.hi - a.random_walk.lo) / 3.92))
    assert 0.6 < np.std(z_n) < 1.4
    assert 0.6 < np.std(z_k) < 1.4


def test_pooled_stretches_give_the_whole_recordings_curve_and_add_their_edf():
    """A series cut into two stretches: every second difference of either is one of the whole
    series', so the pooled Allan variance matches the whole's within its precision, and the
    stretches' edf add to about the whole's."""
    from rigcal.imunoise.allan import curve_edf, pooled_allan_deviation

    x = series(3600, N, K, seed=13)
    whole = allan_deviation(x, RATE)
    pooled = pooled_allan_deviation([x[:300_000], x[300_500:]], RATE)
    assert pooled.segments == (300_000, len(x) - 300_500) and pooled.n == len(x) - 500
    k = len(pooled.m)
    assert np.array_equal(pooled.m, whole.m[:k])
    nu = curve_edf(0, pooled, pooled.m)
    assert np.all(np.abs(pooled.adev / whole.adev[:k] - 1) < 3 / np.sqrt(2 * nu))
    nu_whole = curve_edf(0, whole, pooled.m)
    assert np.all(nu < nu_whole) and nu[0] == pytest.approx(nu_whole[0], rel=0.01)
    a = fit_axis(pooled, "x")
    assert a.white.lo < N < a.white.hi


def test_correlation_of_scaled_pairs_matches_the_unscaled_sums():
    """`correlation` sums each pair of cluster sizes from filters scaled down to SCALED_M (and
    caches the pair): against the sums of the full-length filters, computed directly, the
    correlation agrees within 0.01 (the continuum limit errs by ~1/SCALED_M at most), for white noise, random walk
    and a mix where both count."""
    from scipy.signal import fftconvolve

    from rigcal.imunoise.allan import _second_difference_filters, correlation

    m = np.array([64, 128, 256, 1024])

    def direct(white_var, walk_var):
        f = [_second_difference_filters(int(k)) for k in m]
        S = np.empty((len(m), len(m)))
        for i in range(len(m)):
            for j in range(len(m)):
                rw, rr = fftconvolve(f[i][0], f[j][0][::-1]), fftconvolve(f[i][1], f[j][1][::-1])
                r = white_var * rw  # rw is two lags longer than rr: centre rr on it
                r[1:-1] += walk_var * rr
                S[i, j] = np.sum(r * r)
        d = np.sqrt(np.diag(S))
        return S / np.outer(d, d)

    for white_var, walk_var in ((1.0, 0.0), (0.0, 1.0), (1.0, 3.0 / 256 ** 2)):
        rho = correlation(m, white_var, walk_var)
        assert np.allclose(rho, rho.T) and np.allclose(np.diag(rho), 1.0)
        assert np.all(np.abs(rho - direct(white_var, walk_var)) < 0.01)
        assert np.array_equal(correlation(m, white_var, walk_var), rho)  # the cached pairs give the same


def _exact_curve(flicker, n_dens: float, k_walk: float, rate: float, seconds: float):
    """A noise-free Allan curve: white noise + random walk + flicker(tau) (its Allan variance)."""
    from rigcal.imunoise.allan import AllanCurve

    n = int(seconds * rate)
    m = octave_clusters(n)
    tau = m / rate
    return AllanCurve(tau, np.sqrt(n_dens ** 2 / tau + k_walk ** 2 * tau / 3 + flicker(tau)), m, n, rate)


@pytest.mark.parametrize("corner_s", [None, 0.01])
def test_flicker_bound_holds_a_flat_and_a_rolled_off_bias_instability(corner_s):
    """An accelerometer-like axis (N 2e-3, K 3e-3 at 200 Hz, 3 h) whose bias instability is
    flat (None) or a Gauss-Markov sum rolled off below corner_s (time constants from there,
    x4, to the recording's length), its flat level where white noise and random walk cross:
    at every tau of the white-noise and random-walk ranges the flicker's true Allan variance
    lies in the bound flicker_bound derives from the curve, and both figures' intervals hold
    the truth."""
    from rigcal.imunoise.terms import flicker_bound
    from rigcal.sim.static_imu import gm_allan_variance

    n_dens, k_walk, rate, seconds = 2e-3, 3e-3, 200.0, 3 * 3600.0
    level = 2 * n_dens * k_walk / np.sqrt(3)  # the white + random-walk minimum (variance)
    if corner_s is None:
        def flicker(tau):
            return np.full_like(tau, level)
    else:
        Ts = corner_s * 4.0 ** np.arange(int(np.log(seconds / corner_s) / np.log(4)) + 1)
        mid = sum(gm_allan_variance(np.array([30.0]), 1.0, T) for T in Ts)[0]

        def flicker(tau):
            return level / mid * sum(gm_allan_variance(tau, 1.0, T) for T in Ts)
    c = _exact_curve(flicker, n_dens, k_walk, rate, seconds)
    p, nu = joint_fit(c)
    a = fit_axis(c, "x")
    for k, fit in ((1, a.white), (3, a.random_walk)):
        sel = (c.tau >= fit.tau_lo) & (c.tau <= fit.tau_hi)
        mid_g, half, sd_level = flicker_bound(c, p, nu, sel, k)
        g = flicker(c.tau[sel])
        assert np.all(np.abs(g - mid_g) <= half + 2 * sd_level), (k, g / level, mid_g / level, half / level)
    assert a.white.lo < n_dens < a.white.hi
    assert a.random_walk.lo < k_walk < a.random_walk.hi


def test_a_term_dominates_the_taus_where_it_is_the_largest():
    """Each term's variance per tau (quantisation, white, flat, random walk): the random walk
    dominates where it is the largest even under half of the model (second row), and a term
    at zero dominates nowhere."""
    from rigcal.imunoise.terms import dominates

    parts = np.array([[0.0, 0.2, 0.45, 0.35], [0.0, 0.15, 0.4, 0.45], [0.0, 0.1, 0.2, 0.7], [0.0, 1.0, 0.0, 0.0]])
    assert dominates(parts, 3).tolist() == [False, True, True, False]
    assert dominates(parts, 2).tolist() == [True, False, False, False]
    assert dominates(parts, 1).tolist() == [False, False, False, True]
    assert not dominates(np.zeros((2, 4)), 3).any()
