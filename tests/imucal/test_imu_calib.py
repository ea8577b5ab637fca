"""The camera-IMU estimator alone on synthetic corner recordings (imu_synthetic: the
`simulate --scene imu` truth, projected instead of rendered) against the truth."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.sim import imu_model
from rigcal.imucal import estimator as ic
from rigcal.imucal import residuals as ir
from rigcal.sim import imu_corners as isyn
from rigcal.errors import CalibrationError
from rigcal.core.rig import load_rig

RIG = Path(__file__).resolve().parents[2] / "rigs" / "drone-stereo-back-imu.yaml"
SIGMA_PX = 0.3


@pytest.fixture(scope="module")
def solved():
    rec = isyn.synthetic_recording(load_rig(RIG), duration=5.0, seed=1, sigma_px=SIGMA_PX)
    return rec, ic.calibrate_camera_imu(rec.cams, rec.obs, rec.imu, ic.Settings(sigma_px=SIGMA_PX))


def test_camera_imu_poses_and_offsets_against_truth(solved):
    rec, res = solved
    err = isyn.errors_against_truth(rec, res.T_imu_cam, res.time_offset_s)
    start = np.array([[geo.rotation_angle_deg(s.R_imu_cam.T @ (geo.inv_T(rec.truth.imus[0].T_body_imu)
                                                               @ c.T_body_cam)[:3, :3]), s.time_offset_s - c.time_offset_s]
                      for s, c in zip(res.starts, rec.truth.cameras)])
    assert np.all(err[:, 0] < 0.05)  # degrees
    assert np.all(err[:, 1] < 3e-3)  # metres (the declared translations start 5 mm off)
    assert np.all(np.abs(err[:, 2]) < 3e-4)  # seconds
    assert np.all(err[:, 0] < np.abs(start[:, 0]))  # the estimate improves on the start
    # errors within 4 sigma of what the estimator reports (declared noise = true noise here)
    sig_rot = np.degrees(np.linalg.norm(res.sigma[:, :3], axis=1))
    sig_pos = np.linalg.norm(res.sigma[:, 3:6], axis=1)
    assert np.all(err[:, 0] < 4 * sig_rot) and np.all(err[:, 1] < 4 * sig_pos)
    assert np.all(np.abs(err[:, 2]) < 4 * res.sigma[:, 6])
    assert np.all(res.sigma > 0)


def test_residuals_match_the_declared_noise_and_gravity_biases_are_found(solved):
    rec, res = solved
    for k in ("corners", "gyro", "accel"):
        assert 0.8 < res.normalised_rms[k] < 1.2, (k, res.normalised_rms)
    g_true = imu_model.G_WORLD  # the boards' world is the truth's world
    assert np.degrees(np.arccos(res.state.g_world @ g_true / np.linalg.norm(g_true) ** 2)) < 0.05
    bg, ba = ir.bias_values(res.state, rec.t_bias[(rec.t_bias > 1.0) & (rec.t_bias < 5.0)])
    keep = (rec.t_bias > 1.0) & (rec.t_bias < 5.0)
    assert np.abs(bg.mean(0) - rec.gyro_bias[keep].mean(0)).max() < 5e-4  # rad/s, true turn-on ~2e-3
    assert np.abs(ba.mean(0) - rec.accel_bias[keep].mean(0)).max() < 2e-2  # m/s^2, true ~5e-2


@pytest.mark.parametrize("still", [False, True], ids=["yaw-only", "yaw-only-no-translation"])
def test_one_axis_recording_is_refused(still):
    """Issue 18's degenerate recording: turning about one axis (with or without translation)
    is refused before any solve, naming the missing motion."""
    traj = imu_model.hand_held_trajectory(np.random.default_rng([0, 2]))
    amp = traj.ang_amp.copy()
    amp[1:] = 0.0  # yaw only
    traj = replace(traj, ang_amp=amp, pos_amp=np.zeros_like(traj.pos_amp) if still else traj.pos_amp)
    rec = isyn.synthetic_recording(load_rig(RIG), duration=4.0, seed=0, trajectory=traj)
    with pytest.raises(CalibrationError, match="fewer than two axes"):
        ic.calibrate_camera_imu(rec.cams, rec.obs, rec.imu)


def test_translation_free_recording_is_refused():
    traj = imu_model.hand_held_trajectory(np.random.default_rng([0, 2]))
    rec = isyn.synthetic_recording(load_rig(RIG), duration=4.0, seed=0,
                                   trajectory=replace(traj, pos_amp=np.zeros_like(traj.pos_amp)))
    with pytest.raises(CalibrationError, match="hardly accelerates"):
        ic.calibrate_camera_imu(rec.cams, rec.obs, rec.imu)


def test_problem_size_grows_linearly_with_length():
    rig = load_rig(RIG)
    nnz = []
    for duration in (2.0, 4.0):
        rec = isyn.synthetic_recording(rig, duration=duration, seed=0)
        state, _, use = ic.start_state(rec.cams, rec.imu, ic.Settings())
        lay = ir.layout_for(state)
        J, _ = ir.assemble([ir.gyro_block(state, lay, rec.imu.t[use], rec.imu.gyro[use], 1.0),
                            ir.reprojection_block(state, lay, rec.obs, [c.model for c in rec.cams], 1.0)], lay.size)
        nnz.append(((J.T @ J) != 0).nnz / lay.n_ctrl)
    assert nnz[1] < 1.3 * nnz[0]  # nonzeros of J^T J per knot stay constant: banded, not dense


def test_rolling_shutter_line_delay_is_estimated():
    """A 30 us/row rolling shutter on every camera, started from 0: the line delay is found,
    and holding it at 0 instead shifts the clock offset by about the mean row's delay and
    leaves the corners worse than their noise."""
    rig = load_rig(RIG)
    rig = replace(rig, cameras=tuple(replace(c, line_delay_s=3e-5) for c in rig.cameras))
    rec = isyn.synthetic_recording(rig, duration=4.0, seed=2, sigma_px=SIGMA_PX)
    cams = [replace(c, line_delay_s=0.0) for c in rec.cams]
    res = ic.calibrate_camera_imu(cams, rec.obs, rec.imu, ic.Settings(sigma_px=SIGMA_PX, line_delay=True))
    assert np.abs(res.state.line_delay_s - 3e-5).max() < 1e-6  # s/row (issue target 0.5 us at 30 s)
    err = isyn.errors_against_truth(rec, res.T_imu_cam, res.time_offset_s)
    assert np.all(err[:, 0] < 0.05) and np.all(np.abs(err[:, 2]) < 3e-4)
    assert res.normalised_rms["corners"] < 1.2
    held = ic.calibrate_camera_imu(cams, rec.obs, rec.imu, ic.Settings(sigma_px=SIGMA_PX))
    assert held.normalised_rms["corners"] > 1.15 * res.normalised_rms["corners"]
    assert np.abs(isyn.errors_against_truth(rec, held.T_imu_cam, held.time_offset_s)[:, 2]).max() > 1e-3


@pytest.mark.slow
def test_rendered_recording_end_to_end(tmp_path):
    """`simulate --scene imu` images (4 s, 10 Hz, 640x480) -> detected corners and PnP poses
    (tests.support.motion_inputs) -> the estimator, against truth.yaml's rig. Intrinsics and board
    poses from the truth."""
    from tests.support import motion_inputs as imu_dataset
    from rigcal.sim.imu_scene import simulate_motion_dataset

    rig = load_rig(RIG)
    sim = simulate_motion_dataset(rig, tmp_path / "ds", duration=4.0, camera_rate=10.0, seed=0, jobs=1)
    start_rig = replace(rig, cameras=tuple(replace(c, intrinsics=sim.truth.camera(c.name).intrinsics)
                                           for c in rig.cameras))
    cams, obs, imu = imu_dataset.motion_inputs(tmp_path / "ds", start_rig, sim.target, sim.T_world_board)
    assert all(len(c.t_cam) >= 35 for c in cams)  # PnP on (nearly) every one of the 40 frames
    res = ic.calibrate_camera_imu(cams, obs, imu, ic.Settings(sigma_px=0.1))
    err = isyn.errors_against_truth(sim, res.T_imu_cam, res.time_offset_s)
    assert np.all(err[:, 0] < 0.05) and np.all(err[:, 1] < 3e-3) and np.all(np.abs(err[:, 2]) < 3e-4), err
    for k in ("gyro", "accel"):
        assert 0.8 < res.normalised_rms[k] < 1.2, res.normalised_rms


def _start_problem(rig, duration: float, settings: ic.Settings):
    """(layout, J, r) of every block at the start state of a synthetic recording."""
    rec = isyn.synthetic_recording(rig, duration=duration, seed=0)
    state, _, use = ic.start_state(rec.cams, rec.imu, settings)
    lay = ir.layout_for(state)
    J, r = ir.assemble([ir.gyro_block(state, lay, rec.imu.t[use], rec.imu.gyro[use], 1e-2),
                        ir.accel_block(state, lay, rec.imu.t[use], rec.imu.accel[use], 1e-1),
                        ir.reprojection_block(state, lay, rec.obs, [c.model for c in rec.cams], 0.3),
                        ir.bias_prior_block(state, lay, 1e-3, 1e-2)], lay.size)
    return lay, J, r


def test_band_order_factor_solves_as_a_general_sparse_solver():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    lay, J, r = _start_problem(load_rig(RIG), 2.0, ic.Settings())
    H = (J.T @ J).tocsc()
    order = ic.band_order(lay)
    assert sorted(order) == list(range(lay.size))  # a permutation
    solve, act = ic.factor(H, order)
    H_act = H[act][:, act].tocsc()
    x = solve((J.T @ r)[act])
    x_ref = spla.spsolve(H_act, (J.T @ r)[act])
    assert np.abs(x - x_ref).max() < 1e-6 * np.abs(x_ref).max()
    assert np.abs(H_act @ x - (J.T @ r)[act]).max() < 1e-8 * np.abs(J.T @ r).max()
    assert set(act) == set(np.flatnonzero(H.diagonal() > 0)) and not sp.issparse(x)


def test_band_order_fill_per_knot_stays_constant_with_length():
    """The factorisation's fill per spline knot does not grow with the recording: the bias
    knots sit in the band next to the control points they touch. Placed after every control
    point (the arrow) each bias row filled in to the end of the recording, so the fill per
    knot grew with the length (EuRoC's 72 s: 1.02 s a factorisation, interleaved 0.17 s)."""
    import scipy.sparse.linalg as spla

    rig = load_rig(RIG)
    fill = []
    for duration in (4.0, 8.0):
        lay, J, _ = _start_problem(rig, duration, ic.Settings(bias_dt=0.5))
        assert lay.knots_per_bias == pytest.approx(10.0)
        H = (J.T @ J).tocsc()
        order = ic.band_order(lay)
        act = order[H.diagonal()[order] > 0]
        lu = spla.splu(H[act][:, act].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        fill.append((lu.L.nnz + lu.U.nnz) / lay.n_ctrl)
    assert fill[1] < 1.15 * fill[0], fill


def test_huber_loss_resists_gross_corner_outliers():
    """2 % of the corners moved by 20 px: least squares is pulled off, the Huber loss is not."""
    rec = isyn.synthetic_recording(load_rig(RIG), duration=4.0, seed=3, sigma_px=SIGMA_PX)
    rng = np.random.default_rng(7)
    bad = rng.random(len(rec.obs.cam)) < 0.02
    uv = rec.obs.uv.copy()
    uv[bad] += rng.choice([-20.0, 20.0], size=(int(bad.sum()), 2))
    obs = replace(rec.obs, uv=uv)
    plain = ic.calibrate_camera_imu(rec.cams, obs, rec.imu, ic.Settings(sigma_px=SIGMA_PX))
    robust = ic.calibrate_camera_imu(rec.cams, obs, rec.imu, ic.Settings(sigma_px=SIGMA_PX, huber=3.0))
    e_plain = isyn.errors_against_truth(rec, plain.T_imu_cam, plain.time_offset_s)
    e_robust = isyn.errors_against_truth(rec, robust.T_imu_cam, robust.time_offset_s)
    assert np.all(e_robust[:, 0] < 0.05) and np.all(e_robust[:, 1] < 3e-3) and np.all(np.abs(e_robust[:, 2]) < 3e-4)
    assert e_robust[:, 0].max() < 0.5 * e_plain[:, 0].max()


def test_start_bridges_a_gap_in_the_frames_with_the_gyroscope():
    """1.2 s without frames (the board out of view, as in EuRoC's recording): the start's
    rotations across the gap follow the integrated gyroscope, not the last pose."""
    from rigcal.core import spline as spl

    traj = imu_model.hand_held_trajectory(np.random.default_rng([0, 2]))
    rec = isyn.synthetic_recording(load_rig(RIG), duration=5.0, seed=0, trajectory=traj)
    lo, hi = 1.8, 3.0
    cams = []
    for c in rec.cams:
        keep = (c.t_cam + c.time_offset_guess_s < lo) | (c.t_cam > hi)
        cams.append(replace(c, t_cam=c.t_cam[keep], T_world_cam=c.T_world_cam[keep]))
    state, starts, _ = ic.start_state(cams, rec.imu, ic.Settings())
    t = np.linspace(lo + 0.2, hi - 0.2, 9)
    R_est = spl.evaluate(state.spline, t).R_world_body
    # the estimator's body is the declared IMU's frame; the truth's IMU is mounted off it
    R_true = traj.at(t).R_world_body @ rec.truth.imus[0].T_body_imu[:3, :3] @ rec.imu.T_body_imu[:3, :3].T
    err = [geo.rotation_angle_deg(a.T @ b) for a, b in zip(R_est, R_true)]
    swing = max(geo.rotation_angle_deg(R_true[0].T @ b) for b in R_true)
    assert swing > 5.0  # the rig does turn inside the gap: holding the last pose would be off by this
    assert max(err) < 0.5, err


def test_every_knot_is_observed_when_the_imu_starts_with_the_frames():
    """EuRoC's IMU starts 5 ms before its first frame: the spline (with its padding knots)
    must stay inside the IMU stream, frames too near its ends left out, so no control point
    is all but unobserved (one was, turned by 10^5 degrees a step, and LM crawled)."""
    rec = isyn.synthetic_recording(load_rig(RIG), duration=3.0, seed=2)
    t_first = min(c.t_cam.min() for c in rec.cams)
    k = rec.imu.t >= t_first - 0.005
    imu = replace(rec.imu, t=rec.imu.t[k], gyro=rec.imu.gyro[k], accel=rec.imu.accel[k])
    state, _, use = ic.start_state(rec.cams, imu, ic.Settings())
    assert state.spline.t0 >= imu.t[0] and state.spline.t_end <= imu.t[-1]
    keep = ic.frame_span(state, rec.obs)
    assert 0.9 * len(keep) < keep.sum() < len(keep)  # the first frames' corners are left out
    obs = rec.obs.subset(keep)
    lay = ir.layout_for(state)
    rate = np.sqrt(imu.update_rate)
    J, _ = ir.assemble([ir.gyro_block(state, lay, imu.t[use], imu.gyro[use], imu.gyroscope_noise_density * rate),
                        ir.accel_block(state, lay, imu.t[use], imu.accel[use], imu.accelerometer_noise_density * rate),
                        ir.reprojection_block(state, lay, obs, [c.model for c in rec.cams], SIGMA_PX)], lay.size)
    d = (J.T @ J).diagonal()
    for group in (lay.rot, lay.pos):
        g = d[group:group + 3 * lay.n_ctrl]
        assert g.min() > 1e-3 * np.median(g), (g.min(), np.median(g))


def test_last_iterations_blocks_reweighted_equal_a_fresh_evaluation(solved):
    """The estimate keeps its last residual blocks; re-weighted to another corner noise they
    give the Jacobian and residuals a fresh evaluation at that noise gives (what
    step.jacobian used to compute)."""
    rec, res = solved
    settings = replace(res.settings, sigma_px=SIGMA_PX * 1.7)
    lay = ir.layout_for(res.state, ic.held_groups(settings))
    fresh = ic.residual_blocks(res.state, lay, rec.obs.subset(res.corners_used), [c.model for c in rec.cams],
                               rec.imu, ic.imu_span(res.state.spline, rec.imu.t), settings)
    kept = ic.reweighted_blocks(res, settings)
    (J0, r0), (J1, r1) = (ir.assemble(ir.normal_rows(b), lay.size) for b in (fresh, kept))
    H0, H1 = (J0.T @ J0).toarray(), (J1.T @ J1).toarray()
    assert np.abs(H1 - H0).max() <= 1e-9 * np.abs(H0).max()
    assert np.allclose(J1.T @ r1, J0.T @ r0, rtol=1e-9, atol=1e-9 * np.abs(J0.T @ r0).max())
    assert np.isclose(sum(b.objective for b in kept), sum(b.objective for b in fresh), rtol=1e-9)
    # anything but the corner noise changed, or a robust loss: an evaluation is needed
    assert ic.reweighted_blocks(res, replace(settings, line_delay=True)) is None
    assert ic.reweighted_blocks(res, replace(settings, huber=3.0)) is None
    assert ic.reweighted_blocks(replace(res, blocks=()), settings) is None
    # blocks made on other corners than the result now says it used (outliers left out after)
    assert ic.reweighted_blocks(replace(res, corners_used=res.corners_used.copy()), settings) is None
    assert ic.reweighted_corners(replace(res, corners_used=res.corners_used.copy()), settings) is None


def _refine_with_and_without(solved, settings, monkeypatch, counted, shortcut: str):
    """(the refine() of `solved` with `settings` as it is, the same with the kept-blocks
    shortcut `shortcut` (an estimator function) returning None), after checking that the
    shortcut saves exactly one call of `counted` (module, function name) and nothing else:
    the same iterations and cost."""
    rec, res = solved
    models = [c.model for c in rec.cams]
    module, name = counted
    calls = []
    evaluate = getattr(module, name)
    monkeypatch.setattr(module, name, lambda *a, **k: calls.append(1) or evaluate(*a, **k))
    quick = ic.refine(res, models, rec.obs, rec.imu, settings, cost_tol=0.0)
    n_quick = len(calls)
    calls.clear()
    monkeypatch.setattr(ic, shortcut, lambda *a: None)
    fresh = ic.refine(res, models, rec.obs, rec.imu, settings, cost_tol=0.0)
    assert len(calls) == n_quick + 1 and quick.iterations == fresh.iterations
    assert np.isclose(sum(quick.costs.values()), sum(fresh.costs.values()), rtol=1e-9)
    return quick, fresh


def test_reweighted_refinement_starts_from_the_estimates_last_blocks(solved, monkeypatch):
    """refine() with only the corner noise changed (step.estimate's second pass) takes res's
    last blocks re-weighted as its first evaluation: one evaluation fewer, the same result
    as evaluating them afresh."""
    settings = replace(solved[1].settings, sigma_px=SIGMA_PX * 1.7)
    quick, fresh = _refine_with_and_without(solved, settings, monkeypatch, (ic, "residual_blocks"),
                                            "reweighted_blocks")
    for a, b in ((quick.state.T_body_cam, fresh.state.T_body_cam), (quick.time_offset_s, fresh.time_offset_s)):
        assert np.allclose(a, b, rtol=0, atol=1e-9)


def test_scale_misalignment_refit_starts_from_the_estimates_corner_block(solved, monkeypatch):
    """The IMU model's refit (scale-misalignment freed, step.calibrate_imu's test) takes res's
    last corner block as its first (the scale columns are no corner's) and evaluates only the
    IMU's blocks there: one corner evaluation fewer, the same fit as evaluating them afresh."""
    res = solved[1]
    settings = replace(res.settings, scale_misalignment=True)
    assert ic.reweighted_blocks(res, settings) is None and ic.reweighted_corners(res, settings) is not None
    quick, fresh = _refine_with_and_without(solved, settings, monkeypatch, (ir, "reprojection_rows"),
                                            "reweighted_corners")
    for a, b in ((quick.state.T_body_cam, fresh.state.T_body_cam), (quick.state.M_gyro, fresh.state.M_gyro),
                 (quick.state.M_accel, fresh.state.M_accel), (quick.time_offset_s, fresh.time_offset_s)):
        assert np.allclose(a, b, rtol=0, atol=1e-9)
