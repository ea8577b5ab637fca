"""Free-running cameras given as corners/<camera>.csv (the dataset's pre-detected corners):
their csv frames (integer ns, shared by no other camera) are grouped by time for the
camera-only start exactly as image folders are, then every view is placed at its own time:
without an IMU (imucal.visual_motion) and with imu/ (the camera-IMU step). The recordings are
projected corners of simulate's free-running schedule (tests/support/imu_check_cases.record),
so each round trip takes seconds."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.commands.calibrate import CalibrateOptions, run
from rigcal.core.rig import load_rig
from tests.support.imu_check_cases import record, true_rig

DURATION, RATE = 5.0, 20.0


@pytest.fixture(scope="module")
def truth():
    return true_rig(1, 3.0)


def _calibrate(truth, tmp, with_imu: bool):
    ds = record(truth, tmp / "ds", DURATION, RATE, seed=3, free_running=True, with_imu=with_imu)
    stems = [{ln.split(",", 1)[0] for ln in (ds / "corners" / f"{c}.csv").read_text().splitlines()[1:]}
             for c in truth.names]
    assert all(not (a & b) for i, a in enumerate(stems) for b in stems[i + 1:])  # really free-running
    out = tmp / "cal.yaml"
    run(ds, out, CalibrateOptions(jobs=1))
    return load_rig(out)


def test_corner_files_of_free_running_cameras_without_an_imu(truth, tmp_path):
    est = _calibrate(truth, tmp_path, with_imu=False)
    ref = est.calibration["free_running"]["clock"].split(":", 1)[1]
    for c in est.cameras:
        sig = c.calibration["sigma"]["time_offset_ms"]
        true_rel = truth.camera(c.name).time_offset_s - truth.camera(ref).time_offset_s
        if c.name == ref:
            continue
        assert abs(true_rel) > 3e-4  # the clocks really differ: the estimate must find them
        err_ms = 1000 * (c.time_offset_s - true_rel)
        assert abs(err_ms) <= 3 * sig and abs(err_ms) < 0.2, (c.name, err_ms, sig)


def test_corner_files_of_free_running_cameras_with_an_imu(truth, tmp_path):
    est = _calibrate(truth, tmp_path, with_imu=True)
    for c in est.cameras:
        sig = c.calibration["sigma"]["time_offset_ms"]
        err_ms = 1000 * (c.time_offset_s - truth.camera(c.name).time_offset_s)
        assert abs(err_ms) <= 3 * sig and abs(err_ms) < 0.2, (c.name, err_ms, sig)
