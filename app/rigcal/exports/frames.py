"""Frame, direction, quaternion and clock conventions of the estimator and autopilot
exports, converted here and nowhere else.

rigcal's side (rigcal.core.geometry): body frame FLU (x forward, y left, z up);
``T_a_b`` maps b-frame points into a (``p_a = T_a_b p_b``); quaternions ``[w, x, y, z]``;
a camera's ``time_offset_s`` obeys ``t_imu = t_cam + time_offset_s``.

The targets' side:

=================  =========================================  ==========================
target             transform it stores                        rigcal expression
=================  =========================================  ==========================
OpenVINS           ``T_imu_cam`` (camera -> IMU)              T_imu_cam(imu, cam)
VINS-Fusion        ``body_T_camN`` (camera -> IMU)            T_imu_cam(imu, cam)
ORB-SLAM3          ``IMU.T_b_c1`` (camera 1 -> IMU)           T_imu_cam(imu, cam1)
ORB-SLAM3          ``Stereo.T_c1_c2`` (camera 2 -> camera 1)  T_cam_cam(cam1, cam2)
basalt             ``T_imu_cam`` px py pz qx qy qz qw         T_imu_cam, quat_xyzw
PX4 / ArduPilot    position in FRD (x fwd, y right, z down)   p_frd(t_body_cam)
=================  =========================================  ==========================

Clocks: Kalibr's and OpenVINS's ``timeshift_cam_imu``, VINS-Fusion's ``td`` and basalt's
``cam_time_offset_ns`` all mean ``t_imu = t_cam + offset`` (rigcal's sign). PX4's
``EKF2_EV_DELAY`` and ArduPilot's ``VISO_DELAY_MS`` are how late a camera measurement
arrives after the instant it describes: ``delay = -offset``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from rigcal.core import geometry as geo

# FLU <-> FRD: x kept, y and z negated. The same matrix both ways (it is its own inverse).
R_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def T_imu_cam(T_body_imu: np.ndarray, T_body_cam: np.ndarray) -> np.ndarray:
    """The camera's pose in the IMU frame (maps camera points into the IMU frame), 4x4."""
    return geo.inv_T(T_body_imu) @ T_body_cam


def T_cam_cam(T_body_a: np.ndarray, T_body_b: np.ndarray) -> np.ndarray:
    """Camera b's pose in camera a (maps b's points into a): ORB-SLAM3's T_c1_c2 for a=c1, b=c2."""
    return geo.inv_T(T_body_a) @ T_body_b


def p_frd(p_flu: Sequence[float]) -> np.ndarray:
    """A point or direction (3,) or (N, 3) given in FLU, in FRD."""
    return np.asarray(p_flu, dtype=float) @ R_FRD_FLU.T


def R_frd(R_flu_x: np.ndarray) -> np.ndarray:
    """A rotation R_flu_x (frame x's axes in FLU terms) as R_frd_x."""
    return R_FRD_FLU @ np.asarray(R_flu_x, dtype=float)


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """R -> [x, y, z, w] (Eigen's storage order, basalt's qx qy qz qw), w >= 0."""
    w, x, y, z = geo.quat_from_R(R)
    return np.array([x, y, z, w])


def R_from_quat_xyzw(q: Sequence[float]) -> np.ndarray:
    """[x, y, z, w] unit quaternion -> R."""
    x, y, z, w = (float(v) for v in q)
    return geo.R_from_quat([w, x, y, z])


def pose_xyzw(T: np.ndarray) -> dict[str, float]:
    """4x4 -> basalt's pose record {px, py, pz, qx, qy, qz, qw}."""
    q = quat_xyzw(T[:3, :3])
    t = T[:3, 3]
    return {"px": float(t[0]) + 0.0, "py": float(t[1]) + 0.0, "pz": float(t[2]) + 0.0,
            "qx": float(q[0]) + 0.0, "qy": float(q[1]) + 0.0, "qz": float(q[2]) + 0.0, "qw": float(q[3]) + 0.0}


def T_from_pose_xyzw(d: dict) -> np.ndarray:
    """basalt's pose record -> 4x4 (the inverse of pose_xyzw)."""
    return geo.make_T(R_from_quat_xyzw([d["qx"], d["qy"], d["qz"], d["qw"]]), [d["px"], d["py"], d["pz"]])


def delay_ms(time_offset_s: float) -> float:
    """rigcal's time_offset_s (t_imu = t_cam + offset) -> an autopilot's measurement delay, ms."""
    return -1000.0 * float(time_offset_s)


def offset_ns(time_offset_s: float) -> int:
    """rigcal's time_offset_s -> basalt's cam_time_offset_ns (same sign, whole nanoseconds)."""
    return int(round(float(time_offset_s) * 1e9))
