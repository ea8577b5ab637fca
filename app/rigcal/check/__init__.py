"""`rigcal check`: is a calibrated rig still what a short new recording says?

inputs (the calibrated rig and the recording, detected) -> estimate (the rig again from the
new views, started from the old) -> verdict (per camera chi-square tests of intrinsics and
pose, decide: the statistics and which camera moved) -> outputs (table, JSON, --update) and
report (HTML). run ties them together for the CLI. Between sim and results in the layer
order: imports core, data, detect, camcal and (the camera-IMU part, check.imu) imucal only.
"""
