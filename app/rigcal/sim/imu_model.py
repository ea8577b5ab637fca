"""The IMU measurement model and a smooth hand-held trajectory (docs/formats.md#motion-datasets).

Conventions: world ENU (z up), body FLU, `g_world = [0, 0, -9.80665]`. An IMU's gyroscope
reads its angular velocity in its own axes, its accelerometer the specific force

    gyro  = R_body_imu.T @ omega_body + b_g + n_g
    accel = R_world_imu.T @ (a_world_imu - g_world) + b_a + n_a

where a_world_imu is the acceleration of the IMU's own point (the lever arm r = t_body_imu):
a_imu = a_body + R_world_body @ (alpha_body x r + omega_body x (omega_body x r)).

Noise: Kalibr's continuous-time densities become discrete standard deviations
sigma = density * sqrt(rate) per sample, and each bias does a random walk with steps of
sigma_step = random_walk / sqrt(rate) (Kalibr's imu.yaml convention).

The trajectory has analytic first and second derivatives (sums of sinusoids in position
and in yaw/pitch/roll angles), so the IMU sees continuous angular velocity and acceleration
without finite differences of poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import Imu
from rigcal.core.spline import Motion  # the trajectory sample both the simulator and the spline give

GRAVITY = 9.80665
G_WORLD = np.array([0.0, 0.0, -GRAVITY])
BIAS_SAMPLE_HZ = 10.0  # truth.yaml samples the true biases at this rate (docs/formats.md#motion-datasets)
# Turn-on biases of the simulated IMU (1-sigma per axis): typical of a MEMS IMU such as the
# ADIS16448 after factory calibration; the declared random walks take them on from there.
GYRO_BIAS_SIGMA = 2e-3  # rad/s
ACCEL_BIAS_SIGMA = 5e-2  # m/s^2


def _sines(t: np.ndarray, amp: np.ndarray, freq: np.ndarray, phase: np.ndarray) -> tuple[np.ndarray, ...]:
    """Value, first and second derivative (N, D) of sum_k amp[d, k] sin(2 pi freq[d, k] t + phase[d, k])."""
    w = 2 * math.pi * freq  # (D, K)
    arg = w[None] * t[:, None, None] + phase[None]  # (N, D, K)
    s, c = np.sin(arg), np.cos(arg)
    return (amp * s).sum(-1), (amp * w * c).sum(-1), (-amp * w * w * s).sum(-1)


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations by `angle` (N,) about body axis 0, 1 or 2."""
    rv = np.zeros((len(angle), 3))
    rv[:, axis] = angle
    return geo.R_from_rotvec(rv)


@dataclass(frozen=True)
class SineTrajectory:
    """T_world_body(t) = position p0 + sum of sines; R = Rz(yaw) Ry(pitch) Rx(roll), each angle
    a base value plus a sum of sines. amp/freq/phase arrays are (3, K): rows x, y, z for the
    position and yaw, pitch, roll for the angles (radians, Hz, radians)."""

    p0: np.ndarray
    pos_amp: np.ndarray
    pos_freq: np.ndarray
    pos_phase: np.ndarray
    ypr0: np.ndarray
    ang_amp: np.ndarray
    ang_freq: np.ndarray
    ang_phase: np.ndarray

    def at(self, t: np.ndarray) -> Motion:
        """The motion at times t (N,) seconds, all derivatives analytic."""
        t = np.atleast_1d(np.asarray(t, float))
        p, v, a = _sines(t, self.pos_amp, self.pos_freq, self.pos_phase)
        ang, dang, ddang = _sines(t, self.ang_amp, self.ang_freq, self.ang_phase)
        ang = ang + self.ypr0
        yaw, pitch, roll = ang.T
        Rz, Ry, Rx = _rot(2, yaw), _rot(1, pitch), _rot(0, roll)
        R = Rz @ Ry @ Rx
        ez = np.array([0.0, 0.0, 1.0])
        # world angular velocity: yaw about world z, pitch about the yawed y, roll about the body x
        roll_axis = (Rz @ Ry)[:, :, 0]
        pitch_axis = Rz[:, :, 1]
        omega_w = dang[:, :1] * ez + dang[:, 1:2] * pitch_axis + dang[:, 2:3] * roll_axis
        # its time derivative: each axis turns with the rotations applied before it
        w_yaw = dang[:, :1] * ez
        d_pitch_axis = np.cross(w_yaw, pitch_axis)
        d_roll_axis = np.cross(w_yaw + dang[:, 1:2] * pitch_axis, roll_axis)
        alpha_w = (ddang[:, :1] * ez + ddang[:, 1:2] * pitch_axis + dang[:, 1:2] * d_pitch_axis
                   + ddang[:, 2:3] * roll_axis + dang[:, 2:3] * d_roll_axis)
        Rt = np.transpose(R, (0, 2, 1))
        # d/dt (R^T w) = R^T alpha_w - omega_b x omega_b = R^T alpha_w
        return Motion(t=t, R_world_body=R, p_world=p + self.p0, v_world=v, a_world=a,
                      omega_body=(Rt @ omega_w[..., None])[..., 0], alpha_body=(Rt @ alpha_w[..., None])[..., 0])


# Hand-held motion in front of the boards: amplitudes per component (two sines each, the
# second at about 1.9x the first's frequency), chosen so every axis is excited while a
# camera's board stays mostly in view (yaw up to ~20 deg, pitch ~10, roll ~13, 0.15-0.3 m).
POS_AMP_M = np.array([[0.15, 0.06], [0.20, 0.08], [0.10, 0.05]])
ANG_AMP_RAD = np.radians([[14.0, 6.0], [7.0, 3.0], [9.0, 4.0]])
BASE_FREQ_HZ = np.array([[0.37, 0.79], [0.31, 0.67], [0.47, 0.91]])  # position x, y, z
ANG_FREQ_HZ = np.array([[0.34, 0.73], [0.52, 0.95], [0.41, 0.83]])  # yaw, pitch, roll


def hand_held_trajectory(rng: np.random.Generator, p0=(0.0, 0.0, 0.0), heading_rad: float = math.pi / 2,
                         scale: float = 1.0) -> SineTrajectory:
    """A seeded smooth hand-held-like motion around p0 (world), level and heading `heading_rad`
    (ENU yaw; pi/2 = north) on average; frequencies jittered by +-10 %, random phases.
    `scale` multiplies every amplitude (0 gives a rig at rest)."""
    jitter = lambda f: f * rng.uniform(0.9, 1.1, f.shape)  # noqa: E731
    return SineTrajectory(
        p0=np.asarray(p0, float), pos_amp=scale * POS_AMP_M, pos_freq=jitter(BASE_FREQ_HZ),
        pos_phase=rng.uniform(0, 2 * math.pi, POS_AMP_M.shape), ypr0=np.array([heading_rad, 0.0, 0.0]),
        ang_amp=scale * ANG_AMP_RAD, ang_freq=jitter(ANG_FREQ_HZ),
        ang_phase=rng.uniform(0, 2 * math.pi, ANG_AMP_RAD.shape))


def excitation(motion: Motion) -> dict[str, list[float]]:
    """Peak |angular rate| (deg/s) and |acceleration| (m/s^2) per axis (body axes for rates,
    world for accelerations), plus the ranges of position (m) and of the body's tilt."""
    return {"peak_rate_deg_s": np.degrees(np.abs(motion.omega_body).max(axis=0)).tolist(),
            "peak_accel_m_s2": np.abs(motion.a_world).max(axis=0).tolist(),
            "position_range_m": np.ptp(motion.p_world, axis=0).tolist()}


# ----------------------------------------------------------------------------- the IMU


def ideal_readings(motion: Motion, T_body_imu: np.ndarray, g_world: np.ndarray = G_WORLD
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Noise- and bias-free (gyro (N, 3) rad/s, accel (N, 3) m/s^2) of an IMU at T_body_imu."""
    R_body_imu, r_body = T_body_imu[:3, :3], T_body_imu[:3, 3]
    w, al = motion.omega_body, motion.alpha_body
    lever_body = np.cross(al, r_body) + np.cross(w, np.cross(w, r_body))
    a_imu_world = motion.a_world + (motion.R_world_body @ lever_body[..., None])[..., 0]
    f_body = (np.transpose(motion.R_world_body, (0, 2, 1)) @ (a_imu_world - g_world)[..., None])[..., 0]
    return w @ R_body_imu, f_body @ R_body_imu  # row-vector form of R_body_imu.T @ v


def bias_walk(n: int, rate: float, random_walk: float, b0: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) bias starting at b0 with steps N(0, random_walk / sqrt(rate)) per sample."""
    steps = rng.standard_normal((n, 3)) * (random_walk / math.sqrt(rate))
    steps[0] = 0.0
    return b0 + np.cumsum(steps, axis=0)


@dataclass(frozen=True)
class ImuStream:
    """One IMU's samples: t (N,) seconds on the IMU clock, readings (N, 3) and the true biases."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray


def synthesize(motion: Motion, imu: Imu, rng: np.random.Generator, noise: bool = True) -> ImuStream:
    """Readings of `imu` along `motion` (sampled at the IMU's rate): ideal readings plus biases
    doing the declared random walks from a seeded turn-on value, plus white noise.
    noise=False: biases zero and no white noise (the golden check)."""
    n = len(motion.t)
    gyro, accel = ideal_readings(motion, imu.T_body_imu)
    if not noise:
        zero = np.zeros((n, 3))
        return ImuStream(motion.t, gyro, accel, zero, zero.copy())
    rate = imu.update_rate
    bg = bias_walk(n, rate, imu.gyroscope_random_walk, rng.normal(0, GYRO_BIAS_SIGMA, 3), rng)
    ba = bias_walk(n, rate, imu.accelerometer_random_walk, rng.normal(0, ACCEL_BIAS_SIGMA, 3), rng)
    ng = rng.standard_normal((n, 3)) * (imu.gyroscope_noise_density * math.sqrt(rate))
    na = rng.standard_normal((n, 3)) * (imu.accelerometer_noise_density * math.sqrt(rate))
    return ImuStream(motion.t, gyro + bg + ng, accel + ba + na, bg, ba)
