"""Known answers for the magnetometer model, the ellipsoid fit, the gyroscope integral (and
its bias Jacobian against finite differences) and the rotation-rate alignment."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.errors import CalibrationError
from rigcal.mag import model
from rigcal.mag.attitude import corrected, integrate_windows, rate_alignment
from rigcal.mag.ellipsoid import check_coverage, fit_ellipsoid, missing_directions
from rigcal.sim import mag_scene

H = np.array([20.0, -10.0, 5.0])
A = model.normalise(model.sym_from_vec(np.array([1.1, 0.95, 1.0, 0.05, -0.03, 0.02])), 1.0)[0]
R = geo.R_from_rotvec(np.array([0.1, 0.2, -0.3]))


def _sphere(n: int, rng) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def test_calibrated_inverts_readings_and_heading_is_exact_for_the_truth():
    rng = np.random.default_rng(0)
    b = 50.0 * _sphere(100, rng)
    np.testing.assert_allclose(model.calibrated(model.readings(b, H, A, R), H, A, R), b, atol=1e-12)
    psi = model.level_headings()
    m = model.readings(model.level_fields(48.0, 1.1, psi), H, A, R)
    np.testing.assert_allclose(model.heading_errors(m, psi, H, A, R), 0.0, atol=1e-12)
    # a chip yawed 2 degrees left (unknown to the calibration) sees the field 2 degrees to the right:
    # the heading it gives is 2 degrees too far left (ENU yaw, counter-clockwise)
    R_off = geo.R_from_rotvec(np.array([0.0, 0.0, np.radians(2.0)])) @ R
    err = model.heading_errors(model.readings(model.level_fields(48.0, 1.1, psi), H, A, R_off), psi, H, A, R)
    np.testing.assert_allclose(np.degrees(err), 2.0, atol=1e-9)


def test_field_world_points_north_and_down_by_the_inclination():
    b = model.field_world(50.0, np.radians(60.0))
    np.testing.assert_allclose(b, [0.0, 25.0, -50.0 * np.sin(np.radians(60.0))], atol=1e-12)


def test_ellipsoid_fit_recovers_hard_and_soft_iron_exactly_without_noise():
    rng = np.random.default_rng(1)
    m = model.readings(47.0 * _sphere(500, rng), H, A, R)
    fit = fit_ellipsoid(m)
    np.testing.assert_allclose(fit.hard_iron, H, atol=1e-8)
    np.testing.assert_allclose(fit.soft_iron, A, atol=1e-10)  # the symmetric part: R is invisible to it
    assert fit.field_uT == pytest.approx(47.0, abs=1e-8)
    declared = fit_ellipsoid(m, field_uT=47.0)
    np.testing.assert_allclose(declared.soft_iron, A, atol=1e-10)


def test_ellipsoid_fit_refuses_a_flat_recording_naming_what_is_missing():
    rng = np.random.default_rng(2)
    u = _sphere(2000, rng)
    u = u[u[:, 2] > 0.6]  # the field never below the chip's x-y plane's cone
    m = model.readings(50.0 * u, H, np.eye(3), np.eye(3))
    assert "-z" in missing_directions(m, H, np.eye(3))
    with pytest.raises(CalibrationError, match=r"-z"):
        check_coverage(m, fit_ellipsoid(m), "mag/mag0.csv")


def _tumble(duration: float = 6.0, rate: float = 200.0):
    traj = mag_scene.dance_trajectory(np.random.default_rng(3))
    t = np.arange(int(duration * rate) + 1) / rate
    return t, traj.at(t)


def test_window_integral_matches_the_true_relative_orientation():
    t, motion = _tumble()
    q = np.linspace(0.01, 5.5, 40)
    w = integrate_windows(t, motion.omega_body, q, 2.0)
    traj = mag_scene.dance_trajectory(np.random.default_rng(3))
    rel = np.transpose(traj.at(w.start).R_world_body[w.window], (0, 2, 1)) @ traj.at(q).R_world_body
    err = geo.rotation_angles(np.transpose(rel, (0, 2, 1)) @ w.dR)
    assert np.degrees(err).max() < 0.01
    assert w.n == 3 and set(w.window) == {0, 1, 2}  # 0-2 s, 2-4 s and 4 s to the end


def test_bias_jacobian_matches_finite_differences():
    t, motion = _tumble(3.0)
    q = np.linspace(0.05, 2.9, 15)
    w = integrate_windows(t, motion.omega_body, q, 10.0)
    db = np.array([2e-3, -1e-3, 1.5e-3])
    exact = integrate_windows(t, motion.omega_body, q, 10.0, bias=db).dR
    first_order = corrected(w, db)
    err = geo.rotation_angles(np.transpose(exact, (0, 2, 1)) @ first_order)
    drift = geo.rotation_angles(np.transpose(exact, (0, 2, 1)) @ w.dR)
    assert err.max() < 0.01 * drift.max()  # the Jacobian removes 99 % of the bias's effect


def test_rate_alignment_finds_the_chip_orientation_in_closed_form():
    t, motion = _tumble(20.0, 100.0)
    R_imu_mag = geo.R_from_rotvec(np.array([0.4, -2.0, 0.7]))
    b_imu = np.einsum("nji,j->ni", motion.R_world_body, model.field_world(50.0, 1.0))
    c = b_imu @ R_imu_mag  # R_imu_mag.T @ b per row
    got = rate_alignment(t, c, motion.omega_body)
    assert geo.rotation_angle_deg(got @ R_imu_mag.T) < 0.05


def test_savgol_is_scipys_savgol_filter():
    """attitude.savgol (numpy alone, so the CLI need not import scipy.signal) against
    scipy.signal.savgol_filter's default "interp" edges: values and derivatives."""
    from scipy.signal import savgol_filter

    from rigcal.mag.attitude import savgol

    x = np.cumsum(np.random.default_rng(1).normal(size=(300, 3)), axis=0)
    for n, deriv, delta in [(5, 0, 1.0), (25, 0, 1.0), (25, 1, 0.01), (7, 2, 0.1)]:
        want = savgol_filter(x, n, 3, deriv=deriv, delta=delta, axis=0)
        np.testing.assert_allclose(savgol(x, n, 3, deriv, delta), want, rtol=0, atol=1e-12 * np.abs(want).max())
