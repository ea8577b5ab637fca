"""`rigcal calibrate --report` on a dataset with images, imu/ and mag/: the camera report
gets the magnetometer section (the sphere and the heading error per magnetometer) at its end,
and the magnetometer's calibration there is the one the same imu/ + mag/ give alone."""

from __future__ import annotations

import shutil

import numpy as np
import yaml
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.rig import load_rig, parse_rig
from rigcal.sim.imu_scene import simulate_motion_dataset

from tests.support.mag_data import MAG_RIG, mag_dataset

# a forward pair whose 2 s motion calibrates the cameras (tests/sim/test_simulate_imu.py's
# --camera-only case), with the IMU and magnetometer of the shipped drone-imu-mag rig, whose
# compass dance (mag_dataset) gives the imu/ and mag/ files
CAMERAS = """\
front:
  model: pinhole
  resolution: [320, 240]
  intrinsics: {focal: 160.0}
  position: [0.1, 0.0, 0.0]
  axes: [-L, -U, F]
right:
  model: pinhole
  resolution: [320, 240]
  intrinsics: {focal: 160.0}
  position: [0.1, -0.1, 0.0]
  axes: [-L, -U, F]
"""
_SHIPPED = yaml.safe_load(MAG_RIG.read_text(encoding="utf-8"))
RIG = yaml.safe_dump({"rig": "pair-imu-mag", "body_frame": _SHIPPED["body_frame"], "imus": _SHIPPED["imus"],
                      "magnetometers": _SHIPPED["magnetometers"], "cameras": yaml.safe_load(CAMERAS)},
                     sort_keys=False)


def test_report_with_images_has_the_magnetometer_section(tmp_path):
    ds = tmp_path / "ds"
    simulate_motion_dataset(parse_rig(RIG), ds, duration=2.0, camera_rate=4.0, seed=1, jobs=2, rig_text=RIG)
    # the hand-held motion in front of the boards does not turn the rig through the sphere:
    # imu/ and mag/ from a compass dance on the same clock (both start at the scenes' epoch)
    dance = tmp_path / "dance"
    mag_dataset(dance, seed=1, duration=20.0)
    for f in ("imu/imu0.csv", "mag/mag0.csv"):
        shutil.copyfile(dance / f, ds / f)
    out, page = tmp_path / "cal.yaml", tmp_path / "report.html"
    r = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(out), "--report", str(page), "--camera-only",
                                 "--jobs", "1"])
    assert r.exit_code == 0, r.stderr
    assert "magnetometers" in r.stdout
    text = page.read_text()
    camera_part = text.index("front")
    assert "Magnetometer mag0" in text and text.index("Magnetometer mag0") > camera_part
    assert "mag0: readings on the sphere" in text and "mag0: heading error over the recording" in text
    assert text.count("plotly.js v") == 1 and text.rstrip().endswith("</html>")  # plotly.js inlined once
    # the same readings against the same declared IMU alone: the same calibration
    alone = tmp_path / "alone.yaml"
    r = CliRunner().invoke(app, ["calibrate", str(dance), "--out", str(alone)])
    assert r.exit_code == 0, r.stderr
    got, want = (load_rig(p).magnetometer("mag0").calibration for p in (out, alone))
    np.testing.assert_allclose(got["hard_iron_uT"], want["hard_iron_uT"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["soft_iron"], want["soft_iron"], rtol=0, atol=1e-12)
