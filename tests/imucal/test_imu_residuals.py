"""Residual blocks of the camera-IMU calibration against differences of the whole problem,
and the models they encode against rigcal.sim.imu_model's simulator (an independent writing)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.sim import imu_model
from rigcal.imucal import residuals as ir
from rigcal.core.camera import CameraModel
from rigcal.camcal.solve import Intrinsics
from rigcal.core.spline import Spline, evaluate, fit
from tests.support.synthetic_obs import central_jacobian


def _state(rng, n=9, dt=0.1, n_bias=3):
    R = geo.R_from_rotvec(np.cumsum(rng.normal(0, 0.15, (n, 3)), axis=0))
    p = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0) + [0, 0, 1.0]
    T_bc = np.stack([geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.2, 3)) @ geo.R_from_axes(["-L", "-U", "F"]),
                                rng.normal(0, 0.05, 3)) for _ in range(2)])
    T_bi = geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.1, 3)), rng.normal(0, 0.03, 3))
    return ir.State(spline=Spline(0.0, dt, R, p), T_body_imu=T_bi, T_body_cam=T_bc,
                    time_offset_s=np.array([0.004, -0.007]), line_delay_s=np.array([0.0, 2e-5]),
                    bias_t0=0.0, bias_dt=0.3, gyro_bias=rng.normal(0, 1e-2, (n_bias, 3)),
                    accel_bias=rng.normal(0, 0.1, (n_bias, 3)),
                    R_grav=geo.R_from_rotvec(rng.normal(0, 0.1, 3)))


def _with_scale(state, seed=11):
    """state with scale-misalignment matrices of a few per cent (scale-misalignment model)."""
    rng = np.random.default_rng(seed)
    return replace(state, M_gyro=np.eye(3) + ir.lower(rng.normal(0, 0.02, 6)),
                   M_accel=np.eye(3) + ir.lower(rng.normal(0, 0.02, 6)))


def _corners(rng, state, m=14):
    t = rng.uniform(0.05, 0.5, m)
    cam = rng.integers(0, 2, m)
    mo = evaluate(state.spline, t + state.time_offset_s[cam])
    # points 1-2 m in front of each camera
    p_cam = np.column_stack([rng.uniform(-0.3, 0.3, (m, 2)), rng.uniform(1, 2, m)])
    T_wc = mo.T_world_body @ state.T_body_cam[cam]
    p_world = np.einsum("mij,mj->mi", T_wc[:, :3, :3], p_cam) + T_wc[:, :3, 3]
    uv = rng.uniform(0, 480, (m, 2))
    return ir.Corners(cam, t, uv, p_world)


def _on_boards(rng, state, obs, n_boards=3):
    """state with boards 1 .. n_boards - 1 at random poses (board 0 the world) and the
    corners of obs spread over the boards, each at the same world point as before."""
    T = np.stack([np.eye(4)] + [geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.5, 3)), rng.normal(0, 0.5, 3))
                                for _ in range(n_boards - 1)])
    board = rng.integers(0, n_boards, len(obs.cam))
    T_board_world = geo.inv_T(T)[board]
    p_board = np.einsum("mij,mj->mi", T_board_world[:, :3, :3], obs.p_board) + T_board_world[:, :3, 3]
    return replace(state, T_world_board=T), ir.Corners(obs.cam, obs.t_cam, obs.uv, p_board, board)


CAMS = [CameraModel("pinhole", 640, 480, 300.0, 310.0, 320.0, 240.0, (0.05, -0.02, 0.001, 0.0, 0.0)),
        CameraModel("fisheye", 640, 480, 250.0, 250.0, 320.0, 240.0, (0.02, -0.01, 0.0, 0.0))]


def _global_fd(state, lay, blocks_of, h=1e-6):
    """Whole-problem central differences: every global column perturbed through retract."""
    _, r0 = ir.assemble(blocks_of(state), lay.size)
    J = np.zeros((len(r0), lay.size))
    for k in range(lay.size):
        dx = np.zeros(lay.size)
        dx[k] = h
        rp = ir.assemble(blocks_of(ir.retract(state, lay, dx)), lay.size)[1]
        rm = ir.assemble(blocks_of(ir.retract(state, lay, -dx)), lay.size)[1]
        J[:, k] = (rp - rm) / (2 * h)
    return J


def _with_intrinsics(state):
    """state carrying CAMS' intrinsics as parameters: the pinhole's fx, fy, cx, cy and its
    five distortion terms free; the fisheye's focal tied (fx = fy) and centre held."""
    vals = [np.array([k.fx, k.fy, k.cx, k.cy, *k.dist]) for k in CAMS]
    return replace(state, intrinsics=(Intrinsics("pinhole", vals[0]),
                                      Intrinsics("fisheye", vals[1], tie_focal=True, hold_centre=True)))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["gyro", "accel", "corners", "corners on boards", "corners with intrinsics", "prior"])
def test_block_jacobians_match_whole_problem_differences(kind):
    rng = np.random.default_rng(7)
    st = _with_scale(_state(rng))  # every group free, the scale-misalignment columns included
    t = rng.uniform(0.0, 0.55, 12)
    meas = rng.normal(0, 1, (12, 3))
    obs = _corners(rng, st)
    if kind == "corners on boards":  # boards 1 and 2 estimated, board 0 the world
        st, obs = _on_boards(rng, st, obs)
    if kind == "corners with intrinsics":
        st = _with_intrinsics(st)
    lay = ir.layout_for(st, held=frozenset())
    blocks_of = {
        "gyro": lambda s: [ir.gyro_block(s, lay, t, meas, 0.01)],
        "accel": lambda s: [ir.accel_block(s, lay, t, meas, 0.05)],
        "corners": lambda s: [ir.reprojection_block(s, lay, obs, CAMS, 0.5)],
        "corners on boards": lambda s: [ir.reprojection_block(s, lay, obs, CAMS, 0.5)],
        "corners with intrinsics": lambda s: [ir.reprojection_block(s, lay, obs, CAMS, 0.5)],
        "prior": lambda s: [ir.bias_prior_block(s, lay, 2e-5, 3e-3)],
    }[kind]
    J, _ = ir.assemble(blocks_of(st), lay.size)
    J_fd = _global_fd(st, lay, blocks_of)
    J = J.toarray()
    scale = np.abs(J_fd).max()
    assert scale > 0
    np.testing.assert_allclose(J, J_fd, atol=2e-5 * scale)
    # every column a block claims is one it really moves (no stray index)
    assert np.all((np.abs(J) > 0).sum(axis=0)[np.abs(J_fd).max(axis=0) > 1e-6 * scale] > 0)
    if kind == "corners with intrinsics":  # 9 + 1 + 4 parameters, each moved by some corner
        assert lay.n_intr == (9, 5) and np.all(np.abs(J_fd[:, lay.intr:]).max(axis=0) > 1e-3)
    if kind == "corners on boards":
        assert lay.n_board == 2 and np.all(np.abs(J_fd[:, lay.board:]).max(axis=0) > 10.0)  # every board column


def test_boards_leave_the_corners_of_the_world_board_unchanged():
    """Corners given on boards (board 0 the world, the others placed by T_world_board) give
    the residuals of the same points given in the world, and board 0 has no columns."""
    rng = np.random.default_rng(8)
    st = _state(rng)
    obs = _corners(rng, st, m=40)
    st_b, obs_b = _on_boards(rng, st, obs)
    r = ir.reprojection_block(st, ir.layout_for(st), obs, CAMS, 0.5).r
    lay_b = ir.layout_for(st_b)
    b = ir.reprojection_block(st_b, lay_b, obs_b, CAMS, 0.5)
    np.testing.assert_allclose(b.r, r, atol=1e-9)
    assert np.all(b.cols[obs_b.board == 0, -6:] == -1) and np.all(b.cols[obs_b.board > 0, -6:] >= lay_b.board)


@pytest.mark.parametrize("sensor", ["gyro", "accel"])
def test_scale_misalignment_jacobian_matches_central_differences(sensor):
    """The analytic columns of the 6 + 6 parameters of L (M = I + L, lower-triangular)
    against central differences of the residuals in those parameters alone, at M != I;
    each sensor's block touches only its own 6, and the held group has no columns."""
    rng = np.random.default_rng(4)
    st = _with_scale(_state(rng))
    lay = ir.layout_for(st, held=frozenset())
    t = rng.uniform(0.0, 0.55, 15)
    meas = rng.normal(0, 1, (15, 3))
    block = ir.gyro_block if sensor == "gyro" else ir.accel_block

    def residuals(x):
        s = replace(st, M_gyro=np.eye(3) + ir.lower(x[:6]), M_accel=np.eye(3) + ir.lower(x[6:]))
        return block(s, lay, t, meas, 0.02).r.ravel()

    x0 = np.concatenate([(st.M_gyro - np.eye(3))[ir.SCALE_ROWS, ir.SCALE_COLS],
                         (st.M_accel - np.eye(3))[ir.SCALE_ROWS, ir.SCALE_COLS]])
    np.testing.assert_allclose(residuals(x0), block(st, lay, t, meas, 0.02).r.ravel(), atol=1e-12)
    J_fd = central_jacobian(residuals, x0)
    J = ir.assemble([block(st, lay, t, meas, 0.02)], lay.size)[0].toarray()[:, lay.scale:lay.scale + 12]
    np.testing.assert_allclose(J, J_fd, atol=1e-6 * np.abs(J_fd).max())
    mine, other = (slice(0, 6), slice(6, 12)) if sensor == "gyro" else (slice(6, 12), slice(0, 6))
    assert np.all(np.abs(J_fd[:, mine]).max(axis=0) > 1.0) and np.all(J[:, other] == 0)
    held = ir.layout_for(st)  # the calibrated model: the group held, no column
    assert "scale" in held.held and np.all(block(st, held, t, meas, 0.02).cols[:, -6:] == -1)


def test_time_offset_column_is_the_image_motion():
    """d uv / d offset equals the pixel velocity from the spline's v and omega (first order)."""
    rng = np.random.default_rng(3)
    st = _state(rng)
    lay = ir.layout_for(st)
    obs = _corners(rng, st, m=6)
    J, _ = ir.assemble([ir.reprojection_block(st, lay, obs, CAMS, 1.0)], lay.size)
    col = J.toarray()[:, lay.offset:lay.offset + 2]
    h = 1e-5
    t = ir.corner_times(st, obs)
    uv = []
    for dt_ in (h, -h):
        mo = evaluate(st.spline, t + dt_)
        T_cw = np.linalg.inv(mo.T_world_body @ st.T_body_cam[obs.cam])
        p_cam = np.einsum("mij,mj->mi", T_cw[:, :3, :3], obs.p_board) + T_cw[:, :3, 3]
        uv.append(np.stack([CAMS[c].project(p[None])[0][0] for c, p in zip(obs.cam, p_cam)]))
    vel = ((uv[0] - uv[1]) / (2 * h)).ravel()
    got = col[np.arange(len(vel)), np.repeat(obs.cam, 2)]
    np.testing.assert_allclose(got, vel, rtol=1e-5, atol=1e-4)
    assert np.abs(vel).max() > 1.0  # the test would see a missing time column


def test_residuals_vanish_on_the_simulators_readings():
    """Blocks evaluated at a spline fitted to the simulator's motion reproduce
    rigcal.sim.imu_model.ideal_readings (bias included): the two models agree."""
    rng = np.random.default_rng(1)
    traj = imu_model.hand_held_trajectory(rng)
    t = np.arange(0.0, 3.0, 0.002)
    mo = traj.at(t)
    spline = fit(t, mo.R_world_body, mo.p_world, 0.02)
    T_bi = geo.make_T(geo.R_from_rotvec([0.02, -0.03, 0.5]), [0.03, -0.02, 0.01])
    st = _state(rng)
    st = ir.State(spline=spline, T_body_imu=T_bi, T_body_cam=st.T_body_cam, time_offset_s=st.time_offset_s,
                  line_delay_s=st.line_delay_s, bias_t0=0.0, bias_dt=1.0, gyro_bias=rng.normal(0, 1e-2, (4, 3)),
                  accel_bias=rng.normal(0, 0.1, (4, 3)), R_grav=np.eye(3))
    lay = ir.layout_for(st)
    tq = np.arange(0.2, 2.8, 0.05)
    g, a = imu_model.ideal_readings(traj.at(tq), T_bi)
    bg, ba = ir.bias_values(st, tq)
    rg = ir.gyro_block(st, lay, tq, g + bg, 1.0).r
    ra = ir.accel_block(st, lay, tq, a + ba, 1.0).r
    assert np.abs(rg).max() < 2e-3  # rad/s: spline fit error at 50 knots/s of the sine motion
    assert np.abs(ra).max() < 2e-2  # m/s^2
    # and a wrong lever arm is seen
    st2 = ir.State(**{**st.__dict__, "T_body_imu": geo.make_T(T_bi[:3, :3], [0.0, 0.0, 0.0])})
    assert np.abs(ir.accel_block(st2, lay, tq, a + ba, 1.0).r).max() > 5 * np.abs(ra).max()


def test_huber_block_cost_and_weights():
    b = ir.Block(np.array([[3.0, 4.0], [0.3, 0.4]]), np.ones((2, 2, 1)), np.zeros((2, 1), dtype=int))
    h = ir.huber(b, 2.0)
    # row 0: |r| = 5 > 2 -> cost 2 * 2 * 5 - 4 = 16, weight sqrt(2 / 5); row 1: |r| = 0.5 -> 0.25, unweighted
    assert abs(h.cost - 16.25) < 1e-12 and abs(b.objective - 25.25) < 1e-12
    assert np.allclose(h.r[0], b.r[0] * np.sqrt(0.4)) and np.allclose(h.r[1], b.r[1])
    assert np.allclose(h.J[0], np.sqrt(0.4)) and np.allclose(h.J[1], 1.0)
    # IRLS: J^T r is half the cost's gradient in s beyond k (d/ds (2 k s) / 2 = k = w s)
    assert abs(np.linalg.norm(h.r[0]) ** 2 - 2.0 * 5.0) < 1e-12


def test_corner_past_the_lens_fold_stays_finite():
    """A corner the start places past the radius where the distortion polynomial folds back
    (CameraModel.project: NaN) gets the polynomial's finite pixel, as in the camera BA, with
    a Jacobian that matches the whole problem's differences there. A NaN made the first cost
    NaN and LM refused every step (EuRoC's start came back as the result)."""
    rng = np.random.default_rng(5)
    st = _state(rng)
    lay = ir.layout_for(st, held=frozenset())
    # EuRoC-like radtan with k3 < 0: folds back near r = 1.36 (normalised)
    cams = [CameraModel("pinhole", 752, 480, 458.0, 457.0, 367.0, 248.0, (-0.33, 0.16, 0.0005, 0.0005, -0.045))] * 2
    obs = _corners(rng, st, m=6)
    mo = evaluate(st.spline, ir.corner_times(st, obs))
    T_wc = mo.T_world_body @ st.T_body_cam[obs.cam]
    p_cam = np.array([[1.6, 0.3, 1.0], [0.1, 0.1, 1.0], [-1.5, -0.2, 1.0], [0.2, -0.1, 1.5], [0.0, 0.0, 2.0],
                      [1.9, 1.0, 1.2]])
    obs = ir.Corners(obs.cam, obs.t_cam, obs.uv, np.einsum("mij,mj->mi", T_wc[:, :3, :3], p_cam) + T_wc[:, :3, 3])
    assert not cams[0].project(p_cam)[1].all()  # some corners are past the fold
    blocks_of = lambda s: [ir.reprojection_block(s, lay, obs, cams, 0.5)]  # noqa: E731
    b = blocks_of(st)[0]
    assert np.all(np.isfinite(b.r)) and np.all(np.isfinite(b.J))
    J_fd = _global_fd(st, lay, blocks_of)
    J = ir.assemble([b], lay.size)[0].toarray()
    np.testing.assert_allclose(J, J_fd, rtol=1e-4, atol=2e-5 * np.abs(J_fd).max())


@pytest.mark.parametrize("held, boards", [(frozenset(), False), (frozenset(), True),
                                          (frozenset({"imu_rot", "imu_pos", "line_delay", "scale"}), False)])
def test_normal_rows_keep_the_normal_equations(held, boards):
    """normal_rows merges each image's corner rows (one camera, one spline segment, one
    board: the same columns) into at most K rows: J^T J, J^T r and the objective are
    unchanged, with and without held columns, under a rolling shutter (rows of one image on
    several segments), with corners on several estimated boards."""
    rng = np.random.default_rng(11)
    st = _state(rng)
    obs = _corners(rng, st, m=400)
    obs = ir.Corners(obs.cam, np.round(obs.t_cam, 2), obs.uv, obs.p_board)  # ~45 images of ~9 corners
    if boards:
        st, obs = _on_boards(rng, st, obs)
    lay = ir.layout_for(st, held=held)
    blocks = [ir.huber(ir.reprojection_block(st, lay, obs, CAMS, 0.5), 3.0),
              ir.gyro_block(st, lay, rng.uniform(0.0, 0.55, 30), rng.normal(0, 1, (30, 3)), 0.01)]
    merged = ir.normal_rows(blocks)
    assert len(merged[0].r) < len(blocks[0].r) / 2 and merged[1] is blocks[1]
    J, r = ir.assemble(blocks, lay.size)
    Jm, rm = ir.assemble(merged, lay.size)
    H, Hm = (J.T @ J).toarray(), (Jm.T @ Jm).toarray()
    np.testing.assert_allclose(Hm, H, rtol=0, atol=1e-11 * np.abs(H).max())
    np.testing.assert_allclose(Jm.T @ rm, J.T @ r, rtol=0, atol=1e-11 * np.abs(J.T @ r).max())
    assert [b.objective for b in merged] == pytest.approx([b.objective for b in blocks], rel=1e-15)


def _assert_same_normal_equations(whole, rows, size: int) -> None:
    """The merged rows keep the whole block's J^T J, J^T r, objective and RMS."""
    J, r = ir.assemble([whole], size)
    Jm, rm = ir.assemble([rows], size)
    H = (J.T @ J).toarray()
    np.testing.assert_allclose((Jm.T @ Jm).toarray(), H, rtol=0, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(Jm.T @ rm, J.T @ r, rtol=0, atol=1e-10 * np.abs(J.T @ r).max())
    assert rows.objective == pytest.approx(whole.objective, rel=1e-12)
    assert rows.residual_rms == pytest.approx(float(np.sqrt(np.mean(whole.r ** 2))), rel=1e-12)


@pytest.mark.parametrize("huber_k", [None, 1.5])
def test_reprojection_rows_in_chunks_keep_the_normal_equations(monkeypatch, huber_k):
    """reprojection_rows builds the corner block a chunk at a time (in time order) and merges
    each chunk's rows: J^T J, J^T r, the objective and the residual RMS are those of the
    whole block, with and without the Huber loss, chunks of any size (here 37 corners, so
    images are split across chunks), boards and intrinsics estimated."""
    rng = np.random.default_rng(12)
    st = _with_intrinsics(_state(rng))
    obs = _corners(rng, st, m=300)
    obs = ir.Corners(obs.cam, np.round(obs.t_cam, 2), obs.uv, obs.p_board)
    st, obs = _on_boards(rng, st, obs)
    lay = ir.layout_for(st, held=frozenset())
    whole = ir.reprojection_block(st, lay, obs, CAMS, 0.5)
    whole = whole if huber_k is None else ir.huber(whole, huber_k)
    monkeypatch.setattr(ir, "CHUNK_CORNERS", 37)
    rows = ir.reprojection_rows(st, lay, obs, CAMS, 0.5, huber_k)
    _assert_same_normal_equations(whole, rows, lay.size)
    assert len(rows.r) < len(whole.r)


def test_motion_jacobian_matches_central_differences_of_the_spline():
    """J_rot (forward differences of each row's own controls) against central differences
    of the whole spline (one control turned at a time, every row re-evaluated), to 1e-6 of
    each output's largest entry: far tighter than any step of the estimate needs."""
    rng = np.random.default_rng(5)
    st = _state(rng)
    sp_ = st.spline
    t = rng.uniform(sp_.t0, sp_.t_end, 40)
    mj = ir.motion_jacobian(st, t)
    n, h = len(sp_.p), 1e-6
    J = np.zeros((len(t), 9, 3 * n))
    m0 = evaluate(sp_, t)
    for k in range(n):
        for axis in range(3):
            outs = []
            for s in (h, -h):
                d = np.zeros((n, 3))
                d[k, axis] = s
                m = evaluate(replace(sp_, R=geo.R_from_rotvec(d) @ sp_.R), t)
                theta = geo.rotvecs_from_R(m.R_world_body @ np.swapaxes(m0.R_world_body, 1, 2))
                outs.append(np.concatenate([theta, m.omega_body, m.alpha_body], axis=1))
            J[:, :, 3 * k + axis] = (outs[0] - outs[1]) / (2 * h)
    cols = 3 * (mj.i[:, None] + np.arange(4))[:, :, None] + np.arange(3)
    local = np.take_along_axis(J, cols.reshape(len(t), 1, 12), axis=2)
    for rows in (slice(0, 3), slice(3, 6), slice(6, 9)):
        np.testing.assert_allclose(mj.J_rot[:, rows], local[:, rows], rtol=0,
                                   atol=1e-6 * np.abs(local[:, rows]).max())
    # and no column outside a row's four controls moves it
    outside = np.abs(J).sum(axis=(1, 2)) - np.abs(local).sum(axis=(1, 2))
    assert np.all(outside < 1e-9 * np.abs(J).sum(axis=(1, 2)))


@pytest.mark.parametrize("huber_k", [None, 1.5])
@pytest.mark.parametrize("threads", [1, 2])
def test_image_rows_keep_the_normal_equations(monkeypatch, huber_k, threads):
    """Without line delays reprojection_rows merges each image's corners in the pose's 6
    columns and carries them to the 24 control columns afterwards (_image_rows): J^T J,
    J^T r, the objective and the residual RMS are those of the whole corner block, with
    and without the Huber loss, chunks split across images, boards and intrinsics
    estimated, the chunks built in turn or on threads."""
    rng = np.random.default_rng(13)
    st = _with_intrinsics(_state(rng))
    st = replace(st, line_delay_s=np.zeros(2))
    obs = _corners(rng, st, m=300)
    obs = ir.Corners(obs.cam, np.round(obs.t_cam, 2), obs.uv, obs.p_board)
    st, obs = _on_boards(rng, st, obs)
    lay = ir.layout_for(st, held=frozenset({"line_delay"}))
    whole = ir.reprojection_block(st, lay, obs, CAMS, 0.5)
    whole = whole if huber_k is None else ir.huber(whole, huber_k)
    monkeypatch.setattr(ir, "CHUNK_CORNERS", 37)
    monkeypatch.setattr(ir, "JOBS_THREADS", threads)
    sizes = []
    image_rows = ir._image_rows
    monkeypatch.setattr(ir, "_image_rows", lambda s, l, o, *a: sizes.append(len(o.cam)) or image_rows(s, l, o, *a))
    rows = ir.reprojection_rows(st, lay, obs, CAMS, 0.5, huber_k)
    _assert_same_normal_equations(whole, rows, lay.size)
    # chunks of at most CHUNK_CORNERS, as many as a multiple of the threads, of equal size
    assert sum(sizes) == 300 and max(sizes) <= 37 and len(sizes) % threads == 0 and max(sizes) - min(sizes) <= 1
    # 6 pose + 6 camera + 1 offset + 6 board columns and the intrinsic ones merged: as many rows a view
    assert rows.r.shape[1] == 6 + 6 + 1 + 6 + max(lay.n_intr)


def test_gram_over_two_halves_is_the_normal_matrix():
    """estimator.gram: J^T J summed over two halves of J's rows on two threads equals the
    one product to rounding, above the split size and below it."""
    import scipy.sparse as sp

    from rigcal.imucal import estimator as ic

    rng = np.random.default_rng(5)
    for rows in (ic.GRAM_SPLIT_ROWS // 2, 2 * ic.GRAM_SPLIT_ROWS + 1):
        J = sp.random(rows, 300, density=0.02, format="csr", random_state=rng)
        H = ic.gram(J)
        assert sp.isspmatrix_csc(H) or H.format == "csc"
        ref = (J.T @ J).toarray()
        assert np.allclose(H.toarray(), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("boards", [False, True])
def test_corner_errors_are_the_corner_block_residuals_unweighted(boards):
    """corner_errors (the camera-IMU outlier test's errors, no Jacobians): the corner block's
    residuals times its sigma, on boards and with intrinsics estimated alike."""
    rng = np.random.default_rng(17)
    st = _with_intrinsics(_state(rng))
    obs = _corners(rng, st)
    if boards:
        st, obs = _on_boards(rng, st, obs)
    e = ir.corner_errors(st, obs, CAMS)
    r = ir.reprojection_block(st, ir.layout_for(st), obs, CAMS, 0.5).r * 0.5
    assert e.shape == (len(obs.cam), 2) and np.all(np.isfinite(e))
    assert np.allclose(e, r.reshape(-1, 2), rtol=0, atol=1e-12 * max(1.0, np.abs(r).max()))
    assert np.abs(e).max() > 1e-3  # the start is off the measurements: a test of something
