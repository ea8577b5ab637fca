"""Solver tests on synthetic corners (no rendering): Jacobian vs finite differences, LM vs
scipy's least_squares, round trips against truth, outliers, disconnected rigs, chessboard flips."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

import rigcal
from rigcal.core import geometry as geo
from rigcal.results.compare import compare_rigs
from rigcal.camcal.pipeline import calibrate_views
from rigcal.core.observations import BoardView
from rigcal.errors import CalibrationError
from rigcal.camcal.solve import Intrinsics, Observations, Problem, State, levenberg_marquardt
from rigcal.sim.synthetic import grid_corners, room_scene, with_noise

from tests.support.synthetic_obs import central_jacobian, noisy_room, perturb


@pytest.fixture(scope="module")
def drone():
    return rigcal.load_rig("rigs/drone-stereo-back.yaml")


def _small_problem(rig, rng, n_frames=6, jitter=True):
    truth = perturb(rig, rng)
    sc = room_scene(truth, rng, n_frames=n_frames)
    views, corners = with_noise(sc.views, 0.1, rng), sc.corners
    names, boards = list(rig.names), list(corners)
    frames = sorted({v.frame for v in views})
    cam = np.concatenate([np.full(len(v.ids), names.index(v.camera)) for v in views])
    frame = np.concatenate([np.full(len(v.ids), frames.index(v.frame)) for v in views])
    board = np.concatenate([np.full(len(v.ids), boards.index(v.board)) for v in views])
    P = np.concatenate([corners[v.board][v.ids] for v in views])
    uv = np.concatenate([v.uv for v in views])
    obs = Observations(cam, frame, board, P, uv, np.zeros(len(cam), int))
    intr = [Intrinsics("pinhole", np.concatenate([[c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx,
                                                   c.intrinsics.cy], c.intrinsics.dist])) for c in truth.cameras]
    T_cb = np.array([geo.inv_T(c.T_body_cam) for c in truth.cameras])
    T_bw = np.array([geo.inv_T(sc.T_world_body[f]) for f in frames])
    state = State(intr, T_cb, T_bw, np.array([sc.T_world_board[b] for b in boards]))
    if jitter:  # start away from the truth so deltas are non-zero (tests the SO(3) left Jacobian)
        for T in (state.T_cam_body[1:], state.T_body_world, state.T_world_board[1:]):
            for k in range(len(T)):
                T[k, :3, :3] = geo.R_from_rotvec(rng.normal(0, 0.02, 3)) @ T[k, :3, :3]
                T[k, :3, 3] += rng.normal(0, 0.01, 3)
    return obs, state


def test_jacobian_matches_central_differences(drone):
    rng = np.random.default_rng(3)
    obs, state = _small_problem(drone, rng)
    pb = Problem(obs, state, gauge_cam=0, gauge_board=0)
    x = pb.x0() + rng.normal(0, 1e-2, pb.layout.size) * (np.abs(pb.x0()) > 10) + rng.normal(0, 0.05, pb.layout.size) * (np.abs(pb.x0()) <= 10)
    J = pb.jacobian(x).toarray()
    Jn = central_jacobian(pb.residuals, x)
    scale = np.abs(Jn).max(axis=0) + 1e-9
    assert np.max(np.abs(J - Jn) / scale) < 1e-5


def test_jacobian_pattern_built_once_serves_every_x(drone):
    """jacobian() builds its CSR pattern on the first call and only refills the values:
    at a second point it must equal a fresh problem's Jacobian, entry for entry."""
    rng = np.random.default_rng(8)
    obs, state = _small_problem(drone, rng)
    pb = Problem(obs, state, gauge_cam=0, gauge_board=0)
    pb.jacobian(pb.x0())
    x1 = pb.x0() + rng.normal(0, 1e-3, pb.layout.size)
    fresh = Problem(obs, state, gauge_cam=0, gauge_board=0).jacobian(x1)
    again = pb.jacobian(x1)
    assert (again != fresh).nnz == 0 and again.nnz == fresh.nnz
    coo = again.tocoo()
    assert len(set(zip(coo.row.tolist(), coo.col.tolist()))) == again.nnz  # no duplicate entries


def test_levenberg_marquardt_reaches_scipy_least_squares_minimum(drone):
    rng = np.random.default_rng(4)
    obs, state = _small_problem(drone, rng)
    pb = Problem(obs, state, gauge_cam=0, gauge_board=0)
    x_lm, _, converged = levenberg_marquardt(pb)
    ref = least_squares(pb.residuals, pb.x0(), jac=lambda x: pb.jacobian(x).toarray(), method="lm",
                        x_scale="jac", ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=2000)
    assert converged
    cost_lm = 0.5 * np.sum(pb.residuals(x_lm) ** 2)
    assert cost_lm <= ref.cost * (1 + 1e-9)
    # LM stops once a step lowers chi-square by < 1e-2 (levenberg_marquardt): what is left
    # must be a tiny fraction of each parameter's standard error, not a fixed number of digits
    J = pb.jacobian(ref.x).toarray()
    dof = J.shape[0] - J.shape[1]
    sd = np.sqrt(np.diag(np.linalg.inv(J.T @ J)) * 2 * ref.cost / dof)
    assert np.all(np.abs(x_lm - ref.x) < 0.01 * sd), np.max(np.abs(x_lm - ref.x) / sd)


def test_weighted_solve_is_least_squares_on_whitened_residuals_with_its_own_covariance(drone):
    """Corner weights (Observations.weight, inverse variances): the LM minimum is scipy's
    on sqrt(w) r; the reported sigma stays the unweighted RMS in px; the covariance is the
    weighted problem's, variance_factor (J^T W J)^-1."""
    from dataclasses import replace

    from rigcal.camcal.solve import bundle_adjust, camera_covariance

    rng = np.random.default_rng(5)
    obs, state = _small_problem(drone, rng)
    sigma = np.where(rng.random(len(obs)) < 0.3, 0.4, 0.1)  # 30 % of corners said four times noisier
    obs_w = replace(obs, weight=1.0 / sigma**2)
    pb = Problem(obs_w, state, gauge_cam=0, gauge_board=0)
    x_lm, _, converged = levenberg_marquardt(pb)
    sw = obs_w.sqrt_weights()
    ref = least_squares(lambda x: sw * pb.residuals(x), pb.x0(), jac=lambda x: sw[:, None] * pb.jacobian(x).toarray(),
                        method="lm", x_scale="jac", ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=2000)
    assert converged and 0.5 * np.sum((sw * pb.residuals(x_lm)) ** 2) <= ref.cost * (1 + 1e-9)
    res = bundle_adjust(obs_w, state, 0, 0)
    r = res.residuals
    dof = r.size - res.problem.layout.size
    assert res.sigma_px == pytest.approx(np.sqrt(np.sum(r ** 2) / dof))
    w_in = res.problem.obs.sqrt_weights()
    assert res.variance_factor == pytest.approx(np.sum((w_in * r.ravel()) ** 2) / dof)
    cov, _, cam_sl = camera_covariance(res)
    J = res.problem.jacobian(res.problem.x0()).toarray()
    full = res.variance_factor * np.linalg.inv(J.T @ (w_in[:, None] ** 2 * J))
    s1 = cam_sl[1]
    assert np.allclose(cov[s1, s1], full[s1, s1], rtol=1e-6)

def _noise_sample(rng, n, gamma, scale):
    """(s_det, r2) of n corners: detector sigmas spread 3x (log-normal), true 1-sigma
    scale * s_det^gamma, r2 = |r|^2 / 2 of Gaussian residuals of that sigma."""
    s_det = 0.01 * np.exp(rng.normal(0.0, 0.45, n))
    s_true = scale * s_det**gamma
    return s_det, np.sum(rng.normal(0.0, 1.0, (n, 2)) ** 2, axis=1) / 2 * s_true**2


@pytest.mark.parametrize("gamma, scale", [(0.5, 0.12), (1.0, 1.3), (0.0, 0.02)])
def test_noise_model_recovers_how_the_true_noise_follows_the_detector_sigma(gamma, scale):
    """fit_noise_model: gamma and scale of s_eff = scale * s_det^gamma from residuals;
    weights 1 / s_eff^2 span at most WEIGHT_RATIO_MAX; too few corners give no model."""
    from rigcal.camcal.solve import NOISE_MIN_CORNERS, WEIGHT_RATIO_MAX, fit_noise_model, noise_weights

    rng = np.random.default_rng(int(10 * gamma) + 3)
    s_det, r2 = _noise_sample(rng, 20000, gamma, scale)
    m = fit_noise_model(s_det, r2)
    assert m.gamma == pytest.approx(gamma, abs=0.06)
    s_mid = scale * np.median(s_det) ** gamma
    assert m.s_mid == pytest.approx(s_mid, rel=0.03)
    s_det[:10] = np.nan  # unknown sigma: the camera's median
    w = noise_weights(s_det, np.zeros(len(s_det), int), [m])
    assert w.max() / w.min() <= WEIGHT_RATIO_MAX * (1 + 1e-9)
    assert np.allclose(w[:10], 1 / m.sigma(np.array([m.s_ref])) ** 2)
    assert fit_noise_model(s_det[:NOISE_MIN_CORNERS - 1], r2[:NOISE_MIN_CORNERS - 1]) is None


def test_noise_model_does_not_follow_a_detector_sigma_that_tells_nothing():
    """Residuals independent of s_det: gamma near 0, weights nearly equal; a steeper
    dependence than s_det's own is clipped at gamma 1."""
    from rigcal.camcal.solve import fit_noise_model

    rng = np.random.default_rng(4)
    s_det, _ = _noise_sample(rng, 20000, 0.0, 1.0)
    r2 = _noise_sample(rng, 20000, 0.0, 0.05)[1]
    assert fit_noise_model(s_det, r2).gamma < 0.05
    r2_steep = np.sum(rng.normal(0.0, 1.0, (20000, 2)) ** 2, axis=1) / 2 * (50 * s_det**2) ** 2
    assert fit_noise_model(s_det, r2_steep).gamma == 1.0


def _heteroscedastic_room(drone, seed, base=0.05, spread=0.8, n_frames=12):
    """Room views of a perturbed drone rig whose corners each have their own noise
    (log-normal about `base` px, `spread` in log) and the detector's sigma says so
    (BoardView.sigma)."""
    rng = np.random.default_rng(seed)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.0, n_frames=n_frames)
    out = []
    for v in views:
        s = base * np.exp(rng.normal(0.0, spread, len(v.ids)))
        out.append(BoardView(v.camera, v.frame, v.board, v.ids, v.uv + rng.normal(0, 1, v.uv.shape) * s[:, None],
                          sigma=s))
    return truth, out, corners


@pytest.mark.slow
def test_corners_are_weighted_by_their_calibrated_sigma_and_the_covariance_stays_honest(drone):
    """weight_corners: the pipeline weights each camera's corners by its NoiseModel fitted on
    BoardView.sigma (gamma near 1: this sigma is right); without sigma, or by default,
    everything stays unweighted. Weighted,
    the pair errors come out smaller than unweighted (summed over seeds), and each
    camera's reported sigma still explains its errors."""
    from dataclasses import replace as _replace

    err_w, err_u, z = 0.0, 0.0, []
    for seed in (21, 22):
        truth, views, corners = _heteroscedastic_room(drone, seed)
        cal = calibrate_views(views, drone, corners, weight_corners=True)
        plain = calibrate_views([_replace(v, sigma=None) for v in views], drone, corners, weight_corners=True)
        assert cal.obs.weight is not None and plain.obs.weight is None
        assert all(m is not None and m.gamma > 0.8 for m in cal.noise_models)
        err_w += sum(e["rot_deg"] ** 2 for e in _pair_errors(cal.rig, truth).values())
        err_u += sum(e["rot_deg"] ** 2 for e in _pair_errors(plain.rig, truth).values())
        rel = compare_rigs(cal.rig, truth)["pairs"]
        for (a, b), e in rel.items():
            sa, sb = cal.stats[a].sigma_rotation_deg, cal.stats[b].sigma_rotation_deg
            z.append(e["rot_deg"] / np.sqrt(np.sum(sa**2) + np.sum(sb**2)))
    assert err_w < err_u
    assert max(z) < 3.0


@pytest.mark.slow
def test_weighted_solve_does_not_depend_on_where_the_solve_started(drone):
    """pipeline.weighted_solve is a function of the unweighted solve's inlier set: from two
    different starts (the calibration's own and one nudged off it) the same corners and
    the same rig to 1e-9 (an iterated rejection on weighted residuals could settle either
    side of a corner near its threshold)."""
    from rigcal.camcal.pipeline import weighted_solve
    from rigcal.camcal.solve import bundle_adjust

    truth, views, corners = _heteroscedastic_room(drone, 23)
    cal = calibrate_views(views, drone, corners)
    assert cal.obs.weight is None and cal.corner_sigma_detected is not None  # weighting is opt-in
    obs = cal.obs
    g = (cal.problem.gauge_cam, cal.problem.gauge_board, cal.problem.fix_intr)
    inliers = bundle_adjust(obs, cal.state, *g).inliers
    nudged = cal.state.copy()
    nudged.T_body_world[:, :3, 3] += 0.002
    res = []
    for start in (cal.state, nudged):
        r0 = bundle_adjust(obs, start, *g, inliers=inliers, max_rounds=0)
        res.append(weighted_solve(r0, obs, cal.corner_sigma_detected, *g)[0])
    assert np.array_equal(res[0].inliers, res[1].inliers) and not res[0].inliers.all()
    for c in range(len(drone.names)):
        d = res[0].state.T_cam_body[c] @ geo.inv_T(res[1].state.T_cam_body[c])
        assert geo.rotation_angle_deg(d[:3, :3]) < 1e-7 and np.linalg.norm(d[:3, 3]) < 1e-9


def _pair_errors(cal_rig, truth):
    return compare_rigs(cal_rig, truth)["pairs"]


def test_round_trip_non_overlapping_rig_within_noise(drone):
    """Front pair + back camera that never shares a view: every pair recovered to a few
    thousandths of a degree / tenths of a mm with 0.05 px corner noise, and the
    predicted sigmas explain the errors."""
    rng = np.random.default_rng(11)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=30)
    cal = calibrate_views(views, drone, corners)
    pairs = _pair_errors(cal.rig, truth)
    for (a, b), e in pairs.items():
        assert e["rot_deg"] < 0.03, (a, b, e)
        assert e["trans_mm"] < 1.0, (a, b, e)
    for n in drone.names:
        ct, cc = truth.camera(n).intrinsics, cal.rig.camera(n).intrinsics
        assert abs(cc.fx / ct.fx - 1) < 5e-4 and abs(cc.fy / ct.fy - 1) < 5e-4
        assert cal.stats[n].outliers < 0.005 * cal.stats[n].observations
    # sigma consistent with noise: residual sigma equals the simulated 0.05 px within 10 %
    assert abs(cal.sigma_px - 0.05) < 0.005
    # the body frame is aligned to the declared rig: every camera within the simulated mounting errors
    for n in drone.names:
        d = geo.inv_T(drone.camera(n).T_body_cam) @ cal.rig.camera(n).T_body_cam
        assert np.linalg.norm(d[:3, 3]) < 0.03 and geo.rotation_angle_deg(d[:3, :3]) < 5


def test_planted_outliers_are_rejected(drone):
    rng = np.random.default_rng(12)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=24)
    bad = []
    for k in rng.choice(np.arange(1, len(views)), 25, replace=False):  # view 0 is mirrored below
        v = views[k]
        uv = v.uv.copy()
        i = rng.integers(len(uv))
        uv[i] += rng.choice([-1, 1], 2) * rng.uniform(3, 15, 2)  # a wrong corner
        views[k] = BoardView(v.camera, v.frame, v.board, v.ids, uv)
        bad.append(k)
    # one view with its ids mirrored left-right: a whole wrong board
    v = views[0]
    nx = 10
    mirrored = (v.ids // nx) * nx + (nx - 1 - v.ids % nx)
    views[0] = BoardView(v.camera, v.frame, v.board, mirrored, v.uv)
    cal = calibrate_views(views, drone, corners)
    assert sum(s.outliers for s in cal.stats.values()) >= 25 + len(v.ids)  # corners and the mirrored view
    for (a, b), e in _pair_errors(cal.rig, truth).items():
        assert e["rot_deg"] < 0.03 and e["trans_mm"] < 1.0, (a, b, e)


def test_the_robust_pass_read_on_its_own_leaves_out_gross_errors(drone):
    """bundle_adjust's first stage is robust_pass; read on its own (provisional_result) it
    judges planted gross errors out once, and fits no better than the converged solve."""
    from rigcal.camcal.solve import bundle_adjust, provisional_result, robust_pass

    rng = np.random.default_rng(21)
    obs, state = _small_problem(drone, rng, n_frames=8)
    bad = rng.choice(len(obs), 12, replace=False)
    uv = obs.uv.copy()
    uv[bad] += rng.choice([-1, 1], (12, 2)) * rng.uniform(5, 20, (12, 2))
    obs = Observations(obs.cam, obs.frame, obs.board, obs.p_board, uv, obs.view)
    whole = bundle_adjust(obs, state, 0, 0)
    rp = robust_pass(obs, state, 0, 0)
    assert whole.history[0] == ("robust", rp.n_iterations) and not whole.inliers[bad].any()
    early = provisional_result(obs, rp, 0, 0)
    assert not early.inliers[bad].any() and early.inliers.sum() >= len(obs) - 20
    assert early.history == [("robust", rp.n_iterations)] and early.residuals.shape == (early.inliers.sum(), 2)
    # its residuals are the robust state's, no rounds: at least the converged solution's
    assert early.sigma_px >= whole.sigma_px * (1 - 1e-9)


def test_disconnected_camera_is_named(drone):
    rng = np.random.default_rng(13)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=20)
    # the back camera only ever sees a board no front camera sees, in frames of its own
    back = [BoardView(v.camera, "x" + v.frame, "lonely", v.ids, v.uv) for v in views if v.camera == "back"]
    front = [v for v in views if v.camera != "back"]
    corners = dict(corners, lonely=corners["b0"])
    with pytest.raises(CalibrationError, match=r"back: never in a frame with another camera"):
        calibrate_views(front + back, drone, corners)


def test_disconnected_message_names_the_stray_group_whoever_is_the_gauge():
    """When the gauge camera is the stray one (it has the most views), the pose graph
    reaches only it; the message must still blame it, not the pair that is linked."""
    from types import SimpleNamespace as V

    from rigcal.camcal.pose_graph import camera_groups, disconnected_message

    views = ([V(cam=c, frame=f, board=0) for f in range(5) for c in (0, 1)]
             + [V(cam=2, frame=10 + f, board=1) for f in range(9)])
    assert sorted(map(sorted, camera_groups(views, 4))) == [[0, 1], [2], [3]]
    names, boards = ["front_left", "front_right", "back", "down"], ["b0", "lonely"]
    for missing in ([0, 1, 3], [2, 3]):  # gauge = back, then gauge = front_left
        msg = disconnected_message(views, missing, names, boards)
        assert "back: never in a frame with another camera that sees a board" in msg
        assert "(lonely)" in msg and "down: no usable board views" in msg
        assert "front_left:" not in msg and "front_right:" not in msg
    views.append(V(cam=2, frame=3, board=1))  # back now shares frame 3 with the pair: one group
    assert sorted(map(sorted, camera_groups(views, 4))) == [[0, 1, 2], [3]]
    # a pair split from the main group is named as a pair
    pair = [V(cam=c, frame=f, board=0) for f in range(5) for c in (0, 1)] + \
           [V(cam=c, frame=10 + f, board=1) for f in range(5) for c in (2, 3)] + [V(cam=4, frame=1, board=0)]
    msg = disconnected_message(pair, [2, 3], names + ["up"], boards)
    assert "back: linked only to down; no frame or board is shared with front_left, front_right, up" in msg


def test_too_few_frames_suggests_fix_intrinsics(drone):
    rng = np.random.default_rng(14)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=20)
    back_frames = sorted({v.frame for v in views if v.camera == "back"})[:2]
    views = [v for v in views if v.camera != "back" or v.frame in back_frames]
    with pytest.raises(CalibrationError, match=r"back: boards detected in only 2 frame\(s\).*--fix-intrinsics"):
        calibrate_views(views, drone, corners)


def test_reference_camera_keeps_its_declared_pose(drone):
    rng = np.random.default_rng(15)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=20)
    cal = calibrate_views(views, drone, corners, reference="camera:back")
    assert np.allclose(cal.rig.camera("back").T_body_cam, drone.camera("back").T_body_cam, atol=1e-12)
    assert np.allclose(cal.stats["back"].sigma_position_mm, 0, atol=1e-9)


def test_rig_without_declared_poses_uses_first_camera_as_body(drone):
    rng = np.random.default_rng(16)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=20)
    bare = drone.with_cameras([rigcal.Camera(c.name, c.intrinsics, None) for c in drone.cameras])
    cal = calibrate_views(views, bare, corners)
    assert np.allclose(cal.rig.camera("front_left").T_body_cam, np.eye(4), atol=1e-12)
    # the same relative geometry as with declared poses: only the body frame differs
    # (accuracy against the noise is the business of the round-trip tests above)
    declared = calibrate_views(views, drone, corners)
    same = _pair_errors(cal.rig, declared.rig)
    for (a, b), e in _pair_errors(cal.rig, truth).items():
        assert same[(a, b)]["rot_deg"] < 1e-6 and same[(a, b)]["trans_mm"] < 1e-4, (a, b, same[(a, b)])
        assert e["rot_deg"] < 0.1 and e["trans_mm"] < 3.0, (a, b, e)


def _stereo_chessboard_views(rig, truth, rng, n_frames, corners, nx, ny, noise=0.05):
    views = []
    for f in range(n_frames):
        R = geo.R_from_rotvec(rng.normal(0, 0.35, 3)) @ geo.R_from_axes(["-L", "-U", "F"]).T @ np.diag([1, 1, 1])
        # board in front of the pair: board z points away from the cameras
        T_body_board = geo.make_T(geo.R_from_axes(["-L", "-U", "F"]) @ geo.R_from_rotvec(rng.normal(0, 0.3, 3)),
                                  [rng.uniform(0.8, 1.6), rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2)])
        T_body_board[:3, 3] -= T_body_board[:3, :3] @ corners.mean(0)
        del R
        for cam in truth.cameras:
            p = geo.transform(geo.inv_T(cam.T_body_cam) @ T_body_board, corners)
            uv, valid = cam.intrinsics.project(p)
            if not (valid & cam.intrinsics.in_image(uv)).all():
                continue
            views.append(BoardView(cam.name, f"{f:03d}", "chess", np.arange(len(corners)),
                                uv + rng.normal(0, noise, uv.shape), ambiguous=True))
    return views


def test_symmetric_chessboard_order_resolved_against_other_camera():
    rig = rigcal.load_rig("rigs/stereo-forward.yaml")
    rng = np.random.default_rng(17)
    truth = perturb(rig, rng)
    nx, ny = 7, 5  # 8 x 6 squares: 180-degree symmetric
    corners = grid_corners(nx, ny, 0.06)
    views = _stereo_chessboard_views(rig, truth, rng, 16, corners, nx, ny)
    flipped = 0
    for k, v in enumerate(views):
        if v.camera == rig.names[1] and k % 3 == 0:  # detector returned the reverse order
            views[k] = BoardView(v.camera, v.frame, v.board, v.ids, v.uv[::-1].copy(), ambiguous=True)
            flipped += 1
    assert flipped >= 3
    cal = calibrate_views(views, rig, {"chess": corners})
    assert cal.flips == flipped or cal.flips == len([v for v in views if v.camera == rig.names[1]]) - flipped
    e = _pair_errors(cal.rig, truth)[tuple(rig.names)]
    assert e["rot_deg"] < 0.05 and e["trans_mm"] < 0.5, e


def test_fisheye_pair_round_trip():
    rig = rigcal.load_rig("rigs/fisheye-stereo.yaml")
    rng = np.random.default_rng(18)
    truth = perturb(rig, rng, focal=0.01)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=20, board=(8, 6, 0.2), dist=1.5)
    cal = calibrate_views(views, rig, corners)
    e = _pair_errors(cal.rig, truth)[tuple(rig.names)]
    assert e["rot_deg"] < 0.05 and e["trans_mm"] < 1.0, e
    for n in rig.names:
        assert abs(cal.rig.camera(n).intrinsics.fx / truth.camera(n).intrinsics.fx - 1) < 1e-3


@pytest.mark.parametrize("chunk", [7, 8192])
def test_chunked_normal_equations_equal_whole_jacobian(drone, monkeypatch, chunk):
    """Problem.normal_equations (chunks of one camera and board, never the whole Jacobian)
    equals J^T W J / J^T W e from the whole sparse Jacobian, with row weights, a camera
    with fixed intrinsics, a tied focal, observations in shuffled order, and chunk
    boundaries cutting through runs (chunk 7)."""
    import rigcal.camcal.solve as solve

    monkeypatch.setattr(solve, "NE_CHUNK", chunk)
    rng = np.random.default_rng(11)
    obs, state = _small_problem(drone, rng)
    perm = rng.permutation(len(obs))
    obs = obs.subset(perm)
    state.intrinsics[1] = solve.Intrinsics("pinhole", state.intrinsics[1].values, tie_focal=True, hold_centre=True)
    pb = Problem(obs, state, gauge_cam=0, gauge_board=1, fix_intrinsics=np.array([False, False, True]))
    x = pb.x0() + rng.normal(0, 1e-3, pb.layout.size)
    e = pb.residuals(x)
    w = np.repeat(rng.uniform(0.2, 3.0, len(obs)), 2)
    got = pb.normal_equations(x, e, w)
    ref = solve.NormalEquations.from_jacobian(pb.jacobian(x), e, w, pb.layout.frame[0].start)
    for name in ("g_a", "g_d", "H_aa", "H_ad", "H_dd"):
        a, b = getattr(got, name), getattr(ref, name)
        assert np.max(np.abs(a - b)) <= 1e-10 * np.max(np.abs(b)), name
    assert np.abs(ref.H_ad).max() > 0 and np.abs(ref.H_aa).max() > 0  # not a comparison of zeros
    dx, S = got.solve(1e-3)
    dx_ref, S_ref = ref.solve(1e-3)
    assert np.allclose(dx, dx_ref, rtol=1e-8, atol=1e-12 * np.abs(dx_ref).max())


class _PositionPrior:
    """A toy residual block plugged into the rig problem: camera c's position in the body
    frame's inverse (the translation of T_cam_body) held near `t` with sigma (m)."""

    dim, n_rows = 3, 1

    def __init__(self, pb, c, t, sigma):
        self.s, self.t, self.sigma = pb.layout.cam[c], t, sigma

    def residuals(self, x):
        return ((x[self.s][3:] - self.t) / self.sigma)[None]

    def jacobian_chunks(self, x):
        from rigcal.camcal.blocks import JacobianChunk

        yield JacobianChunk(np.array([0]), np.eye(3)[None] / self.sigma, np.arange(self.s.start + 3, self.s.stop))


def test_a_plugged_in_residual_block_joins_the_normal_equations_and_the_solve(drone):
    """Problem.blocks takes a further residual kind without solver changes: its rows join
    the chunked normal equations (equal to the whole Jacobian's) and LM honours it (a
    tight prior moves camera 1 to the prior's position, the corners follow)."""
    import rigcal.camcal.solve as solve

    rng = np.random.default_rng(12)
    obs, state = _small_problem(drone, rng)
    pb = Problem(obs, state, gauge_cam=0, gauge_board=0)
    t_prior = state.T_cam_body[1, :3, 3] + np.array([0.004, -0.003, 0.002])
    pb.blocks.append(_PositionPrior(pb, 1, t_prior, 1e-7))
    x = pb.x0() + rng.normal(0, 1e-4, pb.layout.size)
    e = pb.residuals(x)
    assert e.shape == (2 * len(obs) + 3,)
    w = pb.sqrt_weights() ** 2
    got = pb.normal_equations(x, e, w)
    ref = solve.NormalEquations.from_jacobian(pb.jacobian(x), e, w, pb.layout.frame[0].start)
    for name in ("g_a", "g_d", "H_aa", "H_ad", "H_dd"):
        a, b = getattr(got, name), getattr(ref, name)
        assert np.max(np.abs(a - b)) <= 1e-10 * np.max(np.abs(b)), name
    x_hat, _, conv = levenberg_marquardt(pb)
    assert conv
    assert np.max(np.abs(x_hat[pb.layout.cam[1]][3:] - t_prior)) < 1e-5
    assert np.max(np.abs(x_hat[pb.layout.cam[1]][3:] - state.T_cam_body[1, :3, 3])) > 3e-3
