"""`rigcal simulate --scene imu` (../shared/spec/imu.md): detected corners sit where the truth
pose at t_cam + time_offset_s (and, for a rolling shutter, each row's own time) projects
them; the files follow the contract (EuRoC IMU csv, integer-ns stems, truth.yaml additions,
full-precision truth_trajectory.csv); bytes are fixed by the seed whatever --jobs; the
motion-dataset checks refuse each bad input with one line and exit 2; a camera-only
calibration still runs on a motion dataset. Renders are small so this takes seconds."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.core import geometry as geo
from rigcal.cli import app
from rigcal.detect.detect import detect_image
from rigcal.errors import DatasetError
from rigcal.data.imu_csv import IMU_HEADER, read_imu_csv
from rigcal.core.rig import parse_rig, rig_from_dict
from rigcal.sim.imu_scene import EPOCH_NS, simulate_motion_dataset
from rigcal.core.target import load_target
from tests.support.rig_blocks import IMU_BLOCK

SMALL_RIG = """\
# two small cameras back to back; the back one has a rolling shutter (12 ms readout)
rig: small-imu
""" + IMU_BLOCK + """\
cameras:
  front:
    model: pinhole
    resolution: [320, 240]
    intrinsics: {focal: 160.0}
    position: [0.1, 0.0, 0.0]
    axes: [-L, -U, F]
  back:
    model: pinhole
    resolution: [320, 240]
    intrinsics: {focal: 160.0}
    position: [-0.1, 0.0, 0.0]
    axes: [L, -U, -F]
    line_delay_s: 5.0e-5
"""


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("imu") / "ds"
    res = simulate_motion_dataset(parse_rig(SMALL_RIG), out, duration=1.6, camera_rate=5.0, seed=3, jobs=1,
                                  rig_text=SMALL_RIG)
    return res


def _truth(out: Path):
    doc = yaml.safe_load((out / "truth.yaml").read_text())
    return doc, rig_from_dict(doc["rig"], "truth.yaml")


def _project_at(res, cam, board, ids, t_imu_s):
    """Pixels of board corners `ids` seen by `cam` (true) at IMU-clock times t_imu_s (N,)."""
    T_world_body = res.trajectory.at(t_imu_s).T_world_body
    bi = [b.name for b in res.target.boards].index(board)
    T_cam_board = geo.inv_T(T_world_body @ cam.T_body_cam) @ res.T_world_board[bi]
    p_board = res.target.boards[bi].corners[ids]
    p_cam = (T_cam_board[:, :3, :3] @ p_board[..., None])[..., 0] + T_cam_board[:, :3, 3]
    return cam.intrinsics.project(p_cam)[0]


def _corner_errors(res, truth_rig, cam_name):
    """(errors assuming a global shutter, errors with each corner's row time) in px, all views."""
    cam = truth_rig.camera(cam_name)
    gs, rs = [], []
    for path in res.image_paths[cam_name]:
        t_img = (int(path.stem) - EPOCH_NS) * 1e-9 + cam.time_offset_s
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        for board, ids, uv, _ in detect_image(gray, res.target):
            t = np.full(len(ids), t_img)
            gs.append(_project_at(res, cam, board, ids, t) - uv)
            for _ in range(3):  # the row a corner lands on depends on the time: a fixed point
                row = _project_at(res, cam, board, ids, t)[:, 1]
                t = t_img + np.clip(row, 0, cam.intrinsics.height - 1) * (cam.line_delay_s or 0.0)
            rs.append(_project_at(res, cam, board, ids, t) - uv)
    assert gs, f"no board detected in {cam_name}'s images"
    rms = lambda e: float(np.sqrt(np.mean(np.square(np.concatenate(e)))))  # noqa: E731
    return rms(gs), rms(rs)


def test_global_shutter_corners_sit_at_the_truth_pose_at_t_cam_plus_offset(sim):
    _, truth = _truth(sim.out_dir)
    gs, _ = _corner_errors(sim, truth, "front")
    assert gs <= 0.1, gs
    # and the clock offset matters: ignoring it moves the corners by much more
    cam = truth.camera("front")
    assert abs(cam.time_offset_s) > 1e-3


def test_ignoring_the_clock_offset_is_visibly_wrong(sim):
    _, truth = _truth(sim.out_dir)
    cam = truth.camera("front")
    shifted = truth.with_cameras([cam.__class__(cam.name, cam.intrinsics, cam.T_body_cam, time_offset_s=0.0)
                                  if c.name == "front" else c for c in truth.cameras])
    wrong, _ = _corner_errors(sim, shifted, "front")
    right, _ = _corner_errors(sim, truth, "front")
    assert wrong > 3 * right, (wrong, right)


def test_rolling_shutter_is_rendered_row_by_row(sim):
    _, truth = _truth(sim.out_dir)
    gs, rs = _corner_errors(sim, truth, "back")
    assert rs <= 0.15, rs
    assert gs > 4 * rs, (gs, rs)


def test_files_follow_the_contract(sim):
    out = sim.out_dir
    doc, truth = _truth(out)
    assert (out / "rig.yaml").read_text() == SMALL_RIG
    assert {c.name for c in truth.cameras} == {"front", "back"} and all(c.time_offset_s is not None
                                                                         for c in truth.cameras)
    assert truth.camera("back").line_delay_s == pytest.approx(5e-5)
    assert np.allclose(doc["gravity_world"], [0.0, 0.0, -9.80665], atol=0)
    stems = [sorted(int(p.stem) for p in (out / "images" / c).glob("*.png")) for c in ("front", "back")]
    assert stems[0] == stems[1] and len(stems[0]) == 8
    text = (out / "imu" / "imu0.csv").read_text()
    assert text.splitlines()[0] == IMU_HEADER
    samples = read_imu_csv(out / "imu" / "imu0.csv")
    stream = sim.streams["imu0"]
    np.testing.assert_array_equal(samples.gyro, stream.gyro)  # full double precision in the file
    np.testing.assert_array_equal(samples.accel, stream.accel)
    assert np.all(np.diff(samples.t_ns) == 5_000_000)
    assert samples.t_ns[0] <= stems[0][0] - 100_000_000 and samples.t_ns[-1] >= stems[0][-1] + 100_000_000
    bias = doc["imus"]["imu0"]["gyroscope_bias"]
    assert np.allclose(np.diff(bias["t_ns"]), 1e8) and len(bias["values"]) == len(bias["t_ns"])
    np.testing.assert_array_equal(np.array(bias["values"]), stream.gyro_bias[::20])
    traj = np.loadtxt(out / "truth_trajectory.csv", delimiter=",", comments="#")
    t_ns = np.loadtxt(out / "truth_trajectory.csv", delimiter=",", comments="#", usecols=0, dtype=np.int64)
    np.testing.assert_array_equal(t_ns, samples.t_ns)
    m = sim.trajectory.at((t_ns - EPOCH_NS) * 1e-9)
    np.testing.assert_allclose(traj[:, 1:4], m.p_world, atol=1e-15, rtol=0)
    R = np.stack([geo.R_from_quat(q) for q in traj[::50, 4:]])
    np.testing.assert_allclose(R, m.R_world_body[::50], atol=1e-14)


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_whatever_the_jobs(tmp_path):
    rig = parse_rig(SMALL_RIG)
    a = simulate_motion_dataset(rig, tmp_path / "a", duration=0.4, camera_rate=5.0, seed=7, jobs=1).out_dir
    b = simulate_motion_dataset(rig, tmp_path / "b", duration=0.4, camera_rate=5.0, seed=7, jobs=2).out_dir
    c = simulate_motion_dataset(rig, tmp_path / "c", duration=0.4, camera_rate=5.0, seed=8, jobs=1).out_dir
    assert _tree(a) == _tree(b)
    ta, tc = _tree(a), _tree(c)
    assert ta.keys() == tc.keys() and all(ta[k] != tc[k] for k in ("imu/imu0.csv", "truth.yaml"))


def test_cli_refuses_bad_settings(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(SMALL_RIG)
    plain = tmp_path / "plain.yaml"
    plain.write_text(SMALL_RIG.split("imus:")[0] + "cameras:" + SMALL_RIG.split("cameras:")[1])
    cases = [([str(plain), "--scene", "imu"], "needs a rig that declares an IMU"),
             ([str(rig), "--scene", "imu", "--frames", "3"], "--frames"),
             ([str(rig), "--scene", "imu", "--exposure", "0.5"], "--exposure"),
             ([str(rig), "--scene", "imu", "--duration", "0"], "--duration"),
             ([str(rig), "--scene", "imu", "--time-offset-ms", "500"], "--time-offset-ms"),
             ([str(rig), "--scene", "board", "--duration", "2"], "only used with --scene imu")]
    for args, expected in cases:
        out = tmp_path / "out"
        r = CliRunner().invoke(app, ["simulate", *args, "--out", str(out)])
        assert r.exit_code == 2, (args, r.stdout, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and expected in r.stderr, r.stderr
        assert not out.exists()


# ----------------------------------------------------------------------------- dataset checks


def _copy(sim, tmp_path) -> Path:
    d = tmp_path / "ds"
    shutil.copytree(sim.out_dir, d)
    return d


def _edit_csv(d: Path, row: int, new: str | None) -> Path:
    p = d / "imu" / "imu0.csv"
    lines = p.read_text().splitlines()
    if new is None:
        del lines[row - 1]
    else:
        lines[row - 1] = new
    p.write_text("\n".join(lines) + "\n")
    return p


def _row(d: Path, row: int) -> list[str]:
    return (d / "imu" / "imu0.csv").read_text().splitlines()[row - 1].split(",")


BAD_CSV = {
    "duplicate": (lambda d: _edit_csv(d, 5, ",".join(_row(d, 4))), "row 5", "repeats"),
    "backwards": (lambda d: _edit_csv(d, 6, ",".join([_row(d, 4)[0]] + _row(d, 6)[1:])), "row 6", "is before"),
    "text_cell": (lambda d: _edit_csv(d, 7, ",".join(_row(d, 7)[:3] + ["abc"] + _row(d, 7)[4:])), "row 7",
                  "column 4"),
    "columns": (lambda d: _edit_csv(d, 8, ",".join(_row(d, 8)[:6])), "row 8", "expected 7"),
    "float_stamp": (lambda d: _edit_csv(d, 9, ",".join(["1.5e18"] + _row(d, 9)[1:])), "row 9", "not an integer"),
}


def _calibrate(d: Path, tmp_path: Path, *extra: str):
    out = tmp_path / "cal.yaml"
    r = CliRunner().invoke(app, ["calibrate", str(d), "--out", str(out), "--jobs", "1", *extra])
    return r, out


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_imu_file_is_one_line_exit_2(case, sim, tmp_path):
    d = _copy(sim, tmp_path)
    edit, where, expected = BAD_CSV[case]
    path = edit(d)
    r, out = _calibrate(d, tmp_path)
    assert r.exit_code == 2, (r.stdout, r.stderr)
    line = r.stderr.strip()
    assert "\n" not in line and f"{path}: {where}: " in line and expected in line, line
    assert not out.exists()


def test_undeclared_and_missing_imu_files(sim, tmp_path):
    d = _copy(sim, tmp_path)
    shutil.copy(d / "imu" / "imu0.csv", d / "imu" / "imu9.csv")
    r, out = _calibrate(d, tmp_path)
    assert r.exit_code == 2 and f"{d / 'imu' / 'imu9.csv'}: IMU 'imu9' is not declared" in r.stderr, r.stderr
    (d / "imu" / "imu9.csv").unlink()
    (d / "imu" / "imu0.csv").unlink()
    r, out = _calibrate(d, tmp_path)
    assert r.exit_code == 2 and f"{d / 'imu' / 'imu0.csv'}: missing" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not out.exists()


def test_non_integer_stem_and_no_overlap(sim, tmp_path):
    d = _copy(sim, tmp_path)
    first = sorted((d / "images" / "front").glob("*.png"))[0]
    for cam in ("front", "back"):
        (d / "images" / cam / first.name).rename(d / "images" / cam / "frame_a.png")
    r, out = _calibrate(d, tmp_path)
    assert r.exit_code == 2 and "frame_a.png: image stem 'frame_a' is not an integer" in r.stderr, r.stderr
    d2 = tmp_path / "late"
    shutil.copytree(sim.out_dir, d2)
    for cam in ("front", "back"):  # stems in microseconds instead of nanoseconds
        for p in (d2 / "images" / cam).glob("*.png"):
            p.rename(p.with_name(f"{int(p.stem) // 1000}.png"))
    r, out = _calibrate(d2, tmp_path)
    assert r.exit_code == 2 and "do not overlap" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_read_imu_csv_accepts_euroc_text(tmp_path):
    p = tmp_path / "data.csv"
    p.write_text(IMU_HEADER + "\n1403715273262142976,-0.0991,0.1382,0.0251,8.1125,-0.7929,-3.2669\n"
                 "1403715273267142912,-0.0984,0.1382,0.0244,8.0708,-0.7929,-3.3159\n")
    s = read_imu_csv(p)
    assert s.t_ns.tolist() == [1403715273262142976, 1403715273267142912]
    np.testing.assert_allclose(s.accel[1], [8.0708, -0.7929, -3.3159])
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))  # BOM and CRLF, as Windows writes
    assert read_imu_csv(p).t_ns.tolist() == s.t_ns.tolist()
    p.write_text(IMU_HEADER + "\n")
    with pytest.raises(DatasetError, match="at least 2 samples"):
        read_imu_csv(p)


@pytest.mark.slow
def test_camera_only_calibration_runs_on_a_motion_dataset(tmp_path):
    """--camera-only: stems are frame names, the IMU data are checked but not used, the IMU
    blocks are carried through and a note says so; --reference imu:NAME with it is refused.
    (Without the flag this 2 s recording is too short for the camera-IMU step: exit 1.)"""
    out = tmp_path / "ds"
    # a forward pair (the back camera of SMALL_RIG shares no view: linking it needs more motion)
    text = SMALL_RIG.replace("position: [-0.1, 0.0, 0.0]\n    axes: [L, -U, -F]", "position: [0.1, -0.1, 0.0]\n    "
                             "axes: [-L, -U, F]")
    assert text != SMALL_RIG
    simulate_motion_dataset(parse_rig(text), out, duration=2.0, camera_rate=4.0, seed=1, jobs=2, rig_text=text)
    r, cal = _calibrate(out, tmp_path)
    assert r.exit_code == 1 and "clock offset" in r.stderr and not cal.exists(), r.stderr
    r, cal = _calibrate(out, tmp_path, "--camera-only", "--reference", "imu:imu0")
    assert r.exit_code == 2 and "--camera-only" in r.stderr and not cal.exists(), r.stderr
    r, cal = _calibrate(out, tmp_path, "--camera-only")
    assert r.exit_code == 0, (r.stdout, r.stderr)
    assert "--camera-only: the IMU data are not used" in r.stderr and "reference is `aligned`" in r.stderr
    calibrated = yaml.safe_load(cal.read_text())
    assert list(calibrated["imus"]) == ["imu0"]
    declared = parse_rig(text)
    np.testing.assert_allclose(np.array(calibrated["imus"]["imu0"]["rotation"]), declared.imus[0].T_body_imu[:3, :3],
                               atol=1e-15)
    shutil.rmtree(out / "imu")
    r, cal = _calibrate(out, tmp_path)
    assert r.exit_code == 0 and "reference is `aligned`" in r.stderr, r.stderr
    assert load_target(out / "target.yaml").boards


def test_a_gap_in_the_imu_stream_is_reported(sim, tmp_path):
    from rigcal.data.dataset import list_dataset
    from rigcal.data.imu_csv import check_motion_dataset

    d = _copy(sim, tmp_path)
    p = d / "imu" / "imu0.csv"
    lines = p.read_text().splitlines()
    p.write_text("\n".join(lines[:20] + lines[30:]) + "\n")  # 10 samples (50 ms) missing
    rig = parse_rig(SMALL_RIG)
    check = check_motion_dataset(d, rig, list_dataset(d, rig))
    assert len(check.notes) == 1 and "1 gap(s) longer than 5 samples, the longest 0.055 s" in check.notes[0]
    assert check.image_t_ns["front"][0] == int(sorted(p.stem for p in (d / "images" / "front").glob("*.png"))[0])
    intact = check_motion_dataset(sim.out_dir, rig, list_dataset(sim.out_dir, rig))
    assert intact.notes == ()


def test_images_outside_the_imu_stream_are_refused(tmp_path):
    from rigcal.errors import InputError

    delay = "    line_delay_s: 5.0e-5\n"
    rig = parse_rig(SMALL_RIG.replace(delay, delay + "    time_offset_s: -0.6\n"))
    with pytest.raises(InputError, match="cameras.back: its clock offset"):
        simulate_motion_dataset(rig, tmp_path / "out", duration=0.4, camera_rate=5.0, jobs=1)
    assert not (tmp_path / "out").exists()


def test_a_declared_clock_offset_is_the_nominal_one():
    from rigcal.sim.imu_scene import true_rig_for_motion

    delay = "    line_delay_s: 5.0e-5\n"
    rig = parse_rig(SMALL_RIG.replace(delay, delay + "    time_offset_s: 0.25\n"))
    pert = {"mount_error_mm": 5.0, "mount_error_deg": 1.0, "focal_error": 0.02}
    truth = true_rig_for_motion(rig, 0, 10.0, pert)
    base = true_rig_for_motion(parse_rig(SMALL_RIG), 0, 10.0, pert)
    assert truth.camera("back").time_offset_s - base.camera("back").time_offset_s == pytest.approx(0.25, abs=1e-12)
    assert truth.camera("front").time_offset_s == base.camera("front").time_offset_s
    assert abs(base.camera("back").time_offset_s) <= 0.010
