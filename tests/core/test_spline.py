"""rigcal.core.spline: values and analytic derivatives against known answers and finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.core import spline as spl


def random_spline(seed: int, n: int = 12, dt: float = 0.1) -> spl.Spline:
    rng = np.random.default_rng(seed)
    # a wandering rotation: each control rotation a step of up to ~0.3 rad from the last
    R = [geo.R_from_rotvec(rng.normal(0, 1, 3))]
    for _ in range(n - 1):
        R.append(R[-1] @ geo.R_from_rotvec(rng.normal(0, 0.15, 3)))
    return spl.Spline(0.3, dt, np.array(R), np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0))


def test_constant_control_points_give_a_pose_at_rest():
    R = geo.R_from_rotvec([0.3, -0.2, 1.0])
    s = spl.Spline(0.0, 0.05, np.repeat(R[None], 6, 0), np.repeat([[1.0, 2.0, 3.0]], 6, 0))
    out = spl.evaluate(s, np.linspace(0, s.t_end, 37))
    np.testing.assert_allclose(out.R_world_body, np.broadcast_to(R, (37, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(out.p_world, np.broadcast_to([1.0, 2.0, 3.0], (37, 3)), atol=1e-14)
    for x in (out.v_world, out.a_world, out.omega_body, out.alpha_body):
        np.testing.assert_allclose(x, 0.0, atol=1e-13)


def test_uniform_motion_is_reproduced_exactly():
    # control points on a constant-velocity line and a constant-rate turn about a fixed
    # body axis: a cubic B-spline reproduces both exactly (velocity, rate; no acceleration)
    dt, n = 0.1, 8
    k = np.arange(n)
    v = np.array([1.0, -0.5, 0.25])
    w = np.array([0.2, 0.1, -0.7])  # rad/s, body axes
    R0 = geo.R_from_rotvec([0.1, 0.2, 0.3])
    s = spl.Spline(0.0, dt, R0 @ geo.R_from_rotvec(np.outer((k - 1) * dt, w)), np.outer((k - 1) * dt, v))
    t = np.linspace(0, s.t_end, 41)
    out = spl.evaluate(s, t)
    np.testing.assert_allclose(out.p_world, np.outer(t, v), atol=1e-13)
    np.testing.assert_allclose(out.v_world, np.broadcast_to(v, out.v_world.shape), atol=1e-12)
    np.testing.assert_allclose(out.a_world, 0.0, atol=1e-10)
    np.testing.assert_allclose(out.R_world_body, R0 @ geo.R_from_rotvec(np.outer(t, w)), atol=1e-13)
    np.testing.assert_allclose(out.omega_body, np.broadcast_to(w, out.omega_body.shape), atol=1e-12)
    np.testing.assert_allclose(out.alpha_body, 0.0, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_derivatives_match_finite_differences(seed):
    s = random_spline(seed)
    h = 1e-5
    t = np.linspace(s.t0 + 2 * h, s.t_end - 2 * h, 53)
    mid, plus, minus = (spl.evaluate(s, x) for x in (t, t + h, t - h))
    np.testing.assert_allclose(mid.v_world, (plus.p_world - minus.p_world) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(mid.a_world, (plus.v_world - minus.v_world) / (2 * h), atol=1e-5)
    # body rate: R^T dR/dt = [omega]x, from the rotation between t - h and t + h
    rel = np.swapaxes(minus.R_world_body, 1, 2) @ plus.R_world_body
    omega_fd = geo.rotvecs_from_R(rel) / (2 * h)
    np.testing.assert_allclose(mid.omega_body, omega_fd, atol=1e-6)
    np.testing.assert_allclose(mid.alpha_body, (plus.omega_body - minus.omega_body) / (2 * h), atol=1e-4)
    assert np.abs(mid.alpha_body).max() > 1.0  # the check is about a real acceleration


def test_spline_is_continuous_across_knots():
    s = random_spline(3)
    knots = s.t0 + s.dt * np.arange(1, len(s.p) - 3)
    e = 1e-9
    before, after = spl.evaluate(s, knots - e), spl.evaluate(s, knots + e)
    for name in ("p_world", "v_world", "a_world", "omega_body", "alpha_body"):
        np.testing.assert_allclose(getattr(before, name), getattr(after, name), atol=1e-6, err_msg=name)


def test_times_outside_the_spline_are_refused():
    s = random_spline(0)
    with pytest.raises(ValueError, match="outside"):
        spl.evaluate(s, [s.t_end + 0.01])
    with pytest.raises(ValueError, match="outside"):
        spl.evaluate(s, [s.t0 - 0.01])
    spl.evaluate(s, [s.t0, s.t_end])  # both ends belong to it


def test_fit_recovers_the_spline_that_made_the_samples():
    s = random_spline(4, n=15)
    t = np.linspace(s.t0, s.t_end, 400)
    truth = spl.evaluate(s, t)
    fitted = spl.fit(t, truth.R_world_body, truth.p_world, s.dt)
    assert fitted.t0 == pytest.approx(s.t0) and len(fitted.p) == len(s.p)
    np.testing.assert_allclose(fitted.p, s.p, atol=1e-9)
    angle = geo.rotation_angles(np.swapaxes(fitted.R, 1, 2) @ s.R)
    assert angle.max() < 1e-8
    again = spl.evaluate(fitted, t)
    np.testing.assert_allclose(again.omega_body, truth.omega_body, atol=1e-6)


def test_evaluation_is_vectorised_and_fast_enough_for_an_imu_stream():
    # 72 s at 200 Hz (the EuRoC recording's IMU) on a 50 ms knot spacing
    rng = np.random.default_rng(5)
    n = int(72 / 0.05) + 3
    s = spl.Spline(0.0, 0.05, geo.R_from_rotvec(rng.normal(0, 1, (n, 3))), rng.normal(0, 1, (n, 3)))
    out = spl.evaluate(s, np.arange(0, 72, 0.005))
    assert out.omega_body.shape == (14400, 3) and np.isfinite(out.alpha_body).all()


def test_a_nan_time_is_refused_not_indexed():
    s = spl.Spline(0.0, 0.1, np.broadcast_to(np.eye(3), (6, 3, 3)).copy(), np.zeros((6, 3)))
    assert spl.segment(s, np.array([0.1]))[0][0] == 1
    with pytest.raises(ValueError):
        spl.segment(s, np.array([0.1, np.nan]))
