"""`rigcal check` on a camera-IMU rig: every camera's pose relative to the IMU and its clock
offset, tested against the rig. Known answers: a rig calibrated (camera-only, then
camera-IMU) from one 10 s recording of the true rig, then 6 s recordings of the true rig
unchanged, with front_right turned 0.2 deg about body U relative to the IMU, and with its
clock offset changed by 2 ms (tests/support/imu_check_cases: projected corners, no
rendering)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from rigcal.check import decide
from rigcal.cli import app
from rigcal.core.rig import load_rig
from tests.support.check_cases import documented_keys, json_keys
from tests.support import imu_check_cases as cases

runner = CliRunner()
CHANGED = "front_right"


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("checkimu")
    truth = cases.true_rig(1)
    rig = cases.calibrated_rig(truth, tmp, duration=10.0, seed=1000, camera_rate=20.0)
    recs = {"unchanged": truth, "turned": cases.changed_imu_rig(truth, CHANGED, rotate_deg=0.2, axis="U"),
            "clock": cases.changed_imu_rig(truth, CHANGED, offset_ms=2.0)}
    return {"rig": rig, "dir": tmp,
            **{k: cases.record(r, tmp / k, duration=6.0, camera_rate=20.0, seed=2000) for k, r in recs.items()}}


def check_json(rig, rec, *extra):
    r = runner.invoke(app, ["check", str(rig), str(rec), "--json", "--jobs", "1", *map(str, extra)])
    assert r.exit_code in (0, 1), r.output
    return r.exit_code, json.loads(r.stdout)


@pytest.mark.slow
def test_unchanged_rig_passes_against_the_imu(work):
    code, d = check_json(work["rig"], work["unchanged"])
    assert code == 0 and d["status"] == "ok", d
    # two tests per camera (pose relative to the IMU, clock offset); the camera-only
    # intrinsics and relative poses are not tested on a moving recording
    assert d["tests"] == 6
    for name, cam in d["cameras"].items():
        assert cam["status"] == "ok"
        imu = cam["imu"]
        assert imu["imu"] == "imu0" and imu["dof"] == 6 and imu["clock"]["dof"] == 1
        assert "pose" not in cam and "intrinsics" not in cam
        assert all(s > 0 for s in imu["rotation_sigma_deg"] + imu["translation_sigma_mm"])
        # the IMU's axes are the body's, so the covariance is diagonal and the smallest
        # detectable change per axis is sqrt(noncentrality) sigmas
        lam6 = decide.noncentrality(6, d["level_per_test"]) ** 0.5
        lam1 = decide.noncentrality(1, d["level_per_test"]) ** 0.5
        for det, sig in zip(imu["detectable_rotation_deg"], imu["rotation_sigma_deg"]):
            assert det == pytest.approx(lam6 * sig, rel=2e-3)
        assert imu["clock"]["detectable_ms"] == pytest.approx(lam1 * imu["clock"]["sigma_ms"], rel=2e-3)
    assert any("against imu0" in n for n in d["notes"])
    assert {k for k in documented_keys() if k.startswith("imu")} <= json_keys(d)


@pytest.mark.slow
def test_camera_turned_relative_to_the_imu_is_moved_with_its_size(work, tmp_path):
    update = tmp_path / "fixed.yaml"
    code, d = check_json(work["rig"], work["turned"], "--update", update)
    assert code == 1 and d["changed"] == [CHANGED], d
    imu = d["cameras"][CHANGED]["imu"]
    assert d["cameras"][CHANGED]["status"] == "moved" and imu["changed"] and not imu["clock"]["changed"]
    assert abs(imu["rotation_deg"][2] - 0.2) <= 2 * imu["rotation_sigma_deg"][2]
    assert abs(imu["rotation_deg"][0]) <= 3 * imu["rotation_sigma_deg"][0]
    assert d["cameras"][CHANGED]["update"].endswith("pose relative to imu0")
    assert d["cameras"]["back"]["update"] == "kept"
    old, new = load_rig(work["rig"]), load_rig(update)
    assert (new.camera("back").T_body_cam == old.camera("back").T_body_cam).all()
    assert new.camera(CHANGED).calibration["updated"]["status"] == "moved"
    code, d = check_json(update, work["turned"])
    assert code == 0, d  # the updated rig fits the recording it was updated from


@pytest.mark.slow
def test_changed_clock_offset_is_flagged_with_its_size(work, tmp_path):
    report = tmp_path / "clock.html"
    code, d = check_json(work["rig"], work["clock"], "--report", report)
    assert code == 1 and d["changed"] == [CHANGED], d
    cam = d["cameras"][CHANGED]
    clock = cam["imu"]["clock"]
    assert cam["status"] == "clock changed" and clock["changed"] and not cam["imu"]["changed"]
    assert abs(clock["offset_change_ms"] - 2.0) <= 2 * clock["sigma_ms"]
    page = report.read_text()
    assert "Cameras against the IMU" in page and f"{clock['offset_change_ms']:+.3f}" in page


def test_rig_without_camera_imu_calibration_is_checked_camera_to_camera(work, tmp_path):
    """The same rig with its clock-offset sigmas removed is not a camera-IMU calibration:
    the recording's imu/ is left out, and the output says so."""
    text = work["rig"].read_text()
    plain = tmp_path / "plain.yaml"
    plain.write_text("\n".join(ln for ln in text.splitlines() if "time_offset_ms:" not in ln) + "\n")
    r = runner.invoke(app, ["check", str(plain), str(work["unchanged"]), "--json", "--jobs", "1"])
    assert r.exit_code in (0, 1), r.output
    d = json.loads(r.stdout)
    assert all("imu" not in c for c in d["cameras"].values())
    assert any("not a camera-IMU calibration" in n for n in d["notes"])


def test_recording_without_the_rigs_imu_file_is_refused_with_one_line(work, tmp_path):
    """imu/ without the csv of the IMU the rig was calibrated against: exit 2, one line on
    stderr naming the folder, nothing written."""
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(work["unchanged"], rec)
    (rec / "imu" / "imu0.csv").rename(rec / "imu" / "other.csv")
    out = tmp_path / "fixed.yaml"
    r = runner.invoke(app, ["check", str(work["rig"]), str(rec), "--jobs", "1", "--update", str(out)])
    assert r.exit_code == 2, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and "imu" in r.stderr
    assert not out.exists()
