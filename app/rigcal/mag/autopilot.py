"""A calibrated rig's magnetometers as PX4 and ArduPilot parameters.

Both autopilots use a forward-right-down body frame (FRD; rigcal's body is FLU, so
R_frd_flu = diag(1, -1, -1)) and take the chip's orientation as an enum of Euler angles
(R = Rz(yaw) Ry(pitch) Rx(roll), rotating chip axes into body axes); the table below holds
the enum values 0-37, which the two autopilots share. The raw readings are taken to be the
ones the autopilot's driver delivers in the chip's axes (rigcal's `m`, in microtesla).

rigcal:     b_body = R_body_mag @ A @ (m - h)                     (FLU, uT)
PX4:        b_frd  = R_enum @ (S @ (m_G - OFF))                   (gauss; offsets subtracted in chip axes)
            CAL_MAGn_{X,Y,Z}OFF = h / 100, CAL_MAGn_{X,Y,Z}SCALE = diag(A),
            CAL_MAGn_{X,Y,Z}ODIAG = A[0,1], A[0,2], A[1,2], CAL_MAGn_ROT = the nearest enum.
            PX4 has no custom rotation for a magnetometer: what the fit differs from the enum by
            stays a heading error (px4_rotation_residual_deg says how much).
ArduPilot:  b_frd  = M @ (R_orient @ m_mG + OFS)                  (milligauss; offsets added in body axes)
            with R_orient = Q = R_frd_flu @ R_body_mag: M = Q A Q.T, OFS = -Q h * 10;
            COMPASS_ORIENT the enum when the fit is within ENUM_TOLERANCE_DEG of one, else
            101/102 (ROTATION_CUSTOM_1/2) with CUST_ROT_ENABLE = 1 and CUST_ROTn_ROLL/PITCH/YAW.
"""

from __future__ import annotations

import math

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import Magnetometer, Rig
from rigcal.errors import InputError

R_FRD_FLU = np.diag([1.0, -1.0, -1.0])
UT_PER_GAUSS = 100.0
MILLIGAUSS_PER_UT = 10.0
ENUM_TOLERANCE_DEG = 0.05  # a fit this close to an enum rotation is that enum (below typical 1-sigma x 3)
# (roll, pitch, yaw) degrees of the shared enum values 0..37 (PX4 rotation.h, ArduPilot rotations.h)
ROTATION_ENUM = (
    (0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225), (0, 0, 270), (0, 0, 315),
    (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135), (0, 180, 0), (180, 0, 225), (180, 0, 270),
    (180, 0, 315), (90, 0, 0), (90, 0, 45), (90, 0, 90), (90, 0, 135), (270, 0, 0), (270, 0, 45),
    (270, 0, 90), (270, 0, 135), (0, 90, 0), (0, 270, 0), (0, 180, 90), (0, 180, 270), (90, 90, 0),
    (180, 90, 0), (270, 90, 0), (90, 180, 0), (270, 180, 0), (90, 270, 0), (180, 270, 0), (270, 270, 0),
    (90, 180, 90), (90, 0, 270))
CUSTOM_ENUMS = (101, 102)  # ArduPilot's ROTATION_CUSTOM_1, _2


def R_from_euler_deg(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll), degrees (both autopilots' Euler convention)."""
    r, p, y = (math.radians(v) for v in (roll, pitch, yaw))
    Rx = geo.R_from_rotvec(np.array([r, 0.0, 0.0]))
    Ry = geo.R_from_rotvec(np.array([0.0, p, 0.0]))
    Rz = geo.R_from_rotvec(np.array([0.0, 0.0, y]))
    return Rz @ Ry @ Rx


def euler_deg_from_R(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) degrees with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-90, 90]."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


def nearest_enum(R_frd_mag: np.ndarray) -> tuple[int, float]:
    """(enum value, angle in degrees between R_frd_mag and that enum's rotation)."""
    angles = [geo.rotation_angle_deg(R_from_euler_deg(*e).T @ R_frd_mag) for e in ROTATION_ENUM]
    i = int(np.argmin(angles))
    return i, float(angles[i])


def _calibrated(mags: tuple[Magnetometer, ...]) -> list[tuple[int, Magnetometer, np.ndarray, np.ndarray]]:
    out = []
    for n, m in enumerate(mags):
        c = m.calibration or {}
        if "hard_iron_uT" in c and "soft_iron" in c:
            out.append((n, m, np.asarray(c["hard_iron_uT"], float), np.asarray(c["soft_iron"], float)))
    return out


def px4_mag_params(rig: Rig) -> dict[str, float | int]:
    """CAL_MAGn_* of every calibrated magnetometer (n its index in the rig; PX4 holds 4)."""
    out: dict[str, float | int] = {}
    for n, m, h, A in _calibrated(rig.magnetometers):
        p = f"CAL_MAG{n}_"
        for k, ax in enumerate("XYZ"):
            out[p + f"{ax}OFF"] = float(h[k] / UT_PER_GAUSS)
            out[p + f"{ax}SCALE"] = float(A[k, k])
        out[p + "XODIAG"], out[p + "YODIAG"], out[p + "ZODIAG"] = float(A[0, 1]), float(A[0, 2]), float(A[1, 2])
        out[p + "ROT"] = nearest_enum(R_FRD_FLU @ m.T_body_mag[:3, :3])[0]
    return out


def px4_rotation_residual_deg(rig: Rig) -> dict[str, float]:
    """Per magnetometer, the angle (deg) between its calibrated orientation and CAL_MAGn_ROT's
    enum: PX4 cannot represent it, so it remains as up to this heading error."""
    return {m.name: nearest_enum(R_FRD_FLU @ m.T_body_mag[:3, :3])[1] for _, m, _, _ in _calibrated(rig.magnetometers)}


def ardupilot_mag_params(rig: Rig) -> dict[str, float | int]:
    """COMPASS_* (and CUST_ROT* where a fit is not an enum) of every calibrated magnetometer
    (n its index in the rig: COMPASS_OFS_X, COMPASS_OFS2_X, COMPASS_OFS3_X ...)."""
    out: dict[str, float | int] = {}
    custom = iter(CUSTOM_ENUMS)
    for n, m, h, A in _calibrated(rig.magnetometers):
        s = "" if n == 0 else str(n + 1)
        Q = R_FRD_FLU @ m.T_body_mag[:3, :3]
        enum, off_deg = nearest_enum(Q)
        if off_deg > ENUM_TOLERANCE_DEG:
            enum = next(custom, None)
            if enum is None:
                raise InputError(f"{m.name}: ArduPilot holds two custom rotations; a third magnetometer off the enums "
                                 f"({off_deg:.2f} deg) cannot be written")
            k = enum - CUSTOM_ENUMS[0] + 1
            out["CUST_ROT_ENABLE"] = 1
            roll, pitch, yaw = euler_deg_from_R(Q)
            out[f"CUST_ROT{k}_ROLL"], out[f"CUST_ROT{k}_PITCH"], out[f"CUST_ROT{k}_YAW"] = roll, pitch, yaw
        else:
            Q = R_from_euler_deg(*ROTATION_ENUM[enum])  # the enum exactly: the offsets match what ArduPilot applies
        M = Q @ A @ Q.T
        ofs = -(Q @ h) * MILLIGAUSS_PER_UT
        for k, ax in enumerate("XYZ"):
            out[f"COMPASS_OFS{s}_{ax}"] = float(ofs[k])
            out[f"COMPASS_DIA{s}_{ax}"] = float(M[k, k])
        out[f"COMPASS_ODI{s}_X"], out[f"COMPASS_ODI{s}_Y"], out[f"COMPASS_ODI{s}_Z"] = (
            float(M[0, 1]), float(M[0, 2]), float(M[1, 2]))
        out[f"COMPASS_SCALE{s}"] = 1.0
        out[f"COMPASS_ORIENT{s}"] = int(enum)
    return out
