"""Free-running cameras without an IMU (rigcal.imucal.visual_motion): a round trip on a
short free-running recording (`simulate --scene imu --free-running`, then the images only:
no imu/, a rig without IMUs) -> `calibrate` -> every camera's pose relative to the
reference camera and its clock offset against truth.yaml, within the reported sigmas; the
smoothness prior's Jacobian against differences of its residuals; the refusals where the
views cannot model the motion (one line)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core import geometry as geo
from rigcal.core import spline as spl
from rigcal.core.rig import load_rig
from rigcal.data.truth import load_truth
from rigcal.errors import CalibrationError
from rigcal.imucal import residuals as ir
from rigcal.imucal import visual_motion as vmo
from tests.support.recordings import small_imu_rig

runner = CliRunner()


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _without_imu(text: str) -> str:
    """The rig file with its `imus:` section removed."""
    return text[:text.index("imus:")] + text[text.index("cameras:"):]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("visual")
    rig = small_imu_rig(tmp)
    sim = tmp / "sim"
    r = _cli("simulate", rig, "--out", sim, "--scene", "imu", "--duration", 4, "--free-running", "--seed", 2,
             "--jobs", 1)
    assert r.exit_code == 0, r.output
    ds = tmp / "ds"  # the images only
    ds.mkdir()
    shutil.copytree(sim / "images", ds / "images")
    shutil.copy(sim / "target.yaml", ds / "target.yaml")
    (ds / "rig.yaml").write_text(_without_imu((sim / "rig.yaml").read_text()))
    out = tmp / "cal.yaml"
    r = _cli("calibrate", ds, "--out", out, "--jobs", 1, "--guided", "off")
    assert r.exit_code == 0, r.output
    return sim, out, r.output


def _relative_errors(est, truth, ref: str):
    """Per camera (rotation error rad (3,) about body axes, position error m (3,), offset
    error s) of its pose and clock relative to camera `ref`, the estimate's reference camera
    put on the true one's pose and clock."""
    A = truth.camera(ref).T_body_cam @ geo.inv_T(est.camera(ref).T_body_cam)
    out = {}
    for c in est.cameras:
        T, Tt = A @ c.T_body_cam, truth.camera(c.name).T_body_cam
        d_off = c.time_offset_s - (truth.camera(c.name).time_offset_s - truth.camera(ref).time_offset_s)
        out[c.name] = (geo.rotvec_from_R(T[:3, :3] @ Tt[:3, :3].T), T[:3, 3] - Tt[:3, 3], d_off)
    return out


@pytest.mark.slow
def test_the_images_really_are_free_running(run):
    sim, _, text = run
    stems = [{p.stem for p in (sim / "images" / c).glob("*.png")} for c in ("front_left", "front_right", "back")]
    assert not (stems[0] & stems[1]) and not (stems[0] & stems[2]) and not (stems[1] & stems[2])
    assert "without an IMU" in text and "own time" in text


def test_relative_poses_and_clock_offsets_against_truth_within_their_sigmas(run):
    sim, out, _ = run
    est, truth = load_rig(out), load_truth(sim / "truth.yaml").rig
    ref = est.calibration["free_running"]["clock"].split(":", 1)[1]
    errs = _relative_errors(est, truth, ref)
    for name, (d_rot, d_pos, d_off) in errs.items():
        sig = est.camera(name).calibration["sigma"]
        if name == ref:  # held: its sigmas are zero, its errors zero by construction
            assert sig["time_offset_ms"] == 0.0 and est.camera(name).time_offset_s == 0.0
            continue
        # the truth's offsets differ by milliseconds: the estimate must find them, not stay at 0
        assert abs(truth.camera(name).time_offset_s - truth.camera(ref).time_offset_s) > 1e-4
        assert np.all(np.abs(np.degrees(d_rot)) <= 3 * np.array(sig["rotation_deg"])), (name, np.degrees(d_rot), sig)
        assert np.all(np.abs(1000 * d_pos) <= 3 * np.array(sig["position_mm"])), (name, 1000 * d_pos, sig)
        assert abs(1000 * d_off) <= 3 * sig["time_offset_ms"], (name, 1000 * d_off, sig)
        # and the accuracy line: offsets within 0.1 ms
        assert abs(d_off) < 1e-4, (name, d_off)


def test_the_output_says_how(run):
    _, out, _ = run
    top = load_rig(out).calibration["free_running"]
    tried = top["knot_spacing_tried"]  # from the cameras' frame period (20 Hz) down
    assert tried[0][0] == pytest.approx(0.05, rel=0.2) and top["knot_spacing_s"] in [dt for dt, _ in tried]
    assert top["intrinsics"] == "estimated" and top["corner_rms_px"] < 0.5


# ----------------------------------------------------------------------------- pieces


def _spline(n: int = 12, dt: float = 0.05, seed: int = 0) -> spl.Spline:
    rng = np.random.default_rng(seed)
    R = geo.R_from_rotvec(np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0))
    return spl.Spline(0.0, dt, R, np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0))


def test_smoothness_prior_jacobian_matches_differences_of_its_residuals():
    sp_ = _spline()
    st = ir.State(spline=sp_, T_body_imu=np.eye(4), T_body_cam=np.eye(4)[None], time_offset_s=np.zeros(1),
                  line_delay_s=np.zeros(1), bias_t0=0.0, bias_dt=1.0, gyro_bias=np.zeros((2, 3)),
                  accel_bias=np.zeros((2, 3)), R_grav=np.eye(3))
    lay = ir.layout_for(st, vmo.HELD)
    J, r = ir.assemble(vmo.smoothness_blocks(st, lay, 2.0, 3.0), lay.size)
    J = J.toarray()
    h = 1e-6
    for col in list(range(0, 3 * len(sp_.p), 5)) + list(range(lay.pos, lay.pos + 3 * len(sp_.p), 5)):
        dx = np.zeros(lay.size)
        dx[col] = h
        rp = ir.assemble(vmo.smoothness_blocks(ir.retract(st, lay, dx), lay, 2.0, 3.0), lay.size)[1]
        dx[col] = -h
        rm = ir.assemble(vmo.smoothness_blocks(ir.retract(st, lay, dx), lay, 2.0, 3.0), lay.size)[1]
        assert np.allclose(J[:, col], (rp - rm) / (2 * h), atol=1e-5 * max(1.0, np.abs(J[:, col]).max())), col


def test_a_straight_line_at_constant_speed_has_no_knot_acceleration():
    n, dt = 10, 0.05
    R = geo.R_from_rotvec(np.arange(n)[:, None] * np.array([0.0, 0.0, 0.02]))
    p = np.arange(n)[:, None] * np.array([0.01, -0.02, 0.0])
    a, al = vmo.knot_accelerations(spl.Spline(0.0, dt, R, p))
    assert np.allclose(a, 0.0, atol=1e-12) and np.allclose(al, 0.0, atol=1e-9)


def _views(times: dict[int, np.ndarray]) -> vmo.Views:
    cams = np.concatenate([np.full(len(t), c) for c, t in times.items()])
    t = np.concatenate(list(times.values()))
    return vmo.Views(ir.Corners(cams, t, np.zeros((len(t), 2)), np.zeros((len(t), 3))), t, cams, 0)


def test_a_camera_never_in_step_with_another_is_refused():
    # front cameras 0-2 s and 3-5 s, `back` 2.1-2.85 s: never within a knot spacing of theirs
    grid = np.r_[np.arange(0, 2, 0.05), np.arange(3, 5, 0.05)]
    views = _views({0: grid, 1: grid + 0.01, 2: np.arange(2.1, 2.86, 0.05)})
    with pytest.raises(CalibrationError, match=r"camera back: only 0 of its 16 images .* or an IMU") as e:
        vmo.check_views(views, ["front_left", "front_right", "back"], 0.05)
    assert "\n" not in str(e.value)


def test_too_few_views_per_knot_are_refused():
    views = _views({0: np.arange(0, 4, 0.5), 1: np.arange(0, 4, 0.5) + 0.01})
    with pytest.raises(CalibrationError, match=r"per knot .* needs at least 1.5"):
        vmo.check_views(views, ["a", "b"], 0.05)


def test_knot_spacing_follows_the_slowest_camera():
    views = _views({0: np.arange(0, 2, 0.05), 1: np.arange(0, 2, 1 / 15)})
    assert vmo.knot_spacing(views, 2) == pytest.approx(1 / 15)


@pytest.mark.slow
def test_a_declared_camera_calibration_holds_the_intrinsics(run, tmp_path):
    # the two-recording workflow: a rig that is itself a calibration (its cameras carry
    # calibration.sigma.intrinsics) as --rig; here the first run's output stands in for it
    sim, first, _ = run
    ds = first.parent / "ds"
    out = tmp_path / "held.yaml"
    r = _cli("calibrate", ds, "--rig", first, "--out", out, "--jobs", 1, "--guided", "off")
    assert r.exit_code == 0, r.output
    est, given, truth = load_rig(out), load_rig(first), load_truth(sim / "truth.yaml").rig
    assert est.calibration["free_running"]["intrinsics"] == "held"
    for c in est.cameras:
        a, b = c.intrinsics, given.camera(c.name).intrinsics
        assert np.allclose([a.fx, a.fy, a.cx, a.cy, *a.dist], [b.fx, b.fy, b.cx, b.cy, *b.dist], rtol=0, atol=1e-9)
    ref = est.calibration["free_running"]["clock"].split(":", 1)[1]
    for name, (d_rot, d_pos, d_off) in _relative_errors(est, truth, ref).items():
        assert abs(d_off) < 1e-4 and np.degrees(np.linalg.norm(d_rot)) < 0.05 and np.linalg.norm(d_pos) < 1e-3, name


@pytest.mark.slow
def test_views_that_cannot_model_the_motion_are_refused_by_calibrate(run, tmp_path, monkeypatch):
    # the recording's ~3 images per knot made too few by asking for 100: exit 1, one line, nothing written
    _, first, _ = run
    monkeypatch.setattr(vmo, "MIN_VIEWS_PER_KNOT", 100.0)
    out = tmp_path / "refused.yaml"
    r = _cli("calibrate", first.parent / "ds", "--out", out, "--jobs", 1, "--guided", "off")
    assert r.exit_code == 1, r.output
    line = r.output.strip().splitlines()[-1]
    assert line.startswith("rigcal: free-running cameras without an IMU:") and "per knot" in line, line
    assert "Traceback" not in r.output and not out.exists()


@pytest.mark.slow
def test_a_camera_linked_by_the_motion_alone_is_placed_within_its_sigmas(tmp_path):
    # projected corners (0.3 px), free-running at 20 Hz, no IMU: the back camera sees only a
    # board the front cameras never see, so its pose relative to them comes from the rig's
    # motion alone. The time-grouped start ties this back camera's fx = fy (the true ones are
    # 0.32 px apart); the continuous-time estimate frees them, else the front cameras land
    # 10 mm off along L relative to it, 8 reported sigmas
    from tests.support.imu_check_cases import record, true_rig

    truth = true_rig(100, 3.0)
    ds = record(truth, tmp_path / "ds", 10.0, 20.0, seed=0, free_running=True, with_imu=False)
    out = tmp_path / "cal.yaml"
    r = _cli("calibrate", ds, "--out", out, "--jobs", 1)
    assert r.exit_code == 0, r.output
    est = load_rig(out)
    ref = est.calibration["free_running"]["clock"].split(":", 1)[1]
    for name, (d_rot, d_pos, d_off) in _relative_errors(est, truth, ref).items():
        c = est.camera(name)
        assert c.calibration["intrinsics_model"]["focal"] == "fx,fy", name
        if name == ref:
            continue
        sig = c.calibration["sigma"]
        assert np.all(np.abs(np.degrees(d_rot)) <= 3 * np.array(sig["rotation_deg"])), (name, np.degrees(d_rot), sig)
        assert np.all(np.abs(1000 * d_pos) <= 3 * np.array(sig["position_mm"])), (name, 1000 * d_pos, sig)
        assert abs(1000 * d_off) <= 3 * sig["time_offset_ms"], (name, 1000 * d_off, sig)


def test_an_intrinsics_structure_the_user_chose_is_kept(tmp_path):
    # `--intrinsics square`: fx = fy stays in the continuous-time estimate (only `auto`'s choice is freed)
    from tests.support.imu_check_cases import record, true_rig

    ds = record(true_rig(101, 3.0), tmp_path / "ds", 4.0, 20.0, seed=1, free_running=True, with_imu=False)
    out = tmp_path / "cal.yaml"
    r = _cli("calibrate", ds, "--out", out, "--jobs", 1, "--intrinsics", "square")
    assert r.exit_code == 0, r.output
    est = load_rig(out)
    assert est.calibration["free_running"]["intrinsics"] == "estimated"
    for c in est.cameras:
        assert c.calibration["intrinsics_model"]["focal"] == "fx=fy", c.name
        assert c.intrinsics.fx == c.intrinsics.fy, c.name
