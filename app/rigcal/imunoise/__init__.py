"""IMU noise figures from a static recording (`rigcal imu-noise`): the recording read and
checked (recording), the overlapping Allan deviation per axis (allan), its noise terms
with confidence intervals (terms), Kalibr's four figures (estimate), the files other
programs read (formats) and the HTML plot (report)."""

from rigcal.imunoise.estimate import ImuNoise, SensorNoise, estimate
from rigcal.imunoise.recording import ImuRecording, check, read_imu_file
from rigcal.imunoise.terms import TermFit, TooShort

__all__ = ["ImuNoise", "SensorNoise", "estimate", "ImuRecording", "check", "read_imu_file", "TermFit", "TooShort"]
