"""`rigcal calibrate` on a dance from an independent simulator (tests/support/indie_mag.py:
scipy's rotations, written from the contracts alone): the conventions (inclination sign,
clock offset direction, R_body_mag's direction, FLU/ENU) agree with rigcal's own."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.rig import load_rig

from tests.support.indie_mag import write_dance


def test_independent_dance_calibrates_to_its_truth(tmp_path):
    truth = write_dance(tmp_path / "d", seconds=40.0, seed=5, time_offset_s=0.012, declared_offset_s=0.0)
    out = tmp_path / "cal.yaml"
    r = CliRunner().invoke(app, ["calibrate", str(tmp_path / "d"), "--out", str(out)])
    assert r.exit_code == 0, r.stderr
    mag = load_rig(out).magnetometers[0]
    cal = mag.calibration
    rot_err = np.degrees(Rotation.from_matrix(mag.T_body_mag[:3, :3] @ truth["R_body_mag"].T).magnitude())
    assert rot_err < 0.15
    assert np.abs(np.array(cal["hard_iron_uT"]) - truth["hard_iron"]).max() < 0.15
    assert np.abs(np.array(cal["soft_iron"]) - truth["soft_iron"]).max() < 0.003
    assert abs(cal["inclination_deg"] - truth["inclination_deg"]) < 0.15
    assert abs(cal["field_uT"] - truth["field_uT"]) < 0.1
    assert abs(cal["time_offset_s"] - truth["time_offset_s"]) < 0.002  # the sign: t_imu = t_mag + offset
