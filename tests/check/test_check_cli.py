"""`rigcal check` end to end on small rendered recordings: an unchanged rig passes, a turned
camera is flagged as moved (that camera only), a changed focal length as intrinsics changed,
--update fixes it, and bad input exits 2 with one line and nothing written.

One rig calibrated from a 20-frame recording of the true rig (tests/support/check_cases),
checked against 8-frame recordings of it, unchanged or changed.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig
from tests.support.check_cases import RIG, calibrated_rig, changed_rig, documented_keys, json_keys, record, true_rig

FRAMES = 8


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("check")
    truth = true_rig(1)
    return {"dir": d, "truth": truth, "rig": calibrated_rig(truth, d, frames=20)}


def invoke(*args):
    return CliRunner().invoke(app, ["check", *map(str, args)])


def check_json(work, rec, *more):
    r = invoke(work["rig"], rec, "--json", "--jobs", 1, *more)
    assert r.exit_code in (0, 1), r.output
    return r.exit_code, json.loads(r.stdout)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_unchanged_rig_passes(work, seed):
    rec = record(work["truth"], work["dir"] / f"same{seed}", FRAMES, seed)
    code, d = check_json(work, rec)
    assert code == 0
    assert d["status"] == "ok"
    assert {n: c["status"] for n, c in d["cameras"].items()} == {n: "ok" for n in work["truth"].names}
    for c in d["cameras"].values():
        assert c["pose"]["statistic"] < c["pose"]["threshold"]
        assert max(c["pose"]["detectable_rotation_deg"]) < 0.1  # 8 frames still see a tenth of a degree
    # those of a check against the IMU and of --update: tests/check/test_check_imu.py
    assert {k for k in documented_keys() if not k.startswith(("imu", "update"))} <= json_keys(d)


@pytest.mark.slow
def test_turned_camera_is_flagged_as_moved_with_its_size(work):
    rec = record(changed_rig(work["truth"], "front_right", rotate_deg=0.5, axis="U"), work["dir"] / "turned", FRAMES,
                 13)
    report, update = work["dir"] / "turned.html", work["dir"] / "fixed.yaml"
    code, d = check_json(work, rec, "--report", report, "--update", update)
    assert code == 1
    cams = d["cameras"]
    assert cams["front_right"]["status"] == "moved"
    assert cams["front_left"]["status"] == "ok" and cams["back"]["status"] == "ok"
    p = cams["front_right"]["pose"]
    assert abs(p["rotation_deg"][2] - 0.5) < 3 * p["rotation_sigma_deg"][2] + 0.005
    assert sorted(p["relative_to"]) == ["back", "front_left"]
    assert d["changed"] == ["front_right"]
    html = report.read_text()
    assert "fig-check-0" in html and "front_right" in html
    # --update: the moved camera re-estimated, the rest held
    old, new = load_rig(work["rig"]), load_rig(update)
    np.testing.assert_array_equal(new.camera("front_left").T_body_cam, old.camera("front_left").T_body_cam)
    turn = geo.rotation_angle_deg(new.camera("front_right").T_body_cam[:3, :3]
                                  @ old.camera("front_right").T_body_cam[:3, :3].T)
    assert abs(turn - 0.5) < 0.01
    assert new.camera("front_right").calibration["updated"]["status"] == "moved"
    code, d = check_json({"rig": update}, rec)
    assert code == 0, d  # the updated rig fits the recording it was updated from


@pytest.mark.slow
def test_focal_change_is_flagged_as_intrinsics_changed(work):
    truth = work["truth"]
    rec = record(changed_rig(truth, "back", focal_rel=0.005), work["dir"] / "focal", FRAMES, 14)
    code, d = check_json(work, rec)
    assert code == 1
    cams = d["cameras"]
    assert cams["back"]["status"] == "intrinsics changed"
    assert cams["front_left"]["status"] == "ok" and cams["front_right"]["status"] == "ok"
    i = cams["back"]["intrinsics"]
    true_dfx = 0.005 * truth.camera("back").intrinsics.fx
    assert abs(i["change_px"]["fx"] - true_dfx) < 3 * i["sigma_px"]["fx"] + 0.02
    assert i["displacement_px"] > 0.5


@pytest.mark.slow
def test_camera_with_too_few_views_is_undetermined(work):
    src = record(work["truth"], work["dir"] / "few", FRAMES, 15)
    for p in sorted((src / "images" / "back").iterdir())[2:]:
        p.unlink()
    code, d = check_json(work, src)
    assert code == 0
    back = d["cameras"]["back"]
    assert back["status"] == "undetermined"
    assert "at least 3" in back["notes"][0]
    assert d["cameras"]["front_left"]["status"] == "ok"


def test_uncalibrated_rig_is_refused_with_one_line(work, tmp_path):
    rec = work["dir"] / "same11"
    if not rec.exists():
        record(work["truth"], rec, FRAMES, 11)
    out = tmp_path / "u.yaml"
    r = invoke(RIG, rec, "--update", out)
    assert r.exit_code == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "calibration.sigma" in lines[0] and "rigcal calibrate" in lines[0]
    assert not out.exists()


def test_recording_of_other_cameras_is_refused(work, tmp_path):
    rec = tmp_path / "other"
    shutil.copytree(work["dir"] / "same11" if (work["dir"] / "same11").exists()
                    else record(work["truth"], work["dir"] / "same11", FRAMES, 11), rec)
    (rec / "images" / "back").rename(rec / "images" / "down")
    report = tmp_path / "r.html"
    r = invoke(work["rig"], rec, "--report", report)
    assert r.exit_code == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "down" in lines[0] and "not in the rig" in lines[0]
    assert not report.exists()


def test_bad_level_is_refused(work):
    r = invoke(work["rig"], work["dir"], "--level", "0.7")
    assert r.exit_code == 2
    assert "--level" in r.stderr


@pytest.mark.slow
def test_camera_the_new_views_cannot_place_is_undetermined(work):
    """Seed 5's 8 frames never show the back camera a board the front pair sees, nor turn
    the rig enough to place it by its motion: back is undetermined, the pair still checked."""
    rec = record(work["truth"], work["dir"] / "unlinked", FRAMES, 5)
    code, d = check_json(work, rec)
    assert code == 0
    assert d["cameras"]["back"]["status"] == "undetermined"
    assert "cannot place it" in d["cameras"]["back"]["notes"][0]
    # its intrinsics are still tested, on its own views
    assert d["cameras"]["back"]["intrinsics"]["statistic"] < d["cameras"]["back"]["intrinsics"]["threshold"]
    assert "pose" not in d["cameras"]["back"]
    assert d["tests"] == 2 + 3  # the pair's two pose tests, three intrinsics tests
    assert d["cameras"]["front_left"]["status"] == "ok" and d["cameras"]["front_right"]["status"] == "ok"
    assert d["cameras"]["front_left"]["pose"]["relative_to"] == ["front_right"]


@pytest.mark.slow
def test_update_says_a_changed_camera_it_cannot_place_is_left_as_it_was(work, tmp_path):
    """Seed 5's recording with back's focal length 1 % longer (3 px): back's intrinsics,
    tested on its own views, have changed, but the new views cannot place it in the rig,
    so --update leaves it as it was and says so, per camera, in the JSON and on the console."""
    rec = record(changed_rig(work["truth"], "back", focal_rel=0.01), work["dir"] / "unlinked_focal", FRAMES, 5)
    out = tmp_path / "fixed.yaml"
    code, d = check_json(work, rec, "--update", out)
    assert code == 1 and d["cameras"]["back"]["status"] == "intrinsics changed", d
    assert d["cameras"]["back"]["update"].startswith("left as it was although it changed (intrinsics changed)")
    assert d["cameras"]["front_left"]["update"] == "kept" and d["cameras"]["front_right"]["update"] == "kept"
    old, new = load_rig(work["rig"]), load_rig(out)
    assert new.camera("back").intrinsics.fx == old.camera("back").intrinsics.fx
    assert "updated" not in new.camera("back").calibration
    r = invoke(work["rig"], rec, "--jobs", 1, "--update", tmp_path / "again.yaml")
    assert r.exit_code == 1
    assert "--update: back: left as it was although it changed" in " ".join(r.stdout.split())
