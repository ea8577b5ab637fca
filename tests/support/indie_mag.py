"""An independent magnetometer-dance simulator written from the contracts alone
(magnetometer.md, imu.md), sharing no code with rigcal's: scipy's Rotation for the attitude,
angular rates by differencing a 2 kHz attitude track, its own CSV and YAML text. So rigcal's
simulator and estimator cannot share a convention bug (the field's inclination sign, the
clock offset's direction, which way R_body_mag maps, FLU/ENU) without this one disagreeing.

The rig turns about its own centre (no translation): the accelerometer reads R_world_imu.T
[0, 0, g] plus noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

G = 9.80665
EPOCH_NS = 1_700_000_000_000_000_000
FINE_HZ = 2000.0


def attitude(t: np.ndarray) -> Rotation:
    """R_world_body(t): three incommensurate turns that visit every orientation."""
    yaw = 0.9 * t + 0.4 * np.sin(0.5 * t)
    pitch = 1.2 * np.sin(0.37 * t + 0.3)
    roll = 0.7 * t + 0.8 * np.sin(0.23 * t)
    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))


def write_dance(out: Path, *, seconds: float = 40.0, seed: int = 0, time_offset_s: float = 0.01,
                declared_offset_s: float = 0.0) -> dict:
    """A dataset folder (rig.yaml, imu/imu0.csv, mag/mag0.csv); returns the truth."""
    rng = np.random.default_rng(seed)
    # truth: chip mounted FRD-ish and turned 2 degrees about (1, 2, 3); hard and soft iron
    R_body_mag = (Rotation.from_rotvec(np.radians(2.0) * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0))
                  * Rotation.from_matrix(np.diag([1.0, -1.0, -1.0])))
    h = np.array([14.0, -22.0, 9.0])
    A = np.array([[1.06, 0.03, -0.02], [0.03, 0.95, 0.04], [-0.02, 0.04, 1.0]])
    A = A / np.linalg.det(A) ** (1.0 / 3.0)
    F, incl_deg = 48.0, 63.0
    incl = np.radians(incl_deg)
    b_world = F * np.array([0.0, np.cos(incl), -np.sin(incl)])  # ENU, north = +y, down for I > 0
    # IMU (axes = body FLU) at 200 Hz: rates from the fine attitude track
    fine = np.arange(0.0, seconds + 0.01, 1.0 / FINE_HZ)
    R_fine = attitude(fine)
    omega_mid = (R_fine[:-1].inv() * R_fine[1:]).as_rotvec() * FINE_HZ  # body rates at the midpoints
    t_mid = 0.5 * (fine[:-1] + fine[1:])
    t_imu = np.arange(0.0, seconds, 1.0 / 200.0)
    gyro = np.column_stack([np.interp(t_imu, t_mid, omega_mid[:, i]) for i in range(3)])
    gyro += rng.normal(0.0, 2e-3, gyro.shape) + np.array([0.002, -0.001, 0.0015])
    accel = attitude(t_imu).inv().apply(np.array([0.0, 0.0, G])) + rng.normal(0.0, 0.03, (len(t_imu), 3))
    # magnetometer at 100 Hz on its own clock: its stamp t_mag is the IMU's t_mag + time_offset_s
    t_mag = np.arange(0.05, seconds - 0.05, 1.0 / 100.0)
    b_body = attitude(t_mag + time_offset_s).inv().apply(b_world)
    m = (np.linalg.inv(A) @ R_body_mag.as_matrix().T @ b_body.T).T + h + rng.normal(0.0, 0.5, (len(t_mag), 3))
    (out / "imu").mkdir(parents=True)
    (out / "mag").mkdir()
    rows = [f"{EPOCH_NS + int(round(t * 1e9))},{','.join(f'{v:.9g}' for v in (*g, *a))}"
            for t, g, a in zip(t_imu, gyro, accel)]
    (out / "imu" / "imu0.csv").write_text("#timestamp [ns],wx,wy,wz,ax,ay,az\n" + "\n".join(rows) + "\n")
    rows = [f"{EPOCH_NS + int(round(t * 1e9))},{','.join(f'{v:.9g}' for v in r)}" for t, r in zip(t_mag, m)]
    (out / "mag" / "mag0.csv").write_text("#timestamp [ns],m_x [uT],m_y [uT],m_z [uT]\n" + "\n".join(rows) + "\n")
    (out / "rig.yaml").write_text(f"""rig: indie-mag
imus:
  imu0:
    position: [0.0, 0.0, 0.0]
    axes: [F, L, U]
    update_rate: 200.0
    gyroscope_noise_density: 1.4e-4
    gyroscope_random_walk: 1.0e-5
    accelerometer_noise_density: 2.0e-3
    accelerometer_random_walk: 3.0e-3
magnetometers:
  mag0:
    axes: [F, -L, -U]
    update_rate: 100.0
    noise_density: 0.05
    time_offset_s: {declared_offset_s}
cameras:
  cam0:
    resolution: [640, 480]
    intrinsics: {{focal: 300.0}}
    position: [0.1, 0.0, 0.0]
    look: forward
""")
    return {"R_body_mag": R_body_mag.as_matrix(), "hard_iron": h, "soft_iron": A, "field_uT": F,
            "inclination_deg": incl_deg, "time_offset_s": time_offset_s}
