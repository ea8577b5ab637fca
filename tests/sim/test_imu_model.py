"""The IMU measurement model and the hand-held trajectory (rigcal.sim.imu_model): imu.md's golden check,
analytic derivatives against finite differences, the lever arm against a twice
differentiated IMU position, gtsam's ScenarioRunner and preintegration as independent
oracles, and the noisy streams against what the declared noise densities predict."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.sim.imu_model import (G_WORLD, GRAVITY, Motion, hand_held_trajectory, ideal_readings, synthesize)
from rigcal.core.rig import load_rig

ROOT = Path(__file__).resolve().parents[2]
IMU_RIG = load_rig(ROOT / "rigs" / "drone-stereo-back-imu.yaml")
FRD_RIG = load_rig(ROOT / "rigs" / "drone-stereo-back-frd.yaml")


def _yawing(rate: float, t: np.ndarray) -> Motion:
    """Level at the origin, heading north at t = 0, turning left (counter-clockwise from above)."""
    n = len(t)
    R = geo.R_from_rotvec(np.outer(math.pi / 2 + rate * t, [0.0, 0.0, 1.0]))
    z = np.zeros((n, 3))
    return Motion(t=t, R_world_body=R, p_world=z, v_world=z, a_world=z,
                  omega_body=np.tile([0.0, 0.0, rate], (n, 1)), alpha_body=z)


@pytest.mark.parametrize("rate", [0.0, 0.5])
def test_golden_check_of_imu_md(rate):
    t = np.linspace(0.0, 2.0, 5)
    s = synthesize(_yawing(rate, t), IMU_RIG.imus[0], np.random.default_rng(0), noise=False)
    np.testing.assert_allclose(s.gyro, np.tile([0.0, 0.0, rate], (5, 1)), atol=1e-12)
    np.testing.assert_allclose(s.accel, np.tile([0.0, 0.0, 9.80665], (5, 1)), atol=1e-12)


def test_golden_check_through_the_trajectory_and_a_frd_imu():
    """At rest (scale 0) the hand-held trajectory is level and heading north; an FRD IMU at
    the body origin reads gravity on -z and a left yaw as negative z rate."""
    rest = hand_held_trajectory(np.random.default_rng(1), scale=0.0).at(np.linspace(0, 3, 7))
    np.testing.assert_allclose(rest.R_world_body[:, :, 0], np.tile([0.0, 1.0, 0.0], (7, 1)), atol=1e-15)
    T_frd = FRD_RIG.imus[0].T_body_imu.copy()
    T_frd[:3, 3] = 0.0
    gyro, accel = ideal_readings(rest, T_frd)
    np.testing.assert_allclose(gyro, 0.0, atol=1e-15)
    np.testing.assert_allclose(accel, np.tile([0.0, 0.0, -GRAVITY], (7, 1)), atol=1e-12)
    gyro, _ = ideal_readings(_yawing(0.5, np.zeros(1)), T_frd)
    np.testing.assert_allclose(gyro, [[0.0, 0.0, -0.5]], atol=1e-12)


def test_trajectory_derivatives_are_analytic_and_right():
    traj = hand_held_trajectory(np.random.default_rng(3))
    t = np.linspace(0.3, 29.7, 301)
    m, h = traj.at(t), 1e-5
    m1, m0 = traj.at(t + h), traj.at(t - h)
    dR = np.transpose(m0.R_world_body, (0, 2, 1)) @ m1.R_world_body
    np.testing.assert_allclose(geo.rotvecs_from_R(dR) / (2 * h), m.omega_body, atol=1e-7)
    np.testing.assert_allclose((m1.omega_body - m0.omega_body) / (2 * h), m.alpha_body, atol=1e-6)
    np.testing.assert_allclose((m1.p_world - m0.p_world) / (2 * h), m.v_world, atol=1e-7)
    np.testing.assert_allclose((m1.v_world - m0.v_world) / (2 * h), m.a_world, atol=1e-6)


def test_trajectory_excites_every_axis():
    m = hand_held_trajectory(np.random.default_rng(0)).at(np.arange(0.0, 30.0, 0.005))
    assert np.all(np.degrees(np.abs(m.omega_body).max(axis=0)) > 30.0)
    assert np.all(np.abs(m.a_world).max(axis=0) > 1.0)
    assert np.all(np.ptp(m.p_world, axis=0) > 0.2)


def test_lever_arm_against_the_imu_points_second_derivative():
    """Specific force of an IMU 3 cm behind and 2 cm below, rotated FRD: the acceleration of
    its point by central differences of p_world + R_world_body @ r, rotated into its axes."""
    imu = FRD_RIG.imus[0]
    traj = hand_held_trajectory(np.random.default_rng(4))
    t, h = np.linspace(1.0, 5.0, 41), 1e-4

    def p_imu(tt):
        m = traj.at(tt)
        return m.p_world + (m.R_world_body @ imu.T_body_imu[:3, 3][:, None])[..., 0]

    a_imu = (p_imu(t + h) - 2 * p_imu(t) + p_imu(t - h)) / h**2
    m = traj.at(t)
    R_world_imu = m.R_world_body @ imu.T_body_imu[:3, :3]
    expected = (np.transpose(R_world_imu, (0, 2, 1)) @ (a_imu - G_WORLD)[..., None])[..., 0]
    _, accel = ideal_readings(m, imu.T_body_imu)
    np.testing.assert_allclose(accel, expected, atol=2e-5)
    # and the arm matters: without it the readings differ by far more than that
    T_no_arm = imu.T_body_imu.copy()
    T_no_arm[:3, 3] = 0.0
    assert np.abs(ideal_readings(m, T_no_arm)[1] - expected).max() > 1e-3


def test_gtsam_scenario_runner_agrees():
    gtsam = pytest.importorskip("gtsam")
    R0 = gtsam.Rot3.Rz(0.3) * gtsam.Rot3.Ry(0.2)
    w_b, a_n, v0 = np.array([0.2, -0.4, 0.7]), np.array([0.5, -1.0, 0.3]), np.array([0.1, 0.2, -0.3])
    scenario = gtsam.AcceleratingScenario(R0, np.array([1.0, 2.0, 3.0]), v0, a_n, w_b)
    runner = gtsam.ScenarioRunner(scenario, gtsam.PreintegrationParams.MakeSharedU(GRAVITY), 0.005,
                                  gtsam.imuBias.ConstantBias())
    t = np.linspace(0.0, 3.0, 13)
    motion = Motion(t=t, R_world_body=np.stack([scenario.rotation(x).matrix() for x in t]),
                    p_world=np.stack([scenario.pose(x).translation() for x in t]),
                    v_world=np.stack([scenario.velocity_n(x) for x in t]),
                    a_world=np.stack([scenario.acceleration_n(x) for x in t]),
                    omega_body=np.tile(w_b, (len(t), 1)), alpha_body=np.zeros((len(t), 3)))
    gyro, accel = ideal_readings(motion, np.eye(4))
    np.testing.assert_allclose(gyro, np.stack([runner.actualAngularVelocity(x) for x in t]), atol=1e-12)
    np.testing.assert_allclose(accel, np.stack([runner.actualSpecificForce(x) for x in t]), atol=1e-9)


def _gtsam_prediction_error(gtsam, traj, dt: float, t0: float = 2.0, seconds: float = 1.0) -> np.ndarray:
    """(rotation deg, position m, velocity m/s) errors of gtsam's preintegration of our
    noise-free readings (sampled at each step's midpoint) from the true state at t0."""
    n = int(round(seconds / dt))
    gyro, accel = ideal_readings(traj.at(t0 + (np.arange(n) + 0.5) * dt), np.eye(4))
    pim = gtsam.PreintegratedImuMeasurements(gtsam.PreintegrationParams.MakeSharedU(GRAVITY),
                                             gtsam.imuBias.ConstantBias())
    for f, w in zip(accel, gyro):
        pim.integrateMeasurement(f, w, dt)
    a, b = traj.at(np.array([t0])), traj.at(np.array([t0 + n * dt]))
    start = gtsam.NavState(gtsam.Rot3(a.R_world_body[0]), a.p_world[0], a.v_world[0])
    end = pim.predict(start, gtsam.imuBias.ConstantBias())
    return np.array([geo.rotation_angle_deg(end.attitude().matrix().T @ b.R_world_body[0]),
                     np.linalg.norm(end.position() - b.p_world[0]), np.linalg.norm(end.velocity() - b.v_world[0])])


def test_gtsam_preintegration_of_the_synthesis_reaches_the_truth():
    """gtsam integrates 1 s of our readings of the hand-held motion from the true state. Its
    integration is first order, so it reaches the true pose and velocity only as the step
    shrinks: the errors are small and halve with the step (a wrong sign, frame or gravity
    would leave errors of metres and degrees that do not shrink)."""
    gtsam = pytest.importorskip("gtsam")
    traj = hand_held_trajectory(np.random.default_rng(5))
    coarse, fine = _gtsam_prediction_error(gtsam, traj, 0.002), _gtsam_prediction_error(gtsam, traj, 0.001)
    assert np.all(fine < [1e-3, 2e-3, 4e-3]), fine
    assert np.all((coarse / fine > 1.6) & (coarse / fine < 2.6)), coarse / fine


def _noisy_run(seed: int, imu, t0: float, seconds: float):
    traj = hand_held_trajectory(np.random.default_rng(seed))
    rate = imu.update_rate
    t = t0 + np.arange(int(seconds * rate) + 1) / rate
    m = traj.at(t)
    return m, synthesize(m, imu, np.random.default_rng([seed, 9]))


@pytest.mark.parametrize("rig", [IMU_RIG, FRD_RIG], ids=["flu", "frd"])
def test_integrated_gyro_matches_truth_within_its_noise(rig):
    imu = rig.imus[0]
    dt = 1.0 / imu.update_rate
    errors = []
    for seed in range(6):
        m, s = _noisy_run(seed, imu, 3.0, 1.0)
        w = s.gyro - s.gyro_bias
        R = m.R_world_body[0] @ imu.T_body_imu[:3, :3]
        for k in range(len(w) - 1):  # the exponential of the mean rate over each step
            R = R @ geo.R_from_rotvec(0.5 * (w[k] + w[k + 1]) * dt)
        R_true = m.R_world_body[-1] @ imu.T_body_imu[:3, :3]
        errors.append(geo.rotvec_from_R(R_true.T @ R))
    # angle random walk over 1 s: density * sqrt(1 s) per axis (the trapezoid halves the end samples)
    sigma = imu.gyroscope_noise_density
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert rms < 2.5 * sigma, (rms, sigma)
    assert rms > 0.3 * sigma, "the noise should be visible: the streams carry the declared noise"


@pytest.mark.parametrize("rig", [IMU_RIG, FRD_RIG], ids=["flu", "frd"])
def test_double_integrated_accel_matches_truth_within_its_noise(rig):
    imu = rig.imus[0]
    dt = 1.0 / imu.update_rate
    R_bi, r = imu.T_body_imu[:3, :3], imu.T_body_imu[:3, 3]
    errors = []
    for seed in range(6):
        m, s = _noisy_run(seed, imu, 4.0, 0.5)
        R_world_imu = m.R_world_body @ R_bi  # orientation from the truth: this checks the accelerometer
        a = (R_world_imu @ (s.accel - s.accel_bias)[..., None])[..., 0] + G_WORLD
        p_true = m.p_world + (m.R_world_body @ r[:, None])[..., 0]
        v = m.v_world[0] + m.R_world_body[0] @ np.cross(m.omega_body[0], r)
        p = p_true[0].copy()
        for k in range(len(a) - 1):
            p = p + v * dt + (2 * a[k] + a[k + 1]) / 6 * dt * dt  # exact for a linear acceleration
            v = v + 0.5 * (a[k] + a[k + 1]) * dt
        errors.append(p - p_true[-1])
    # velocity random walk integrated: density * T^1.5 / sqrt(3) per axis
    sigma = imu.accelerometer_noise_density * 0.5 ** 1.5 / math.sqrt(3)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert rms < 2.5 * sigma, (rms, sigma)
    assert rms > 0.3 * sigma


def test_bias_walks_have_the_declared_spread():
    imu = IMU_RIG.imus[0]
    _, s = _noisy_run(0, imu, 0.0, 400.0)
    rate = imu.update_rate
    # increments over 1 s: random_walk * sqrt(1 s)
    step = int(rate)
    dg = np.diff(s.gyro_bias[::step], axis=0)
    da = np.diff(s.accel_bias[::step], axis=0)
    assert dg.std() == pytest.approx(imu.gyroscope_random_walk, rel=0.15)
    assert da.std() == pytest.approx(imu.accelerometer_random_walk, rel=0.15)
    white = s.gyro - s.gyro_bias - ideal_readings(_noisy_run(0, imu, 0.0, 400.0)[0], imu.T_body_imu)[0]
    assert white.std() == pytest.approx(imu.gyroscope_noise_density * math.sqrt(rate), rel=0.05)
