"""Synthetic camera-IMU recordings without rendering: the `simulate --scene imu` truth
(same rig perturbation, trajectory, boards, clocks and IMU streams, seeded the same way)
with each board corner projected through the true camera at its true time plus Gaussian
pixel noise, and per-frame camera poses by PnP on those corners (as a real start would
get them). For tests and benches of rigcal.imucal.estimator; the rendering path itself is tested
in tests/sim/test_simulate_imu.py.

A rolling shutter (a camera's line_delay_s) exposes each corner at its own row's time:
the projection iterates on the row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.core import geometry as geo
from rigcal.sim import imu_model
from rigcal.imucal.estimator import CameraInput, ImuInput
from rigcal.imucal.residuals import Corners
from rigcal.camcal.initialise import pnp_views
from rigcal.core.rig import Rig
from rigcal.sim.imu_scene import MARGIN_S, frame_timing, plan_boards, true_rig_for_motion

PERTURBATION = {"mount_error_mm": 5.0, "mount_error_deg": 1.0, "focal_error": 0.02}
MIN_PNP_CORNERS = 8


@dataclass(frozen=True, eq=False)
class SyntheticRecording:
    """truth: the true rig (time offsets included); cams and imu: the estimator's inputs
    (true intrinsics, declared T_body_cam, PnP frame poses); obs: all corners; the true
    biases (N, 3) at times t_bias (N,)."""

    truth: Rig
    cams: list
    imu: ImuInput
    obs: Corners
    t_bias: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray


def _frame_poses(cam_model, T_world_board_f, p_board, uv, keep):
    """PnP per frame (first board seen with enough corners) -> (frame index, T_world_cam)."""
    idx, obj, img, boards = [], [], [], []
    for f in range(keep.shape[0]):
        for b in range(keep.shape[1]):
            if keep[f, b].sum() >= MIN_PNP_CORNERS:
                idx.append(f)
                obj.append(p_board[b][keep[f, b]])
                img.append(uv[f, b][keep[f, b]])
                boards.append(b)
                break
    vals = np.array([cam_model.fx, cam_model.fy, cam_model.cx, cam_model.cy, *cam_model.dist])
    fits = pnp_views(obj, img, vals, cam_model.model)
    ok = [k for k, fit in enumerate(fits) if fit is not None]
    T_world_cam = np.stack([T_world_board_f[boards[k]] @ geo.inv_T(fits[k][0]) for k in ok])
    return np.array([idx[k] for k in ok]), T_world_cam


def _project_rows(traj, cam, t_frame: np.ndarray, p_world: np.ndarray, iters: int = 4):
    """Pixels (F * N, 2) and validity of world points (N, 3) seen by `cam` in frames at IMU
    times t_frame (F,); with a rolling shutter each point at its own row's time, found by
    fixed-point iteration on the row (converges: the image moves far less than a row per
    row-time)."""
    t = np.repeat(t_frame, len(p_world))
    p = np.tile(p_world, (len(t_frame), 1))
    ld = cam.line_delay_s or 0.0
    t_row = t
    for _ in range(iters if ld else 1):
        T_cam_world = geo.inv_T(traj.at(t_row).T_world_body @ cam.T_body_cam)
        p_c = np.einsum("mij,mj->mi", T_cam_world[:, :3, :3], p) + T_cam_world[:, :3, 3]
        uv, valid = cam.intrinsics.project(p_c)
        t_row = t + np.nan_to_num(uv[:, 1]) * ld
    return uv, valid


def synthetic_recording(rig: Rig, duration: float, camera_rate: float = 20.0, seed: int = 0, sigma_px: float = 0.3,
                        time_offset_ms: float = 10.0, trajectory: imu_model.SineTrajectory | None = None
                        ) -> SyntheticRecording:
    """A recording of `rig` (one IMU) as `simulate --scene imu` would make it, as corners;
    `trajectory` replaces the hand-held motion (e.g. a degenerate one)."""
    truth = true_rig_for_motion(rig, seed, time_offset_ms, PERTURBATION)
    traj = trajectory or imu_model.hand_held_trajectory(np.random.default_rng([seed, 2]))
    mean_pose = geo.make_T(geo.R_from_rotvec(np.array([0.0, 0.0, traj.ypr0[0]])), traj.p0)
    target, T_world_board = plan_boards(truth, mean_pose, None)
    timing = frame_timing(truth, duration, camera_rate)
    imu = truth.imus[0]
    t_end = duration + 2 * MARGIN_S
    t_imu = np.arange(int(math.floor(t_end * imu.update_rate)) + 1) / imu.update_rate
    stream = imu_model.synthesize(traj.at(t_imu), imu, np.random.default_rng([seed, 4, 0]))
    rng = np.random.default_rng([seed, 5])
    p_board = [b.corners for b in target.boards]
    cams, parts = [], []
    for ci, cam in enumerate(truth.cameras):
        t_true = timing.t_imu_s[ci]
        uv_all, keep_all = [], []
        for b, T_world_board_b in enumerate(T_world_board):
            p_w = geo.transform(T_world_board_b, p_board[b])
            uv, valid = _project_rows(traj, cam, t_true, p_w)
            uv = uv + rng.normal(0.0, sigma_px, uv.shape)
            keep = valid & cam.intrinsics.in_image(uv)
            uv_all.append(uv.reshape(len(t_true), -1, 2))
            keep_all.append(keep.reshape(len(t_true), -1))
            f, n = np.nonzero(keep_all[-1])
            t_cam = t_true - cam.time_offset_s
            parts.append((np.full(len(f), ci), t_cam[f], uv_all[-1][f, n], p_w[n]))
        keep_fb = np.stack(keep_all, axis=1)  # (F, B, N) needs equal N per board
        uv_fb = np.stack(uv_all, axis=1)
        frames, T_world_cam = _frame_poses(cam.intrinsics, T_world_board, p_board, uv_fb, keep_fb)
        declared = rig.camera(cam.name)
        cams.append(CameraInput(cam.intrinsics, declared.T_body_cam.copy(), t_true[frames] - cam.time_offset_s,
                                T_world_cam, declared.line_delay_s or 0.0))
    obs = Corners(*(np.concatenate(x) for x in zip(*parts)))
    declared_imu = rig.imus[0]
    imu_in = ImuInput(t_imu, stream.gyro, stream.accel, imu.update_rate, imu.gyroscope_noise_density,
                      imu.gyroscope_random_walk, imu.accelerometer_noise_density, imu.accelerometer_random_walk,
                      declared_imu.T_body_imu.copy())
    return SyntheticRecording(truth, cams, imu_in, obs, t_imu, stream.gyro_bias, stream.accel_bias)


def errors_against_truth(rec, T_imu_cam: np.ndarray, time_offset_s: np.ndarray) -> np.ndarray:
    """(C, 3): rotation error (deg), translation error (m) of T_imu_cam and offset error (s)
    against `rec.truth` (a SyntheticRecording or simulate_imu.MotionSimResult)."""
    T_body_imu = rec.truth.imus[0].T_body_imu
    out = []
    for c, T, off in zip(rec.truth.cameras, T_imu_cam, time_offset_s):
        T_true = geo.inv_T(T_body_imu) @ c.T_body_cam
        out.append([geo.rotation_angle_deg(T[:3, :3].T @ T_true[:3, :3]),
                    float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])), float(off - c.time_offset_s)])
    return np.array(out)


def component_errors(rec, T_imu_cam: np.ndarray, time_offset_s: np.ndarray, T_body_imu: np.ndarray) -> np.ndarray:
    """(C, 7) errors in the axes of CameraImuResult.sigma: rotation (rad, Log(R_est R_true^T)
    in body axes), translation (m, body axes), offset (s), with the body frame the estimate's
    (its IMU held at T_body_imu). Each component against its own 1-sigma is the honest test
    of the reported sigmas; the angle against the norm of three sigmas mixes axes."""
    T_bi_true = rec.truth.imus[0].T_body_imu
    out = []
    for c, T, off in zip(rec.truth.cameras, T_imu_cam, time_offset_s):
        T_ic_true = geo.inv_T(T_bi_true) @ c.T_body_cam
        R_bi = T_body_imu[:3, :3]
        d_rot = geo.rotvecs_from_R((R_bi @ T[:3, :3] @ T_ic_true[:3, :3].T @ R_bi.T)[None])[0]
        out.append([*d_rot, *(R_bi @ (T[:3, 3] - T_ic_true[:3, 3])), off - c.time_offset_s])
    return np.array(out)
