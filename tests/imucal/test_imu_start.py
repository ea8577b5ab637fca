"""The camera-IMU start: clock offset and rotation from rotation rates, refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.sim import imu_model
from rigcal.imucal import start as imu_start
from rigcal.errors import CalibrationError

T_BODY_CAM = geo.make_T(geo.R_from_rotvec([0.1, -0.2, 0.05]) @ geo.R_from_axes(["-L", "-U", "F"]), [0.1, 0.05, 0.01])
T_BODY_IMU = geo.make_T(geo.R_from_rotvec([0.03, 0.02, -0.6]), [0.01, 0.0, 0.02])


def _recording(traj, offset, seed=0, pose_noise_deg=0.0, gyro_noise=0.0, duration=12.0):
    rng = np.random.default_rng(seed)
    t_imu = np.arange(0.0, duration + 1.0, 0.005)
    gyro = imu_model.ideal_readings(traj.at(t_imu), T_BODY_IMU)[0] + rng.normal(0, gyro_noise, (len(t_imu), 3))
    t_cam = np.arange(0.5, duration, 0.05)
    R_wc = traj.at(t_cam + offset).R_world_body @ T_BODY_CAM[:3, :3]
    if pose_noise_deg:
        R_wc = geo.R_from_rotvec(rng.normal(0, np.radians(pose_noise_deg), (len(t_cam), 3))) @ R_wc
    return t_cam, R_wc, t_imu, gyro


def _true_R_imu_cam():
    return T_BODY_IMU[:3, :3].T @ T_BODY_CAM[:3, :3]


def test_exact_rates_give_offset_and_rotation():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(4))
    t_cam, R_wc, t_imu, gyro = _recording(traj, offset=0.0137)
    s = imu_start.rate_start(t_cam, R_wc, t_imu, gyro)
    assert abs(s.time_offset_s - 0.0137) < 3e-4
    assert geo.rotation_angle_deg(s.R_imu_cam.T @ _true_R_imu_cam()) < 0.05
    assert s.correlation > 0.99


def test_noisy_poses_and_gyro_still_start_close():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(5))
    # PnP-like pose noise (0.1 deg per frame) and 10x the ADIS16448's gyro noise per sample
    t_cam, R_wc, t_imu, gyro = _recording(traj, offset=-0.042, seed=2, pose_noise_deg=0.1, gyro_noise=2.4e-2)
    s = imu_start.rate_start(t_cam, R_wc, t_imu, gyro)
    assert abs(s.time_offset_s + 0.042) < 2e-3
    assert geo.rotation_angle_deg(s.R_imu_cam.T @ _true_R_imu_cam()) < 0.5


def test_offset_outside_the_window_is_refused_not_clipped():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(4))
    t_cam, R_wc, t_imu, gyro = _recording(traj, offset=0.3)
    with pytest.raises(CalibrationError, match="outside the search window"):
        imu_start.rate_start(t_cam, R_wc, t_imu, gyro, window_s=0.1)
    # the same recording with a window that contains it is found
    assert abs(imu_start.rate_start(t_cam, R_wc, t_imu, gyro, window_s=0.4).time_offset_s - 0.3) < 3e-4


def test_rotation_about_one_axis_is_refused():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(4))
    amp = traj.ang_amp.copy()
    amp[1:] = 0.0  # yaw only
    t_cam, R_wc, t_imu, gyro = _recording(replace(traj, ang_amp=amp), offset=0.01)
    with pytest.raises(CalibrationError, match="fewer than two axes"):
        imu_start.rate_start(t_cam, R_wc, t_imu, gyro, what="cameras.front_left")


def test_never_accelerating_is_refused_and_hand_held_is_accepted():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(4))
    t = np.arange(0.0, 10.0, 0.01)
    imu_start.check_acceleration(traj.at(t).a_world, "rec")  # hand-held motion passes
    still = replace(traj, pos_amp=np.zeros_like(traj.pos_amp))
    with pytest.raises(CalibrationError, match="hardly accelerates"):
        imu_start.check_acceleration(still.at(t).a_world, "rec")


def test_kabsch_recovers_a_rotation_and_gyro_means_integrate_exactly():
    rng = np.random.default_rng(0)
    R = geo.R_from_rotvec(rng.normal(0, 1, 3))
    b = rng.normal(0, 1, (20, 3))
    assert geo.rotation_angle_deg(imu_start.kabsch(b @ R.T, b).T @ R) < 1e-9
    # a linear gyro signal: the trapezoid mean over any interval is exact
    t = np.linspace(0, 1, 101)
    g = np.column_stack([t, 2 * t, -t])
    m = imu_start.gyro_means(t, g, np.array([0.1, 0.33]), np.array([0.5, 0.9]))
    np.testing.assert_allclose(m[:, 0], [0.3, 0.615], atol=1e-12)
    np.testing.assert_allclose(m[:, 1], 2 * m[:, 0], atol=1e-12)


def test_images_outside_the_imu_stream_are_refused():
    traj = imu_model.hand_held_trajectory(np.random.default_rng(4))
    t_cam, R_wc, t_imu, gyro = _recording(traj, offset=0.0)
    with pytest.raises(CalibrationError, match="overlap the IMU stream"):
        imu_start.rate_start(t_cam + 100.0, R_wc, t_imu, gyro)


def test_frame_poses_take_the_given_start_poses_of_each_frames_largest_view():
    """build_inputs' per-image poses: the camera-only step's start pose of each frame's
    largest view when given (no second PnP), else a PnP of that view; on exact corners the
    two agree."""
    from rigcal.core.camera import CameraModel
    from rigcal.imucal.step import _frame_poses

    cam = CameraModel("pinhole", 640, 480, 400.0, 400.0, 320.0, 240.0, (-0.1, 0.02, 0.0, 0.0, 0.0))
    gx, gy = np.meshgrid(np.arange(6) * 0.04, np.arange(5) * 0.04)
    board = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    rng = np.random.default_rng(3)
    uv, p, view, frame, brd, T_views = [], [], [], [], [], []
    for v in range(8):  # two views (boards) per frame, the second with fewer corners
        T = geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.2, 3)) @ geo.R_from_rotvec([np.pi, 0, 0]),
                       [-0.1 + 0.02 * rng.normal(), -0.08, 0.5 + 0.05 * v])
        n = 30 if v % 2 == 0 else 12
        xy, _ = cam.project(geo.transform(T, board[:n]))
        uv.append(xy), p.append(board[:n]), view.append(np.full(n, v)), frame.append(np.full(n, v // 2))
        brd.append(np.full(n, v % 2)), T_views.append(T)
    args = [np.concatenate(x) for x in (uv, p, view, frame, brd)]
    faces = [1.0, 1.0]
    f_given, b_given, T_given = _frame_poses(cam, *args, faces, view_T_cam_board=np.array(T_views))
    f_pnp, b_pnp, T_pnp = _frame_poses(cam, *args, faces)
    assert list(f_given) == [0, 1, 2, 3] and list(b_given) == [0, 0, 0, 0]  # each frame's 30-corner view
    assert np.array_equal(f_given, f_pnp) and np.array_equal(b_given, b_pnp)
    assert np.allclose(T_given, geo.inv_T(np.array(T_views)[[0, 2, 4, 6]]), atol=1e-15)
    assert np.allclose(T_pnp, T_given, atol=1e-7)
