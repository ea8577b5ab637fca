"""Known answers for rigcal.check.decide (the check's statistics) and verdict's helpers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from rigcal.check import decide
from rigcal.check.verdict import displacement, intrinsics_to_test
from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel


def random_poses(rng, n):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = geo.R_from_rotvec(rng.normal(size=(n, 3)))
    T[:, :3, 3] = rng.normal(scale=0.2, size=(n, 3))
    return T


def test_sidak_level_makes_the_family_rate():
    assert decide.sidak_level(0.01, 1) == pytest.approx(0.01)
    a = decide.sidak_level(0.01, 6)
    assert 1 - (1 - a) ** 6 == pytest.approx(0.01)
    assert 0.01 / 6 < a < 0.01 / 5.9


def test_chi2_test_known_answers():
    stat, p = decide.chi2_test(np.array([1.0, 2.0]), np.diag([1.0, 4.0]))
    assert stat == pytest.approx(2.0)
    assert p == pytest.approx(stats.chi2.sf(2.0, 2))
    # a direction without variance (held in both calibrations) carries no information
    stat, p = decide.chi2_test(np.array([2.0, 0.0]), np.diag([1.0, 0.0]))
    assert stat == pytest.approx(4.0)
    assert p == pytest.approx(stats.chi2.sf(4.0, 1))


def test_detectable_change_is_flagged_with_the_stated_power():
    sigma, level = 0.3, 0.002
    d = decide.detectable(np.array([[sigma**2]]), level)[0]
    power = stats.ncx2.sf(decide.chi2_threshold(1, level), 1, (d / sigma) ** 2)
    assert power == pytest.approx(decide.DETECT_POWER, abs=1e-6)
    # by simulation: a change of d with noise sigma is flagged 80 % of the time
    rng = np.random.default_rng(3)
    x = d + rng.normal(0, sigma, 20000)
    assert np.mean((x / sigma) ** 2 > decide.chi2_threshold(1, level)) == pytest.approx(0.8, abs=0.01)


def test_aligned_delta_finds_the_turned_camera_whatever_the_body_frame():
    rng = np.random.default_rng(0)
    T_old = random_poses(rng, 3)
    T_moved = T_old.copy()
    T_moved[1, :3, :3] = geo.R_from_rotvec([0.0, 0.0, 0.01]) @ T_old[1, :3, :3]  # 0.01 rad about body U
    G = random_poses(rng, 1)[0]  # the new estimate's own body frame
    T_new = G @ T_moved
    np.testing.assert_allclose(decide.aligned_delta(T_new, T_old, 1, [0, 2]), [0, 0, 0.01, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(decide.aligned_delta(T_new, T_old, 0, [2]), np.zeros(6), atol=1e-12)
    # aligned by the moved camera alone, an unmoved one looks moved: what locate_moved avoids
    assert np.linalg.norm(decide.aligned_delta(T_new, T_old, 0, [1])[:3]) == pytest.approx(0.01, rel=1e-6)


def test_delta_covariance_matches_monte_carlo():
    """The propagated covariance against sampling the new poses (solver parameters, the
    gauge camera fixed) and the rig's (independent per axis)."""
    rng = np.random.default_rng(1)
    C = 3
    T_old = random_poses(rng, C)
    Tcb = decide.inverse_poses(T_old)
    A = rng.normal(size=(6 * C, 6 * C)) * 1e-3
    cov_new = A @ A.T
    cov_new[:6, :] = cov_new[:, :6] = 0.0  # camera 0 is the gauge
    var_old = (rng.uniform(0.5, 2.0, (C, 6)) * 1e-3) ** 2
    i, others = 1, [0, 2]
    pred = decide.delta_covariance(Tcb, cov_new, T_old, var_old, i, others)
    L = np.linalg.cholesky(cov_new[6:, 6:])
    samples = []
    for _ in range(2000):
        x = np.concatenate([np.zeros(6), L @ rng.normal(size=6 * (C - 1))])
        Tn = Tcb.copy()
        To = T_old.copy()
        for c in range(C):
            Tn[c, :3, :3] = geo.R_from_rotvec(x[6 * c:6 * c + 3]) @ Tcb[c, :3, :3]
            Tn[c, :3, 3] += x[6 * c + 3:6 * c + 6]
            e = rng.normal(size=6) * np.sqrt(var_old[c])
            To[c, :3, :3] = geo.R_from_rotvec(e[:3]) @ T_old[c, :3, :3]
            To[c, :3, 3] += e[3:]
        samples.append(decide.aligned_delta(decide.inverse_poses(Tn), To, i, others))
    emp = np.cov(np.array(samples).T)
    sd = np.sqrt(np.diag(pred))
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), sd, rtol=0.08)  # 2000 draws: 1.6 % sampling error
    np.testing.assert_allclose(emp / np.outer(sd, sd), pred / np.outer(sd, sd), atol=0.08)


def test_locate_moved_drops_the_moved_camera_first():
    moved = 2

    def stat_of(i, others):  # the moved camera fails; others fail only when aligned by it too
        return 100.0 if i == moved else (30.0 if moved in others and len(others) < 3 else 1.0)

    keep, against = decide.locate_moved(stat_of, [0, 1, 2, 3], threshold=20.0)
    assert keep == [0, 1, 3]
    assert against[moved] == [0, 1, 3]
    assert against[0] == [1, 3]


def test_locate_moved_two_cameras_that_disagree_are_both_dropped():
    keep, against = decide.locate_moved(lambda i, o: 50.0, [0, 1], threshold=20.0)
    assert keep == []
    assert against == {0: [1], 1: [0]}


def test_locate_moved_unchanged_rig_keeps_all():
    keep, _ = decide.locate_moved(lambda i, o: 1.0, [0, 1, 2], threshold=20.0)
    assert keep == [0, 1, 2]


def test_intrinsics_to_test_follow_the_rigs_structure():
    assert intrinsics_to_test(False, False, False) == [0, 1, 2, 3]
    assert intrinsics_to_test(True, False, False) == [0, 2, 3]
    assert intrinsics_to_test(True, True, False) == [0]
    assert intrinsics_to_test(False, False, True) == []


def test_displacement_of_a_focal_change_is_largest_at_the_image_corner():
    old = CameraModel("pinhole", 640, 480, 300.0, 300.0, 319.5, 239.5, (0.0,) * 5)
    new = old.with_(fx=303.0, fy=303.0)
    assert displacement(old, new) == pytest.approx(0.01 * np.hypot(319.5, 239.5), rel=1e-6)
    assert displacement(old, old.with_(cx=321.5)) == pytest.approx(2.0, rel=1e-6)


def _refit_errors(T: np.ndarray, e0: np.ndarray) -> np.ndarray:
    """(N, C, 6) the errors e0 (N, C, 6) as an `aligned` rig reports them: every camera
    perturbed by its e0, then the whole rig re-fitted onto T (geometry.fit_rigid_to)."""
    out = np.empty_like(e0)
    for n, e in enumerate(e0):
        Tp = T.copy()
        for c in range(len(T)):
            Tp[c, :3, :3] = geo.R_from_rotvec(e[c, :3]) @ T[c, :3, :3]
            Tp[c, :3, 3] += e[c, 3:]
        A = geo.fit_rigid_to(Tp, T)
        out[n] = [decide.pose_change(A @ Tp[c], T[c]) for c in range(len(T))]
    return out


def test_gauge_free_variances_of_two_like_cameras_double_along_the_baseline():
    """Two cameras side by side on body L, looking the same way: a fit to both moves each
    by the mean of their position errors along L (no rotation of the fit moves them along
    the line joining them), so there the reported variance is half the independent one."""
    T = np.tile(np.eye(4), (2, 1, 1))
    T[0, 1, 3], T[1, 1, 3] = 0.05, -0.05
    var = np.full((2, 6), 1e-8)
    free = decide.gauge_free_variances(T, var)
    assert free[:, 4] == pytest.approx(2e-8, rel=0.02)
    assert np.all(free >= var)


def _relative_variances(T: np.ndarray, e0: np.ndarray) -> np.ndarray:
    """(C, 6) the variance over draws of each camera's pose relative to the others
    (decide.aligned_delta) under the independent errors e0 (N, C, 6)."""
    C = len(T)
    out = np.zeros((len(e0), C, 6))
    for n, e in enumerate(e0):
        Tp = T.copy()
        for c in range(C):
            Tp[c, :3, :3] = geo.R_from_rotvec(e[c, :3]) @ T[c, :3, :3]
            Tp[c, :3, 3] += e[c, 3:]
        out[n] = [decide.aligned_delta(Tp, T, i, [j for j in range(C) if j != i]) for i in range(C)]
    return out.var(axis=0)


@pytest.mark.slow
def test_gauge_free_variances_give_the_relative_poses_variance_back():
    """Round trip (Monte Carlo, 2000 draws each): independent errors of known variances,
    reported as an aligned rig reports them (re-fitted); the variances found from the
    reported ones give each camera's pose relative to the others the variance the known
    ones give (within the draws' 10 %), where the reported ones taken as independent give
    too little."""
    rng = np.random.default_rng(3)
    T = random_poses(rng, 3)
    d_true = np.exp(rng.uniform(np.log(1e-7), np.log(4e-7), (3, 6)))
    reported = _refit_errors(T, rng.normal(size=(2000, 3, 6)) * np.sqrt(d_true)).var(axis=0)
    found = decide.gauge_free_variances(T, reported)
    want = _relative_variances(T, rng.normal(size=(2000, 3, 6)) * np.sqrt(d_true))
    got = _relative_variances(T, rng.normal(size=(2000, 3, 6)) * np.sqrt(found))
    naive = _relative_variances(T, rng.normal(size=(2000, 3, 6)) * np.sqrt(reported))
    assert got.sum(axis=1) == pytest.approx(want.sum(axis=1), rel=0.1)
    assert np.all(naive.sum(axis=1) < 0.85 * want.sum(axis=1))
