"""Rig-file text for an IMU, shared by the rig-loader and IMU-simulation tests."""

IMU_BLOCK = """\
imus:
  imu0:
    position: [0.01, 0.02, -0.03]
    axes: [F, -L, -U]
    update_rate: 200.0
    gyroscope_noise_density: 1.7e-4
    gyroscope_random_walk: 1.9e-5
    accelerometer_noise_density: 2.0e-3
    accelerometer_random_walk: 3.0e-3
"""
