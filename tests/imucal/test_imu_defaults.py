"""The camera-IMU defaults chosen from the data: the knot spacing from the IMU's own signal
(imu_start.choose_knot_spacing), the declared camera calibration's intrinsics held
(step.resolve_intrinsics), and the sigmas checked on the recording's halves
(step.inflated, subset_sigmas, state_window). Small and simulated; the end-to-end runs
are in test_calibrate_imu.py and the EuRoC figures in bench/imu_euroc.py."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.core import spline as spl
from rigcal.core.rig import Camera, Imu, Rig
from rigcal.imucal import residuals as ir
from rigcal.imucal import start as imu_start
from rigcal.imucal import step
from rigcal.sim import imu_model

RATE = 200.0
GYRO_DENSITY, ACCEL_DENSITY = 1.7e-4, 2.0e-3  # EuRoC's ADIS16448


def _imu(gyro_density: float = GYRO_DENSITY, accel_density: float = ACCEL_DENSITY) -> Imu:
    return Imu("imu0", np.eye(4), RATE, gyro_density, 1.9e-5, accel_density, 3e-3)


def _recording(freq_scale: float, seconds: float = 6.0, seed: int = 0):
    """(t, gyro, accel) of the simulator's hand-held motion with every frequency times
    freq_scale (1: the simulator's own, under 1 Hz; 6: a fast hand-waved recording)."""
    rng = np.random.default_rng(seed)
    traj = imu_model.hand_held_trajectory(rng)
    traj = replace(traj, pos_freq=traj.pos_freq * freq_scale, ang_freq=traj.ang_freq * freq_scale,
                   pos_amp=traj.pos_amp / freq_scale)  # the same accelerations, faster turns
    t = np.arange(0.0, seconds, 1.0 / RATE)
    s = imu_model.synthesize(traj.at(t), _imu(), rng)
    return s.t, s.gyro, s.accel


def _choose(t, gyro, accel, imu: Imu = _imu()):
    sg, sa = GYRO_DENSITY * np.sqrt(RATE), ACCEL_DENSITY * np.sqrt(RATE)
    return imu_start.choose_knot_spacing(t, gyro, accel, sg, sa, imu.update_rate)


# ----------------------------------------------------------------------------- knot spacing


def test_fit_ratio_of_white_noise_is_one_at_any_spacing():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 20.0, 1.0 / RATE)
    y = 0.3 * rng.standard_normal((len(t), 3))
    for dt in (0.05, 0.02, 0.01):
        assert imu_start.spline_fit_ratio(t, y, dt, 0.3) == pytest.approx(1.0, abs=0.03), dt


def test_fit_ratio_survives_a_gap_in_the_samples():
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 10.0, 1.0 / RATE)
    t = t[(t < 4.0) | (t > 4.3)]  # 0.3 s without samples: knots there are held by the ridge
    y = np.sin(t)[:, None] * np.ones(3) + 0.01 * rng.standard_normal((len(t), 3))
    assert imu_start.spline_fit_ratio(t, y, 0.05, 0.01) == pytest.approx(1.0, abs=0.05)


def test_slow_simulated_motion_keeps_the_coarsest_spacing():
    k = _choose(*_recording(1.0))
    assert k.knot_dt == imu_start.KNOT_CANDIDATES_S[0]
    assert max(k.tried[-1][1:]) <= imu_start.KNOT_TARGET
    assert "0.05 s" in k.line()


def test_fast_motion_gets_a_finer_spacing_that_fits_the_noise():
    t, g, a = _recording(6.0)
    k = _choose(t, g, a)
    assert k.knot_dt < imu_start.KNOT_CANDIDATES_S[0]
    dt, rg, ra = k.tried[-1]
    assert dt == k.knot_dt and max(rg, ra) <= imu_start.KNOT_TARGET
    # and the spacing before it did not: the coarsest that fits
    assert max(k.tried[-2][1:]) > imu_start.KNOT_TARGET


def test_noise_declared_too_low_stops_where_refining_stops_paying():
    t, g, a = _recording(1.0)
    sg, sa = GYRO_DENSITY * np.sqrt(RATE), ACCEL_DENSITY * np.sqrt(RATE)
    # declared 4x lower than the sensor's: no spacing fits within 1.5x
    k = imu_start.choose_knot_spacing(t, g, a, sg / 4, sa / 4, RATE)
    assert k.knot_dt == imu_start.KNOT_CANDIDATES_S[0]
    assert "little better" in k.reason
    assert min(max(r[1:]) for r in k.tried) > imu_start.KNOT_TARGET


def test_never_finer_than_two_samples_per_knot():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 5.0, 1.0 / 100.0)  # 100 Hz: 0.02 s at the finest
    y = 5.0 * rng.standard_normal((len(t), 3))  # far above the declared noise at every spacing
    k = imu_start.choose_knot_spacing(t, y, y, 0.01, 0.01, 100.0)
    assert k.knot_dt >= 0.02 - 1e-12


# ----------------------------------------------------------------------------- intrinsics


def _rig(calibrated: bool) -> Rig:
    from rigcal.core.camera import CameraModel

    m = CameraModel("pinhole", 640, 480, 300.0, 300.0, 320.0, 240.0, (0.0, 0.0, 0.0, 0.0, 0.0))
    cal = {"sigma": {"intrinsics": {"fx": 0.1, "fy": 0.1, "cx": 0.2, "cy": 0.2}}} if calibrated else None
    cams = tuple(Camera(n, m, np.eye(4), calibration=cal) for n in ("a", "b"))
    return Rig("r", cams)


def test_auto_holds_the_intrinsics_of_a_camera_calibration():
    assert step.resolve_intrinsics("auto", _rig(True)) == ("held", True)
    assert step.resolve_intrinsics("auto", _rig(False)) == ("joint", False)
    assert step.resolve_intrinsics("joint", _rig(True)) == ("joint", False)
    assert step.resolve_intrinsics("held", _rig(False)) == ("held", False)


def test_one_uncalibrated_camera_is_not_a_camera_calibration():
    r = _rig(True)
    r = replace(r, cameras=(r.cameras[0], replace(r.cameras[1], calibration={"sigma": {"position_mm": [1, 1, 1]}})))
    assert not step.is_camera_calibration(r)


# ----------------------------------------------------------------------------- subset sigmas


def test_inflated_known_answer():
    formal = np.array([1.0, 1.0, 2.0])
    # halves agree to within their sigma: the formal ones stand
    assert np.allclose(step.inflated(formal, np.array([0.5, -1.0, 2.0])), formal)
    # 6, 0, 0: |d| / 2 = 3 on the first; q = 9 is below chi2(3 dof) at p = 0.01 (11.34): the rest stand
    assert np.allclose(step.inflated(formal, np.array([6.0, 0.0, 0.0])), [3.0, 1.0, 2.0])
    # 10, 0, 0: q = 25 is beyond it: the group scaled by sqrt(25 / 3), the first at |d| / 2
    k = np.sqrt(25.0 / 3.0)
    assert np.allclose(step.inflated(formal, np.array([10.0, 0.0, 0.0])), [5.0, k, 2 * k])


def test_subset_sigmas_raise_only_what_the_halves_show_and_say_so():
    C = 2
    formal = {"pose": np.full((C, 6), 1e-3), "offset": np.full(C, 1e-4), "gyro_bias": np.ones(3),
              "accel_bias": np.ones(3), "line_delay": None, "scale": None,
              "intrinsics": [{"fx": 0.1, "fy": 0.1, "cx": 0.0, "cy": 0.0, "distortion": []} for _ in range(C)]}
    d_rot = np.zeros((C, 3))
    d_rot[1, 0] = 8e-3  # camera 1's rotation: halves 8 formal sigmas apart
    d_intr = np.zeros((C, 4))
    d_intr[0, 0] = 1.0  # camera 0's fx: 10 formal sigmas; cx, cy held (sigma 0)
    d_intr[0, 2] = 5.0  # a held value's difference is ignored
    diffs = (d_rot, np.zeros((C, 3)), np.zeros(C), None, d_intr)
    sig, factor = step.subset_sigmas(formal, diffs, np.array([True, True]))
    assert sig["pose"][1, 0] == pytest.approx(4e-3)  # |d| / 2
    assert np.allclose(sig["pose"][0], 1e-3) and np.allclose(sig["pose"][1, 3:], 1e-3)
    assert sig["intrinsics"][0]["fx"] == pytest.approx(0.5)
    assert sig["intrinsics"][0]["cx"] == 0.0 and sig["intrinsics"][1]["fx"] == pytest.approx(0.1)
    assert factor[1]["rotation"] == pytest.approx(4.0) and factor[0]["intrinsics"] == pytest.approx(5.0)
    assert formal["pose"][1, 0] == 1e-3  # the formal dict is left as it was
    check = step.SubsetCheck(*diffs, np.array([True, True]), formal, sig, factor, 1.0, 10.0)
    assert check.source(0) == check.source(1) == "subsets"
    assert step.intrinsics_warnings(check, ["a", "b"])[0].startswith("camera a: this recording determines")
    # a camera not compared keeps its formal sigmas
    sig2, factor2 = step.subset_sigmas(formal, diffs, np.array([True, False]))
    assert np.allclose(sig2["pose"][1], 1e-3) and factor2[1] == {}
    # the intrinsics' excess variance carried into the poses: camera 0's rotation about L
    # follows its fx by 0.01 rad/px; fx's sigma went 0.1 -> 0.5 px, so 0.24 px^2 more
    B = np.zeros((6 * C, 4 * C))
    B[1, 0] = 0.01
    sig3, factor3 = step.subset_sigmas(formal, diffs, np.array([True, True]), B)
    assert sig3["pose"][0, 1] == pytest.approx(np.sqrt(1e-6 + 1e-4 * 0.24))
    assert np.allclose(np.delete(sig3["pose"][0], 1), 1e-3) and np.allclose(sig3["pose"][1], sig["pose"][1])
    assert factor3[0]["rotation"] == pytest.approx(5.0)


def test_halves_differences_in_the_sigmas_axes():
    T = np.stack([np.eye(4), np.eye(4)])
    d = np.array([0.01, -0.02, 0.03])
    Ta = T.copy()
    Ta[0, :3, :3] = geo.R_from_rotvec(d[None])[0]
    Ta[1, :3, 3] = [0.001, 0.0, 0.0]
    spline = spl.Spline(0.0, 0.1, np.stack([np.eye(3)] * 6), np.zeros((6, 3)))
    st = ir.State(spline, np.eye(4), T, np.zeros(2), np.zeros(2), 0.0, 1.0, np.zeros((2, 3)), np.zeros((2, 3)),
                  np.eye(3))
    a = replace(st, T_body_cam=Ta, time_offset_s=np.array([1e-4, 0.0]))
    d_rot, d_pos, d_off, d_delay, d_intr = step.halves_differences(a, st, False, False)
    assert np.allclose(d_rot[0], d) and np.allclose(d_rot[1], 0)
    assert np.allclose(d_pos[1], [0.001, 0, 0]) and d_off[0] == pytest.approx(1e-4)
    assert d_delay is None and d_intr is None


def test_state_window_is_the_same_curve_there():
    rng = np.random.default_rng(4)
    n = 40
    R = geo.R_from_rotvec(0.3 * rng.standard_normal((n, 3)))
    spline = spl.Spline(1.0, 0.05, R, rng.standard_normal((n, 3)))
    st = ir.State(spline, np.eye(4), np.eye(4)[None], np.zeros(1), np.zeros(1), 0.5, 0.5,
                  rng.standard_normal((6, 3)), rng.standard_normal((6, 3)), np.eye(3))
    w = step.state_window(st, 1.4, 2.1)
    assert w.spline.t0 <= 1.4 and w.spline.t_end >= 2.1 and len(w.spline.p) < n
    t = np.linspace(1.4, 2.1, 57)
    a, b = spl.evaluate(spline, t), spl.evaluate(w.spline, t)
    assert np.allclose(a.R_world_body, b.R_world_body, atol=1e-12) and np.allclose(a.p_world, b.p_world, atol=1e-12)
    assert np.allclose(np.concatenate(ir.bias_values(st, t)), np.concatenate(ir.bias_values(w, t)), atol=1e-12)


def test_intrinsics_prior_block_known_answer():
    from rigcal.camcal.solve import Intrinsics

    spline = spl.Spline(0.0, 0.1, np.stack([np.eye(3)] * 6), np.zeros((6, 3)))
    intr = (Intrinsics("pinhole", np.array([300.0, 301.0, 320.0, 240.0, 0.1, 0.0, 0.0, 0.0, 0.0])),
            Intrinsics("pinhole", np.array([400.0, 400.0, 330.0, 250.0, 0.0, 0.0, 0.0, 0.0, 0.0])))
    st = ir.State(spline, np.eye(4), np.stack([np.eye(4)] * 2), np.zeros(2), np.zeros(2), 0.0, 1.0, np.zeros((2, 3)),
                  np.zeros((2, 3)), np.eye(3), intrinsics=intr)
    lay = ir.layout_for(st, frozenset({"imu_rot", "imu_pos", "line_delay", "scale"}))
    prior = (None, (np.array([399.0, 402.0, 330.0, 250.5]), np.array([0.5, 1.0, 2.0, 0.25])))
    b = ir.intrinsics_prior_block(st, lay, prior)
    assert b.r.shape == (1, 4) and np.allclose(b.r[0], [2.0, -2.0, 0.0, -2.0])
    assert np.allclose(b.J[0], np.diag([2.0, 1.0, 0.5, 4.0]))
    assert np.array_equal(b.cols[0], lay.intr_start(1) + np.arange(4))
    # a step along the block's Jacobian moves its residual exactly so (linear)
    dx = np.zeros(lay.size)
    dx[lay.intr_start(1):lay.intr_start(1) + 4] = [0.1, -0.2, 0.3, 0.05]
    b2 = ir.intrinsics_prior_block(ir.retract(st, lay, dx), lay, prior)
    assert np.allclose(b2.r[0] - b.r[0], b.J[0] @ [0.1, -0.2, 0.3, 0.05])
    held = ir.layout_for(st, frozenset({"imu_rot", "imu_pos", "line_delay", "scale", "intrinsics"}))
    assert np.all(ir.intrinsics_prior_block(st, held, prior).cols == -1)


def test_the_structure_is_freed_only_where_the_camera_only_step_left_motion_unmodelled():
    """Free-running images grouped as one instant, or a rolling shutter (declared or
    estimated): fx, fy, cx, cy each a parameter; a synchronised global-shutter recording
    keeps the camera-only step's tested structure."""
    from rigcal.camcal.solve import Intrinsics

    assert not step.motion_unmodelled({"a": 0.0, "b": 0.0}, False, None)
    assert not step.motion_unmodelled({"a": 0.0}, False, {})
    assert step.motion_unmodelled({"a": 0.0, "b": 3e-5}, False, None)  # declared, held
    assert step.motion_unmodelled({"a": 0.0}, True, None)  # --rolling-shutter
    assert step.motion_unmodelled({"a": 0.0}, False, {"a": {"1": 2}})  # grouped stems
    tied = Intrinsics("pinhole", np.array([300.0, 300.0, 320.0, 240.0, 0.01, -0.02, 0.0, 0.0]), True, True)
    free = step.free_structure((tied,))[0]
    assert not free.tie_focal and not free.hold_centre and np.array_equal(free.values, tied.values)
    assert free.basis().shape == (8, 8) and tied.basis().shape == (8, 5)
