"""`--distortion auto`: which pinhole model the joint solve keeps (model_selection.keep_k3,
initialise.select_rational) on synthetic corners whose true distortion is known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

import rigcal
from rigcal.camcal.pipeline import calibrate_views
from rigcal.camcal.model_selection import K3_LEVEL, keep_k3
from rigcal.sim.synthetic import room_scene, with_noise


@pytest.fixture(scope="module")
def drone():
    return rigcal.load_rig("rigs/drone-stereo-back.yaml")


def _with_dist(rig, dist):
    return rig.with_cameras([replace(c, intrinsics=c.intrinsics.with_(dist=tuple(dist))) for c in rig.cameras])


def _auto(rig, truth, seed, n_frames=20, sigma=0.1):
    rng = np.random.default_rng(seed)
    sc = room_scene(truth, rng, n_frames=n_frames)
    return calibrate_views(with_noise(sc.views, sigma, rng), rig, sc.corners, distortion="auto")


def test_keep_k3_threshold_is_the_chi2_quantile():
    need = chi2.ppf(1 - K3_LEVEL, 1)
    assert 15.0 < need < 15.3
    assert keep_k3(0.01, (0.01 / np.sqrt(need)) ** 2 * 0.99)[0]  # just beyond the threshold
    assert not keep_k3(0.01, (0.01 / np.sqrt(need)) ** 2 * 1.01)[0]
    assert keep_k3(-0.02, 1e-6)[0]  # the sign does not matter
    kept, line = keep_k3(0.0, 1e-6)
    assert not kept and "dropped" in line


def test_auto_keeps_decentering_and_drops_an_absent_k3(drone):
    """Truth: radial plus decentering, k3 = 0. auto must estimate p1, p2 (radtan4 is the
    floor) and not invent k3; the fitted decentering must match the truth within 4 of
    its reported sigmas."""
    truth = _with_dist(drone, (-0.03, 0.01, 3e-4, -2e-4, 0.0))
    cal = _auto(drone, truth, 1)
    for n in cal.cam_names:
        assert cal.stats[n].distortion_model == "radtan4", (n, cal.stats[n].model_selection)
        assert any("k3" in line and "dropped" in line for line in cal.stats[n].model_selection)
        p = np.array(cal.rig.camera(n).intrinsics.dist[2:4])
        sd = np.array(cal.stats[n].sigma_intrinsics["distortion"][2:4])
        assert np.all(np.abs(p - [3e-4, -2e-4]) < 4 * sd), (n, p, sd)


def test_auto_keeps_a_strong_k3(drone):
    """Truth with a k3 that bends the image corners by several pixels: kept, and within 4
    of its reported sigmas."""
    truth = _with_dist(drone, (-0.05, 0.02, 1e-4, 1e-4, 0.05))
    cal = _auto(drone, truth, 2)
    for n in cal.cam_names:
        assert cal.stats[n].distortion_model == "radtan5", (n, cal.stats[n].model_selection)
        k3 = cal.rig.camera(n).intrinsics.dist[4]
        assert abs(k3 - 0.05) < 4 * cal.stats[n].sigma_intrinsics["distortion"][4], (n, k3)


def test_auto_k3_tested_in_the_joint_solve_not_per_camera(drone):
    """The log says where each decision was made, so a user can see why."""
    truth = _with_dist(drone, (-0.03, 0.01, 0.0, 0.0, 0.0))
    cal = _auto(drone, truth, 3, n_frames=12)
    for n in cal.cam_names:
        log = cal.stats[n].model_selection
        assert any(line.startswith("joint solve: k3") for line in log), log
        assert any("rational8" in line and "rejected" in line for line in log), log


def _unsynchronised_scene(truth, rng, n_frames, jitter_deg, jitter_mm):
    """Wall boards seen by each camera from its own body pose per frame: the rig pose of
    the frame moved by a random jitter per camera, as when cameras triggered in
    software see a moving rig (or board) at different instants."""
    from rigcal.core import geometry as geo
    from rigcal.core.observations import BoardView
    from rigcal.sim.synthetic import BOARD, board_view, grid_corners, random_body_pose, wall_boards

    p_board = grid_corners(*BOARD)
    T_world_board = wall_boards(4, p_board.mean(0), 2.0)
    views = []
    for f in range(n_frames):
        T_wb = random_body_pose(rng)
        for cam in truth.cameras:
            J = geo.make_T(geo.R_from_rotvec(rng.normal(0, np.radians(jitter_deg), 3)),
                           rng.normal(0, jitter_mm / 1000, 3))
            T_cam_world = geo.inv_T(cam.T_body_cam) @ geo.inv_T(T_wb @ J)
            for name, T in T_world_board.items():
                seen = board_view(cam, T_cam_world @ T, p_board, 8)
                if seen is not None:
                    views.append(BoardView(cam.name, f"{f:06d}", name, seen[0], seen[1] + rng.normal(0, 0.1, seen[1].shape)))
    return views, {n: p_board for n in T_world_board}


@pytest.mark.slow
def test_unsynchronised_frames_take_intrinsics_from_each_camera_alone(drone):
    """Per-camera jitter of the rig pose breaks 'one rigid rig per frame': the joint solve
    would bend the intrinsics to absorb it. rigidity_check must say so, and the focal
    lengths must come out as each camera's own views give them (near the truth)."""
    truth = _with_dist(drone, (-0.03, 0.01, 2e-4, -1e-4, 0.0))
    rng = np.random.default_rng(7)
    views, corners = _unsynchronised_scene(truth, rng, 30, jitter_deg=0.3, jitter_mm=5.0)
    cal = calibrate_views(views, drone, corners, distortion="auto")
    assert any("disagree with one rigid rig per frame" in n for n in cal.notes), cal.notes
    for n in cal.cam_names:
        assert abs(cal.rig.camera(n).intrinsics.fx / truth.camera(n).intrinsics.fx - 1) < 2e-3
        assert any("own views" in line for line in cal.stats[n].model_selection)
    # the same scene without the jitter: rigid, no note, intrinsics from the joint solve
    rng = np.random.default_rng(7)
    views, corners = _unsynchronised_scene(truth, rng, 30, jitter_deg=0.0, jitter_mm=0.0)
    cal = calibrate_views(views, drone, corners, distortion="auto")
    assert not any("rigid rig" in n for n in cal.notes), cal.notes


@pytest.mark.slow
def test_a_rig_the_camera_imu_step_solves_again_is_judged_on_a_sample_of_its_frames(drone, monkeypatch):
    """imu_start (the camera-IMU step re-estimates the intrinsics): when the robust pass
    over a sample of the frames shows the rig far from rigid per frame, first_solve runs no
    joint solve over every frame and only the held-intrinsics solve does. The rig must come
    out as the full path gives it, within its sigmas; on a rigid rig the full path runs and
    the answer is the same to the bit."""
    from rigcal.camcal import pipeline
    from rigcal.core import geometry as geo

    monkeypatch.setattr(pipeline, "RIGIDITY_SAMPLE_FRAMES", 10)  # 30 frames: every third

    calls = []
    full = pipeline.bundle_adjust

    def logged(*a, **k):
        res = full(*a, **k)
        calls.append((bool(np.all(a[4])), res.history))
        return res

    monkeypatch.setattr(pipeline, "bundle_adjust", logged)
    truth = _with_dist(drone, (-0.03, 0.01, 2e-4, -1e-4, 0.0))
    for jitter, rigid in ((0.3, False), (0.0, True)):
        cals = []
        for imu_start in (False, True):
            rng = np.random.default_rng(7)
            views, corners = _unsynchronised_scene(truth, rng, 30, jitter_deg=jitter, jitter_mm=17 * jitter)
            calls.clear()
            cals.append(calibrate_views(views, drone, corners, distortion="auto", imu_start=imu_start))
            held = [fix for fix, _ in calls]
            if imu_start and not rigid:  # no free-intrinsics solve over every frame
                assert held == [True], calls
            else:
                assert held[0] is False and len(calls[0][1]) > 1, calls  # robust pass and rounds
        a, b = cals
        assert (any("rigid rig" in n for n in b.notes)) == (not rigid), b.notes
        assert a.view_T_cam_board is None and (b.view_T_cam_board is None) == rigid
        if not rigid:  # the camera-IMU start's poses: each camera's own-views solve's, one per view
            T = b.view_T_cam_board
            assert T.shape == (b.obs.view.max() + 1, 4, 4)
            for v in range(0, len(T), 7):
                k = b.obs.view == v
                cam = b.rig.camera(b.cam_names[int(b.obs.cam[k][0])]).intrinsics
                uv, _ = cam.project(geo.transform(T[v], b.obs.p_board[k]))
                assert np.sqrt(np.mean(np.sum((uv - b.obs.uv[k]) ** 2, axis=1))) < 0.5  # 0.1 px noise
        for n in a.cam_names:
            Ta, Tb = a.rig.camera(n).T_body_cam, b.rig.camera(n).T_body_cam
            if rigid:
                assert np.array_equal(Ta, Tb)
                continue
            # the held solve starts from the pose graph instead of the joint solve: its
            # rejection rounds can settle on another inlier set in this 1.8 px misfit
            # (0.65 sigma apart where measured); a broken start would be far off
            d = geo.inv_T(Ta) @ Tb
            s = a.stats[n]
            assert np.linalg.norm(d[:3, 3]) * 1000 < np.linalg.norm(s.sigma_position_mm), n
            assert geo.rotation_angle_deg(d[:3, :3]) < np.linalg.norm(s.sigma_rotation_deg), n


def test_the_rigidity_sample_keeps_every_camera_and_board_or_is_not_taken():
    """frame_sample: every k-th frame (k = frames // n), or None when k < 2 or a camera or a
    board would be left with fewer than MIN_VIEW_CORNERS corners."""
    from rigcal.camcal.initialise import MIN_VIEW_CORNERS
    from rigcal.camcal.pipeline import frame_sample
    from rigcal.camcal.solve import Observations

    n = MIN_VIEW_CORNERS
    frame = np.repeat(np.arange(12), 2 * n)  # 12 frames, two views of n corners each
    cam = np.tile(np.repeat([0, 1], n), 12)
    board = np.zeros_like(frame)
    obs = Observations(cam, frame, board, np.zeros((len(cam), 3)), np.zeros((len(cam), 2)), frame)
    m = frame_sample(obs, 4, 2, 1)
    assert m is not None and set(np.unique(frame[m])) == {0, 3, 6, 9}
    assert frame_sample(obs, 7, 2, 1) is None  # k = 1
    # camera 1 only in frame 5: not in the sample
    lone = obs.subset((cam == 0) | (frame == 5))
    assert frame_sample(lone, 4, 2, 1) is None
    # a second board seen in frame 5 only: lost too
    board2 = np.where(frame == 5, 1, 0)
    assert frame_sample(Observations(cam, frame, board2, obs.p_board, obs.uv, frame), 4, 2, 2) is None


def test_own_view_poses_are_not_handed_over_after_a_flip_or_without_own_views():
    """own_view_poses: None when a chessboard's corner order was flipped after the own-views
    solves (their poses would be of the other order) or when a camera has no own-views fit;
    else one pose per view of the observations, its own fit's where it has one."""
    from types import SimpleNamespace as NS

    from rigcal.camcal import pipeline
    from rigcal.core.observations import BoardView

    views = (BoardView("a", "f0", "b0", np.arange(4), np.zeros((4, 2))),
             BoardView("b", "f0", "b0", np.arange(4), np.zeros((4, 2))))
    start = (np.eye(4), 2 * np.eye(4))
    posed = pipeline.PosedViews(views=views, cam=(0, 1), frame=(0, 0), board=(0, 0), T_cam_board=start,
                                rms_px=(0.1, 0.1))
    graph = NS(graph=NS(missing_boards=[], frame_posed=[True]))
    own_pose = 3 * np.eye(4)
    own = [NS(T_cam_board={("f0", "b0"): own_pose}), NS(T_cam_board={})]
    T = pipeline.own_view_poses(NS(flips=0, posed=posed), graph, own)
    assert T.shape == (2, 4, 4) and np.array_equal(T[0], own_pose) and np.array_equal(T[1], start[1])
    assert pipeline.own_view_poses(NS(flips=1, posed=posed), graph, own) is None
    assert pipeline.own_view_poses(NS(flips=0, posed=posed), graph, [own[0], None]) is None
