"""The independent camera + IMU recording (tests/support/indie_motion.py): its physics
against known answers and finite differences, and its files as rigcal reads them."""

from __future__ import annotations

import numpy as np

from rigcal.core.rig import load_rig
from rigcal.data.imu_csv import read_imu_csv
from tests.support import indie_motion as im
from tests.support import indie_render as ir


def _still(yaw_rate: float = 0.0, heading_north: bool = True) -> im.Motion:
    """A rig at rest, level, heading north (body x = world y); with yaw_rate, yawing left at
    that rate at t = 0 (one slow sinusoid, so its rate at t = 0 is yaw_rate)."""
    zero = im.Sines(np.zeros((3, 1)), np.full((3, 1), 0.1), np.zeros((3, 1)))
    f = 0.01
    yaw = im.Sines(np.array([[0.0], [0.0], [yaw_rate / (2 * np.pi * f)]]), np.full((3, 1), f), np.zeros((3, 1)))
    T = ir.pose(im._rz(np.pi / 2 if heading_north else 0.0), [1.0, 2.0, 3.0])
    return im.Motion(T, zero, yaw)


def test_golden_check_of_imu_md():
    """imu.md's golden check: at rest, level, heading north, IMU along the body axes: gyro
    [0, 0, 0], accelerometer [0, 0, 9.80665]; yawing left at 0.5 rad/s: gyro z = +0.5."""
    rng = np.random.default_rng(0)
    s = im.imu_stream(_still(), 0.1, 400.0, rng, T_body_imu=np.eye(4), noiseless=True)
    np.testing.assert_allclose(s["gyro"], 0.0, atol=1e-15)
    np.testing.assert_allclose(s["accel"], np.tile([0.0, 0.0, 9.80665], (len(s["t_ns"]), 1)), atol=1e-12)
    s = im.imu_stream(_still(0.5), 0.0, 400.0, rng, T_body_imu=np.eye(4), noiseless=True)
    np.testing.assert_allclose(s["gyro"][0], [0.0, 0.0, 0.5], atol=1e-12)
    # the same still rig through the declared, rotated IMU: gravity's reaction in IMU axes
    s = im.imu_stream(_still(), 0.0, 400.0, rng, noiseless=True)
    np.testing.assert_allclose(s["accel"][0], im.R_BODY_IMU.T @ [0.0, 0.0, 9.80665], atol=1e-12)
    assert abs(s["accel"][0][2] - 9.80665) > 1e-3  # the tilt shows: the check can tell the frames apart


def test_angular_rate_is_the_derivative_of_the_attitude():
    mot = im.motion(3)
    h = 1e-5
    for t in np.linspace(0.5, 9.5, 13):
        w, wd = mot.omega_body(t)
        dR = mot.T_world_body(t - h)[:3, :3].T @ mot.T_world_body(t + h)[:3, :3]
        w_fd = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2 / (2 * h)  # small angle
        np.testing.assert_allclose(w, w_fd, atol=1e-7)
        np.testing.assert_allclose(wd, (mot.omega_body(t + h)[0] - mot.omega_body(t - h)[0]) / (2 * h), atol=1e-6)
    assert 0.3 < np.linalg.norm(mot.omega_body(2.0)[0]) or 0.3 < np.linalg.norm(mot.omega_body(7.0)[0])


def test_specific_force_is_the_second_derivative_of_the_imu_position():
    """Noise-free accelerometer = R_world_imu^T (d2/dt2 p_world_imu - g), with p_world_imu the
    IMU's origin (lever arm included), finite-differenced from poses alone."""
    mot = im.motion(5)
    s = im.imu_stream(mot, 2.0, 400.0, np.random.default_rng(0), noiseless=True)
    h = 1e-3
    p = lambda t: (mot.T_world_body(t) @ im.T_BODY_IMU)[:3, 3]  # noqa: E731
    for k in range(0, len(s["t_ns"]), 97):
        t = (s["t_ns"][k] - im.T0_NS) * 1e-9
        a = (-p(t + 2 * h) + 16 * p(t + h) - 30 * p(t) + 16 * p(t - h) - p(t - 2 * h)) / (12 * h * h)
        R_wi = (mot.T_world_body(t) @ im.T_BODY_IMU)[:3, :3]
        # 1e-6 m/s^2: a lever arm wrong by 0.01 mm would show as about 5e-5 here
        np.testing.assert_allclose(s["accel"][k], R_wi.T @ (a - im.G_WORLD), atol=1e-6)
        np.testing.assert_allclose(s["gyro"][k], im.R_BODY_IMU.T @ mot.omega_body(t)[0], atol=1e-12)


def test_written_files_read_back_through_rigcal(tmp_path):
    """The IMU csv, rig.yaml and the camera stems as rigcal reads them (no rendering): same
    stamps and readings, the IMU's declared pose, every stem inside the IMU's span after
    its true clock offset, noise at the declared density."""
    rec = im.recording(seed=1, duration=3.0)
    truth = im.write_recording(rec, tmp_path, render=False)
    got = read_imu_csv(tmp_path / "imu" / "imu0.csv")
    np.testing.assert_array_equal(got.t_ns, truth["imu"]["t_ns"])
    np.testing.assert_array_equal(got.gyro, truth["imu"]["gyro"])
    np.testing.assert_array_equal(got.accel, truth["imu"]["accel"])
    assert np.all(np.diff(got.t_ns) == 2_500_000)
    rig = load_rig(tmp_path / "rig.yaml")
    np.testing.assert_allclose(rig.imu("imu0").T_body_imu, im.T_BODY_IMU, atol=1e-12)
    for cam in rig.cameras:
        t = (rec.stamps[cam.name] - im.T0_NS) * 1e-9 + rec.time_offsets[cam.name]
        assert t.min() >= 0 and t.max() <= rec.duration
        assert 1.5e-3 <= abs(rec.time_offsets[cam.name]) <= 6.0e-3
    dt = 1 / rec.imu_rate
    white = truth["imu"]["gyro"] - truth["imu"]["gyro_true"] - truth["imu"]["gyro_bias"]
    density = white.std() * np.sqrt(dt)
    assert abs(density / im.NOISE["gyroscope_noise_density"] - 1) < 0.1
