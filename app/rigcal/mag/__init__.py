"""Magnetometer calibration (docs/magnetometer.md): hard iron, soft iron and the
chip's orientation against an IMU, from a recording turned through many orientations."""
