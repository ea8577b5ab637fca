"""Rig files with `imus:` and per-camera clock keys (../shared/spec/imu.md): the shipped IMU
rigs load with the poses they declare, round-trip through the writer, and each bad input
is one stderr line naming file, IMU (or camera) and key, exit 2; `rigcal view` draws IMUs."""

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

CAMERAS = """\
cameras:
  cam0:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {focal: 300.0}
    position: [0.1, 0.0, 0.0]
    look: forward
    time_offset_s: 0.004
    line_delay_s: 2.0e-5
"""
GOOD = "rig: t\n" + IMU_BLOCK + CAMERAS


def test_shipped_imu_rig_declares_what_the_issue_asks():
    rig = load_rig(ROOT / "rigs" / "drone-stereo-back-imu.yaml")
    golden = load_rig(ROOT / "rigs" / "drone-stereo-back.yaml")
    assert rig.cameras == golden.cameras
    (imu,) = rig.imus
    assert imu.name == "imu0"
    np.testing.assert_allclose(imu.T_body_imu, np.eye(4), atol=0)
    np.testing.assert_allclose(imu.noise, (1.7e-4, 1.9e-5, 2.0e-3, 3.0e-3), rtol=1e-12)
    assert imu.update_rate == pytest.approx(200.0)


def test_frd_rig_maps_imu_axes_to_body_axes():
    imu = load_rig(ROOT / "rigs" / "drone-stereo-back-frd.yaml").imus[0]
    # FRD: IMU x forward, y right (-L), z down (-U) in body terms
    np.testing.assert_allclose(imu.T_body_imu[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-15)


def test_valid_file_loads_and_round_trips():
    rig = parse_rig(GOOD, "good.yaml")
    imu = rig.imu("imu0")
    np.testing.assert_allclose(imu.T_body_imu[:3, 3], [0.01, 0.02, -0.03])
    cam = rig.camera("cam0")
    assert cam.time_offset_s == pytest.approx(0.004)
    assert cam.line_delay_s == pytest.approx(2e-5)
    again = parse_rig(dump_rig(rig), "again.yaml")
    assert again == rig
    doc = rig_to_dict(again)
    assert list(doc)[:4] == ["rig", "body_frame", "imus", "cameras"]
    assert {"rotation", "quaternion", "position"} <= set(doc["imus"]["imu0"])


def test_round_trip_equality_sees_an_imu_change():
    rig = parse_rig(GOOD)
    other = parse_rig(GOOD.replace("update_rate: 200.0", "update_rate: 400.0"))
    assert rig != other
    assert rig != parse_rig(GOOD.replace("time_offset_s: 0.004", "time_offset_s: 0.005"))


def test_rig_without_imus_writes_no_new_keys():
    rig = load_rig(ROOT / "rigs" / "drone-stereo-back.yaml")
    text = dump_rig(rig)
    for key in ("imus", "time_offset_s", "line_delay_s"):
        assert key not in text


BAD = {
    "look": (IMU_BLOCK.replace("axes: [F, -L, -U]", "look: forward"), "imus.imu0.look", "no viewing direction"),
    "zero_noise": (IMU_BLOCK.replace("gyroscope_noise_density: 1.7e-4", "gyroscope_noise_density: 0"),
                   "imus.imu0.gyroscope_noise_density", "positive"),
    "negative_walk": (IMU_BLOCK.replace("accelerometer_random_walk: 3.0e-3", "accelerometer_random_walk: -1"),
                      "imus.imu0.accelerometer_random_walk", "positive"),
    "missing_noise": (IMU_BLOCK.replace("    gyroscope_random_walk: 1.9e-5\n", ""),
                      "imus.imu0.gyroscope_random_walk", "missing"),
    "slow_rate": (IMU_BLOCK.replace("update_rate: 200.0", "update_rate: 0.5"), "imus.imu0.update_rate",
                  "at least 1 Hz"),
    "not_orthonormal": (IMU_BLOCK.replace("axes: [F, -L, -U]", "axes: [F, L, L]"), "imus.imu0.axes", ""),
    "bad_rotation": (IMU_BLOCK.replace("axes: [F, -L, -U]", "rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 2]]"),
                     "imus.imu0.rotation", ""),
    "name_clash": (IMU_BLOCK.replace("  imu0:", "  cam0:"), "imus.cam0", "also a camera"),
    "no_pose": (IMU_BLOCK.replace("    position: [0.01, 0.02, -0.03]\n", ""), "imus.imu0", "missing pose"),
    "unknown_key": (IMU_BLOCK.replace("update_rate:", "rate_hz: 1\n    update_rate:"), "imus.imu0.rate_hz",
                    "unknown key"),
    "bad_name": (IMU_BLOCK.replace("  imu0:", "  Imu-0:"), "imus.Imu-0", "[a-z0-9_]+"),
    "empty": ("imus: {}\n", "imus", "non-empty mapping"),
    "line_delay_negative": (IMU_BLOCK, "cameras.cam0.line_delay_s", "per row"),
    "time_offset_text": (IMU_BLOCK, "cameras.cam0.time_offset_s", "expected a number"),
}
CAMERA_EDITS = {"line_delay_negative": ("line_delay_s: 2.0e-5", "line_delay_s: -1.0e-5"),
                "time_offset_text": ("time_offset_s: 0.004", "time_offset_s: soon")}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_imu_rig_is_one_line_exit_2(case, tmp_path):
    imus, key, expected = BAD[case]
    cams = CAMERAS.replace(*CAMERA_EDITS[case]) if case in CAMERA_EDITS else CAMERAS
    path = tmp_path / "bad.yaml"
    path.write_text("rig: t\n" + imus + cams)
    out = tmp_path / "rig.html"
    r = CliRunner().invoke(app, ["view", str(path), "--out", str(out)])
    assert_one_line_refusal(r, path, key, expected, out)


def test_view_draws_each_imu_axis_at_its_pose(tmp_path):
    rig = load_rig(ROOT / "rigs" / "drone-stereo-back-frd.yaml")
    fig = rig_figure(rig)
    by_name = {t.name: t for t in fig.data}
    imu = rig.imus[0]
    for i, axis in enumerate("xyz"):
        t = by_name[f"imu0 {axis}"]
        start = np.array([t.x[0], t.y[0], t.z[0]])
        end = np.array([t.x[1], t.y[1], t.z[1]])
        np.testing.assert_allclose(start, imu.T_body_imu[:3, 3], atol=1e-12)
        d = (end - start) / np.linalg.norm(end - start)
        np.testing.assert_allclose(d, imu.T_body_imu[:3, i], atol=1e-12)
    assert "imu0" in list(by_name["imu0 x"].text)
    r = CliRunner().invoke(app, ["view", str(ROOT / "rigs" / "drone-stereo-back-frd.yaml"), "--out",
                                 str(tmp_path / "v.html")])
    assert r.exit_code == 0 and "IMU(s): imu0" in r.stdout


@pytest.mark.parametrize("args", [["project", "--position", "0", "0", "0", "--heading", "0", "--point", "5", "0", "0"],
                                  ["export", "--format", "kalibr"], ["export", "--format", "opencv"],
                                  ["export", "--format", "ros"], ["export", "--format", "json"]],
                         ids=["project", "kalibr", "opencv", "ros", "json"])
def test_every_command_accepts_a_rig_with_imus(args, tmp_path):
    rig = ROOT / "rigs" / "drone-stereo-back-frd.yaml"
    extra = ["--out", str(tmp_path / "out")] if args[0] == "export" else []
    r = CliRunner().invoke(app, [args[0], str(rig), *args[1:], *extra])
    assert r.exit_code == 0, (r.stdout, r.stderr)
    plain = ROOT / "rigs" / "drone-stereo-back.yaml"
    if args[0] == "export":  # the cameras' export does not change with an IMU beside them
        r2 = CliRunner().invoke(app, [args[0], str(plain), *args[1:], "--out", str(tmp_path / "plain")])
        assert r2.exit_code == 0
        a, b = tmp_path / "out", tmp_path / "plain"
        files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file()) if a.is_dir() else [None]
        for f in files:
            ta = (a / f if f else a).read_text()
            tb = (b / f if f else b).read_text()
            if args[-1] == "json":  # JSON is the rig file's own form: the IMU and line delays are in it
                assert "imu0" in ta and "imu0" not in tb
            else:
                assert ta.replace("drone-stereo-back-frd", "drone-stereo-back") == tb
