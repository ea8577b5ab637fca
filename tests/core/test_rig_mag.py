"""Rig files with `magnetometers:` (../shared/spec/magnetometer.md): the shipped rig loads with
the pose it declares, files round-trip through the writer, each bad input is one stderr line
naming file, magnetometer and key (exit 2), and `rigcal view` draws magnetometers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.rig import dump_rig, load_rig, parse_rig, rig_to_dict
from rigcal.results.view import rig_figure

from tests.support.rig_blocks import IMU_BLOCK, assert_one_line_refusal

ROOT = Path(__file__).resolve().parents[2]
MAG_BLOCK = """\
magnetometers:
  mag0:
    position: [0.0, 0.0, 0.05]
    axes: [F, -L, -U]
    update_rate: 100.0
    noise_density: 0.05
    imu: imu0
    time_offset_s: 0.002
    earth_field_uT: 48.9
"""
CAMERAS = """\
cameras:
  cam0:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {focal: 300.0}
    position: [0.1, 0.0, 0.0]
    look: forward
"""
GOOD = "rig: t\n" + IMU_BLOCK + MAG_BLOCK + CAMERAS


def test_shipped_mag_rig_declares_an_frd_compass_on_a_mast():
    rig = load_rig(ROOT / "rigs" / "drone-imu-mag.yaml")
    (mag,) = rig.magnetometers
    np.testing.assert_allclose(mag.T_body_mag[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    np.testing.assert_allclose(mag.T_body_mag[:3, 3], [0.0, 0.0, 0.12])
    assert mag.sample_sigma_uT == pytest.approx(0.5)
    assert rig.mag_imu(mag).name == "imu0"


def test_valid_file_loads_and_round_trips():
    rig = parse_rig(GOOD, "good.yaml")
    mag = rig.magnetometer("mag0")
    assert (mag.imu, mag.time_offset_s, mag.earth_field_uT) == ("imu0", pytest.approx(0.002), pytest.approx(48.9))
    again = parse_rig(dump_rig(rig), "again.yaml")
    assert again == rig
    doc = rig_to_dict(again)
    assert list(doc)[:5] == ["rig", "body_frame", "imus", "magnetometers", "cameras"]
    assert {"rotation", "quaternion", "position"} <= set(doc["magnetometers"]["mag0"])
    assert rig != parse_rig(GOOD.replace("noise_density: 0.05", "noise_density: 0.06"))


def test_position_is_optional_and_the_imu_defaults_to_the_first():
    text = MAG_BLOCK.replace("    position: [0.0, 0.0, 0.05]\n", "").replace("    imu: imu0\n", "")
    rig = parse_rig("rig: t\n" + IMU_BLOCK + text + CAMERAS)
    mag = rig.magnetometers[0]
    np.testing.assert_array_equal(mag.T_body_mag[:3, 3], 0.0)
    assert mag.imu is None and rig.mag_imu(mag).name == "imu0"


def test_a_calibration_block_round_trips():
    rig = parse_rig(GOOD)
    block = {"hard_iron_uT": [1.0, 2.0, 3.0], "soft_iron": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
             "sigma": {"rotation_deg": [0.01, 0.02, 0.03]}}
    text = GOOD.replace("    earth_field_uT: 48.9\n", "    earth_field_uT: 48.9\n    calibration: " + str(block) + "\n")
    assert parse_rig(dump_rig(parse_rig(text))).magnetometers[0].calibration == block
    assert rig.magnetometers[0].calibration is None


BAD = {
    "look": (MAG_BLOCK.replace("axes: [F, -L, -U]", "look: forward"), "magnetometers.mag0.look", "no viewing"),
    "no_orientation": (MAG_BLOCK.replace("    axes: [F, -L, -U]\n", ""), "magnetometers.mag0", "missing orientation"),
    "zero_noise": (MAG_BLOCK.replace("noise_density: 0.05", "noise_density: 0"), "magnetometers.mag0.noise_density",
                   "positive"),
    "missing_noise": (MAG_BLOCK.replace("    noise_density: 0.05\n", ""), "magnetometers.mag0.noise_density",
                      "missing"),
    "missing_rate": (MAG_BLOCK.replace("    update_rate: 100.0\n", ""), "magnetometers.mag0.update_rate", "missing"),
    "unknown_imu": (MAG_BLOCK.replace("imu: imu0", "imu: imu7"), "magnetometers.mag0.imu", "imu0"),
    "field_in_nT": (MAG_BLOCK.replace("earth_field_uT: 48.9", "earth_field_uT: 48900"),
                    "magnetometers.mag0.earth_field_uT", "microtesla"),
    "offset_ms": (MAG_BLOCK.replace("time_offset_s: 0.002", "time_offset_s: 20"), "magnetometers.mag0.time_offset_s",
                  "within"),
    "name_clash_camera": (MAG_BLOCK.replace("  mag0:", "  cam0:"), "magnetometers.cam0", "also a camera"),
    "name_clash_imu": (MAG_BLOCK.replace("  mag0:", "  imu0:"), "magnetometers.imu0", "also an IMU"),
    "unknown_key": (MAG_BLOCK.replace("update_rate:", "rate_hz: 1\n    update_rate:"), "magnetometers.mag0.rate_hz",
                    "unknown key"),
    "bad_name": (MAG_BLOCK.replace("  mag0:", "  Mag-0:"), "magnetometers.Mag-0", "[a-z0-9_]+"),
    "empty": ("magnetometers: {}\n", "magnetometers", "non-empty mapping"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_mag_rig_is_one_line_exit_2(case, tmp_path):
    mags, key, expected = BAD[case]
    path = tmp_path / "bad.yaml"
    path.write_text("rig: t\n" + IMU_BLOCK + mags + CAMERAS)
    out = tmp_path / "rig.html"
    r = CliRunner().invoke(app, ["view", str(path), "--out", str(out)])
    assert_one_line_refusal(r, path, key, expected, out)


def test_a_magnetometer_needs_an_imu(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("rig: t\n" + MAG_BLOCK.replace("    imu: imu0\n", "") + CAMERAS)
    r = CliRunner().invoke(app, ["view", str(path), "--out", str(tmp_path / "v.html")])
    assert r.exit_code == 2 and "declare one under `imus:`" in r.stderr


def test_view_draws_each_magnetometer_axis_at_its_pose(tmp_path):
    rig = load_rig(ROOT / "rigs" / "drone-imu-mag.yaml")
    by_name = {t.name: t for t in rig_figure(rig).data}
    mag = rig.magnetometers[0]
    for i, axis in enumerate("xyz"):
        t = by_name[f"mag0 {axis}"]
        start, end = np.array([t.x[0], t.y[0], t.z[0]]), np.array([t.x[1], t.y[1], t.z[1]])
        np.testing.assert_allclose(start, mag.T_body_mag[:3, 3], atol=1e-12)
        np.testing.assert_allclose((end - start) / np.linalg.norm(end - start), mag.T_body_mag[:3, i], atol=1e-12)
    r = CliRunner().invoke(app, ["view", str(ROOT / "rigs" / "drone-imu-mag.yaml"), "--out", str(tmp_path / "v.html")])
    assert r.exit_code == 0 and "magnetometer(s): mag0" in r.stdout
