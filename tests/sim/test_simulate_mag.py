"""`--scene imu` for a rig that declares magnetometers writes mag/ along the same motion and
their truth (magnetometer.md), and the readings follow the model with the truth's values."""

from __future__ import annotations

import numpy as np
import yaml

from rigcal.core.rig import parse_rig
from rigcal.data.mag_csv import read_mag_csv
from rigcal.mag import model
from rigcal.sim.imu_scene import EPOCH_NS, simulate_motion_dataset
from rigcal.sim.mag_scene import EarthField

from tests.support.rig_blocks import IMU_BLOCK

RIG = """\
rig: small-imu-mag
""" + IMU_BLOCK + """\
magnetometers:
  mag0: {axes: [F, -L, -U], update_rate: 50.0, noise_density: 0.05}
cameras:
  front:
    model: pinhole
    resolution: [160, 120]
    intrinsics: {focal: 80.0}
    position: [0.1, 0.0, 0.0]
    axes: [-L, -U, F]
"""


def test_scene_imu_writes_mag_and_its_truth(tmp_path):
    res = simulate_motion_dataset(parse_rig(RIG), tmp_path / "d", duration=0.4, camera_rate=5.0, seed=2, jobs=1)
    truth = yaml.safe_load((res.out_dir / "truth.yaml").read_text())
    assert {"magnetometers", "earth_field", "imus", "boards"} <= set(truth)
    t = truth["magnetometers"]["mag0"]
    R_true = np.array(truth["rig"]["magnetometers"]["mag0"]["rotation"])
    assert 0.3 < np.degrees(np.arccos((np.trace(R_true @ np.diag([1.0, -1.0, -1.0])) - 1) / 2)) < 3.01
    s = read_mag_csv(res.out_dir / "mag" / "mag0.csv")
    assert len(s.t_ns) == 71  # 0.4 s plus the 0.5 s margins at 50 Hz, both ends included
    # noise-free readings from the truth along the trajectory match within the declared noise
    tt = (s.t_ns - EPOCH_NS) * 1e-9
    f = truth["earth_field"]
    b_world = EarthField(f["field_uT"], f["inclination_deg"], f["declination_deg"]).world()
    R_wb = res.trajectory.at(tt).R_world_body
    ideal = model.readings(np.einsum("nji,j->ni", R_wb, b_world), np.array(t["hard_iron_uT"]),
                           np.array(t["soft_iron"]), R_true)
    resid = s.m_uT - ideal
    assert np.abs(resid).max() < 5 * 0.05 * np.sqrt(50.0) and abs(resid.mean()) < 0.1
