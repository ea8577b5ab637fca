"""Initialisation: the hand-eye start for a camera whose boards no other camera sees."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import rigcal
from rigcal.core import geometry as geo
from rigcal.results.compare import compare_rigs
from rigcal.camcal.pipeline import calibrate_views
from rigcal.core.observations import BoardView
from rigcal.errors import CalibrationError
from rigcal.camcal.pose_graph import hand_eye

from tests.support.synthetic_obs import noisy_room, perturb


def _motion(rng, n: int, tilt_deg: float, yaw_deg: float = 30.0) -> np.ndarray:
    """n body poses (n, 4, 4): yaw spread yaw_deg, pitch and roll spread tilt_deg."""
    rv = np.column_stack([rng.normal(0, np.radians(tilt_deg), n), rng.normal(0, np.radians(tilt_deg), n),
                          rng.normal(0, np.radians(yaw_deg), n)])
    return np.array([geo.make_T(geo.R_from_rotvec(r), rng.normal(0, 0.5, 3)) for r in rv])


def _views_of_static_board(T_world_body, T_body_cam, T_world_board, rng, deg=0.1, m=0.002):
    """T_cam_board per frame with PnP-sized noise (rotation deg, translation m)."""
    out = []
    for T in T_world_body:
        T_cb = geo.inv_T(T @ T_body_cam) @ T_world_board
        noise = geo.make_T(geo.R_from_rotvec(rng.normal(0, np.radians(deg), 3)), rng.normal(0, m, 3))
        out.append(noise @ T_cb)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hand_eye_recovers_the_camera_pose(seed):
    rng = np.random.default_rng(seed)
    X = geo.make_T(geo.R_from_rotvec(rng.normal(0, 2, 3)), rng.normal(0, 0.2, 3))
    T_wb = geo.make_T(geo.R_from_rotvec(rng.normal(0, 2, 3)), rng.normal(0, 3, 3))
    TwB = _motion(rng, 15, tilt_deg=10)
    Y = hand_eye(TwB, _views_of_static_board(TwB, X, T_wb, rng))
    assert Y is not None
    # a start for the bundle adjustment: PnP noise of 0.1 deg / 2 mm per view
    assert geo.rotation_angle_deg(Y[:3, :3].T @ X[:3, :3]) < 0.3
    assert np.linalg.norm(Y[:3, 3] - X[:3, 3]) < 0.02
    # exact data give the exact answer
    Z = hand_eye(TwB, _views_of_static_board(TwB, X, T_wb, rng, deg=0.0, m=0.0))
    assert np.allclose(Z, X, atol=1e-9)


def test_hand_eye_survives_a_wrong_view():
    rng = np.random.default_rng(5)
    X = geo.make_T(geo.R_from_rotvec([0.0, np.pi, 0.0]), [-0.2, 0.0, 0.05])
    T_wb = geo.make_T(np.eye(3), [-3.0, 0.0, 0.0])
    TwB = _motion(rng, 15, tilt_deg=10)
    T_cb = _views_of_static_board(TwB, X, T_wb, rng)
    T_cb[4] = geo.make_T(geo.R_from_rotvec([0.3, 0.0, 0.0]), [0.1, 0.0, 0.0]) @ T_cb[4]  # a flipped PnP
    Y = hand_eye(TwB, T_cb)
    assert geo.rotation_angle_deg(Y[:3, :3].T @ X[:3, :3]) < 0.5
    assert np.linalg.norm(Y[:3, 3] - X[:3, 3]) < 0.03


def test_hand_eye_pairs_frames_only_within_a_board():
    """Two boards, each seen in a few frames: every pair of frames showing the same board
    is an AX = XB equation; a pair across boards is not (their poses differ)."""
    rng = np.random.default_rng(8)
    X = geo.make_T(geo.R_from_rotvec([0.0, np.pi, 0.0]), [-0.2, 0.0, 0.05])
    T_wb = [geo.make_T(geo.R_from_rotvec(rng.normal(0, 2, 3)), rng.normal(0, 3, 3)) for _ in range(2)]
    TwB = _motion(rng, 8, tilt_deg=10)
    board = np.array([0, 1] * 4)
    T_cb = np.array([_views_of_static_board(TwB[k:k + 1], X, T_wb[board[k]], rng, deg=0.0, m=0.0)[0]
                     for k in range(8)])
    assert np.allclose(hand_eye(TwB, T_cb, board), X, atol=1e-9)
    # one board's four frames alone also place it; across boards there are no equations
    assert np.allclose(hand_eye(TwB[board == 0], T_cb[board == 0]), X, atol=1e-9)
    assert hand_eye(TwB[:2], T_cb[:2], board[:2]) is None


def test_hand_eye_refuses_rotation_about_one_axis():
    """Yaw only: the camera's rotation about the yaw axis and its height are not
    determined, so there is no start rather than a wrong one."""
    rng = np.random.default_rng(3)
    X = geo.make_T(geo.R_from_rotvec([0.0, np.pi, 0.0]), [-0.2, 0.0, 0.05])
    TwB = _motion(rng, 15, tilt_deg=0.0)
    assert hand_eye(TwB, _views_of_static_board(TwB, X, np.eye(4), rng, deg=0.0, m=0.0)) is None


@pytest.mark.slow
def test_camera_sharing_no_board_calibrates_from_the_rig_motion():
    """dataset.md lets a board be seen by one camera only: the back camera's boards are
    renamed so no front camera ever sees them. The frames are synchronised, so the rig's
    motion (posed by the front pair) places the back camera (AX = XB), and the bundle
    adjustment then recovers it as well as when the boards are shared."""
    drone = rigcal.load_rig("rigs/drone-stereo-back.yaml")
    rng = np.random.default_rng(21)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=30)
    lonely = [BoardView(v.camera, v.frame, "back_" + v.board, v.ids, v.uv) if v.camera == "back" else v
              for v in views]
    corners = dict(corners, **{"back_" + b: p for b, p in corners.items()})
    cal_shared, cal_alone = calibrate_views(views, drone, corners), calibrate_views(lonely, drone, corners)
    assert not any("hand-eye" in n for n in cal_shared.notes)
    assert any(n.startswith("back: no other camera sees its boards") for n in cal_alone.notes), cal_alone.notes
    shared = compare_rigs(cal_shared.rig, truth)["pairs"]
    alone = compare_rigs(cal_alone.rig, truth)["pairs"]
    for pair, e in alone.items():
        # the bounds of the shared-board round trip (test_solve): with shared boards this scene
        # gives 0.002-0.015 deg / 0.1-0.4 mm, with the back camera's boards its own 0.002-0.022 / 0.1-0.65
        assert e["rot_deg"] < 0.03 and e["trans_mm"] < 1.0, (pair, e, shared[pair])


def test_camera_whose_views_contradict_the_rig_motion_is_named():
    """The back camera sees the same image of a board it alone sees while the rig moves:
    no pose explains that, so hand-eye gives no start and the camera is named. Each copy
    carries its own corner noise, as photographs do (bit-identical copies are counted
    once before any of this: test_faults.test_repeated_images_count_once)."""
    drone = rigcal.load_rig("rigs/drone-stereo-back.yaml")
    rng = np.random.default_rng(22)
    truth = perturb(drone, rng)
    views, corners = noisy_room(truth, rng, 0.05, n_frames=12)
    frames = sorted({v.frame for v in views})
    back = [v for v in views if v.camera == "back"]
    one = back[0]
    lonely = [v for v in views if v.camera != "back"] + [
        BoardView("back", f, "back_" + one.board, one.ids, one.uv + rng.normal(0, 0.05, one.uv.shape))
        for f in frames[:6]]
    corners = dict(corners, **{"back_" + b: p for b, p in corners.items()})
    with pytest.raises(CalibrationError, match=r"back: .*never linked to the rest of the rig"):
        calibrate_views(lonely, drone, corners)


def test_pinhole_start_is_the_same_run_to_run_and_leaves_opencv_threads_alone():
    """cv2.calibrateCamera sums per-view terms in parallel in the order threads finish;
    fit_pinhole runs it on one thread so the same corners give the same start, bit for bit
    (results of one process compared, so exact equality is the claim)."""
    import cv2

    from rigcal.camcal.initialise import fit_pinhole

    rng = np.random.default_rng(3)
    truth = perturb(rigcal.load_rig("drone-stereo-back"), rng)
    views, corners = noisy_room(truth, rng, 0.3, n_frames=25)
    mine = [v for v in views if v.camera == "front_left" and len(v.ids) >= 8]
    obj = [corners[v.board][np.asarray(v.ids)] for v in mine]
    img = [np.asarray(v.uv, float) for v in mine]
    before = cv2.getNumThreads()
    fits = [fit_pinhole(obj, img, truth.camera("front_left").intrinsics, 5) for _ in range(4)]
    assert cv2.getNumThreads() == before
    for f in fits[1:]:
        assert np.array_equal(f.values, fits[0].values) and f.rms_px == fits[0].rms_px


def test_own_views_fit_is_capped_at_max_mono_views(monkeypatch):
    """mono() (own-views intrinsics for a rig whose frames are not rigid) hands OpenCV at
    most MAX_MONO_VIEWS views: its solver is dense in the views, and 600 views a camera
    took 270 s of a 313 s calibrate. The capped fit still lands near the truth."""
    from rigcal.camcal import initialise

    rng = np.random.default_rng(5)
    truth = perturb(rigcal.load_rig("drone-stereo-back"), rng)
    views, corners = noisy_room(truth, rng, 0.3, n_frames=25)
    mine = [v for v in views if v.camera == "front_left"]
    cap = 10
    assert len(mine) > 2 * cap
    sizes = []
    fit = initialise.fit_pinhole

    def spy(obj, img, model, n_dist):
        sizes.append(len(obj))
        return fit(obj, img, model, n_dist)

    monkeypatch.setattr(initialise, "MAX_MONO_VIEWS", cap, raising=False)
    monkeypatch.setattr(initialise, "fit_pinhole", spy)
    declared = truth.camera("front_left").intrinsics
    mi = initialise.init_camera(mine, corners, declared, "auto", False)
    sizes.clear()
    values, line = mi.mono()
    assert sizes and max(sizes) <= cap
    assert abs(values[0] - declared.fx) < 0.01 * declared.fx and abs(values[2] - declared.cx) < 5.0


def _pnp_scene(seed: int, n: int = 12):
    """A distorted camera (rigs/stereo-forward.yaml's first), an AprilGrid and n views of it
    with 0.1 px noise: (camera, intrinsic values, obj list, uv list, true T_cam_board list)."""
    from pathlib import Path

    from rigcal.core.target import parse_target
    from rigcal.sim.synthetic import board_view

    cam = rigcal.load_rig(Path(__file__).resolve().parents[2] / "rigs" / "stereo-forward.yaml").cameras[0]
    board = parse_target("boards:\n  - {name: g, type: aprilgrid, tags: [6, 6], tag_size: 0.088, "
                         "tag_spacing: 0.3}\n").boards[0]
    rng = np.random.default_rng(seed)
    obj, img, truth = [], [], []
    while len(obj) < n:
        T = geo.make_T(geo.R_from_rotvec(np.array([np.pi, 0, 0]) + rng.normal(0, 0.3, 3)),
                       np.array([-0.3, -0.3, 1.0]) + rng.normal(0, 0.1, 3))
        seen = board_view(cam, T, board.corners, 20)
        if seen is None:
            continue
        ids, uv = seen
        obj.append(board.corners[ids])
        img.append(uv + rng.normal(0, 0.1, uv.shape))
        truth.append(T)
    m = cam.intrinsics
    return cam, np.array([m.fx, m.fy, m.cx, m.cy, *m.dist]), obj, img, truth, board.print_face


def test_pnp_views_poses_each_view_and_a_views_pose_does_not_depend_on_the_others():
    import rigcal.camcal.initialise as ini

    cam, vals, obj, img, truth, face = _pnp_scene(4)
    faces = [face] * len(obj)
    fresh = ini.pnp_views(obj, img, vals, cam.intrinsics.model, faces)
    for (T, rms), T_true in zip(fresh, truth):  # known answer: the true poses, to the noise
        assert np.degrees(np.linalg.norm(geo.rotvec_from_R(T[:3, :3] @ T_true[:3, :3].T))) < 0.5
        assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.01 and 0.05 < rms < 0.2  # px: 0.1 px per axis
    # every other view again, among views posed with other intrinsics: identical poses
    other = ini.pnp_views(obj[::2], img[::2], vals * [1.01, 1.01, 1, 1, 1, 1, 1, 1, 1][:len(vals)],
                          cam.intrinsics.model, faces[::2])
    half = ini.pnp_views(obj[::2], img[::2], vals, cam.intrinsics.model, faces[::2])
    again = ini.pnp_views(obj, img, vals, cam.intrinsics.model, faces)
    for got in (half, again[::2], again):
        ref = fresh[: len(got)] if got is again else fresh[::2]
        assert all(np.array_equal(a[0], b[0]) and a[1] == b[1] for a, b in zip(got, ref))
    assert not np.array_equal(other[0][0], fresh[0][0])  # other intrinsics: posed anew
    again[0][0][:] = 0.0  # the caller's copy, not shared with a later call
    assert np.array_equal(ini.pnp_views(obj[:1], img[:1], vals, cam.intrinsics.model, faces[:1])[0][0], fresh[0][0])


@pytest.mark.parametrize("k3", [None, 0.05])
def test_own_views_start_makes_monos_k3_decision_without_opencv(monkeypatch, k3):
    """own_views_start (calibrate_views' imu_start: a camera-IMU step follows) fits the
    same up to MAX_MONO_VIEWS views as mono() by rigcal's sparse solve instead of OpenCV's
    dense one: the same k3 decision (dropped on a small k3, kept on a large one) on about
    the same Wald statistic, no OpenCV fit, and the own-views solve over every view lands
    on the same intrinsics from either start (within the solver's convergence)."""
    import re

    from rigcal.camcal import initialise
    from rigcal.camcal.solve import Intrinsics

    rng = np.random.default_rng(5)
    truth = perturb(rigcal.load_rig("drone-stereo-back"), rng)
    if k3 is not None:
        m = truth.camera("front_left").intrinsics
        truth = truth.with_cameras([c if c.name != "front_left" else replace(c, intrinsics=m.with_(
            dist=(*m.dist[:4], k3))) for c in truth.cameras])
    views, corners = noisy_room(truth, rng, 0.3, n_frames=25)
    mine = [v for v in views if v.camera == "front_left"]
    declared = truth.camera("front_left").intrinsics
    mi = initialise.init_camera(mine, corners, declared, "auto", False)
    monkeypatch.setattr(initialise, "MAX_MONO_VIEWS", 15)  # fewer than the camera's views: a selection
    slow, slow_line = mi.mono()
    fits = []
    fit = initialise.fit_pinhole
    monkeypatch.setattr(initialise, "fit_pinhole", lambda o, i, m, n: fits.append(n) or fit(o, i, m, n))
    quick, quick_line = initialise.own_views_start(mine, corners, Intrinsics("pinhole", mi.values.copy()), "auto")
    assert not fits
    assert ("kept" in quick_line) == ("kept" in slow_line) == (k3 is not None) and len(quick) == len(slow)
    wald = [float(re.search(r"Wald ([0-9.]+)", x).group(1)) for x in (slow_line, quick_line)]
    assert abs(wald[0] - wald[1]) <= 0.2 * max(wald[0], 1.0)
    own = [initialise.own_views_intrinsics(mine, corners, Intrinsics("pinhole", np.array(v, float)),
                                           (declared.cx, declared.cy), "auto") for v in (slow, quick)]
    assert own[0].log == own[1].log
    sigma = np.sqrt(np.diag(own[0].cov))
    # the same values, to well under a hundredth of their sigma
    assert np.all(np.abs(own[0].intrinsics.values - own[1].intrinsics.values) <= 0.01 * sigma)  # held: 0


def test_start_poses_are_handed_over_only_when_made_with_the_final_intrinsics():
    """Calibration.view_T_cam_board (the camera-IMU start's poses, one per view of obs): the
    camera-only start's PnP, kept when the intrinsics are held (the start's are then the
    final ones); with them estimated, None (the camera-IMU step poses with the solved ones)."""
    rng = np.random.default_rng(2)
    truth = perturb(rigcal.load_rig("drone-stereo-back"), rng)
    views, corners = noisy_room(truth, rng, 0.2, n_frames=12)
    held = calibrate_views(views, truth, corners, fix_intrinsics=True)
    T = held.view_T_cam_board
    assert T is not None and T.shape == (held.obs.view.max() + 1, 4, 4)
    # each view's start pose reprojects its corners near where they were seen
    for v in (0, len(T) // 2, len(T) - 1):
        k = held.obs.view == v
        cam = truth.camera(held.cam_names[int(held.obs.cam[k][0])]).intrinsics
        uv, _ = cam.project(geo.transform(T[v], held.obs.p_board[k]))
        assert np.sqrt(np.mean(np.sum((uv - held.obs.uv[k]) ** 2, axis=1))) < 1.0
    assert calibrate_views(views, truth, corners).view_T_cam_board is None
