"""Simulation: rendered board images, synthetic corner observations, IMU trajectories and recordings
with ground truth (`rigcal simulate`)."""
