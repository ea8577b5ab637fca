"""rigcal.sim.synthetic: noise-free views re-project exactly through the truth (checked through
Rig.project, another code path), every view a detector could see is there and no edge or
grazing view is, seeded determinism, and with_noise's noise."""

from __future__ import annotations

import numpy as np
import pytest

import rigcal
from rigcal.core import geometry as geo
from rigcal.sim.synthetic import BOARD, board_view, grid_corners, room_scene, with_noise

RIG = "rigs/drone-stereo-back.yaml"
FRAMES = 8


@pytest.fixture(scope="module")
def scene():
    return room_scene(rigcal.load_rig(RIG), np.random.default_rng(21), FRAMES)


def test_grid_corners_row_major():
    P = grid_corners(3, 2, 0.1)
    np.testing.assert_allclose(P, [[0.1, 0.1, 0], [0.2, 0.1, 0], [0.3, 0.1, 0],
                                   [0.1, 0.2, 0], [0.2, 0.2, 0], [0.3, 0.2, 0]], atol=1e-15)


def test_views_reproject_exactly_through_the_truth(scene):
    assert len(scene.views) > FRAMES and set(scene.T_world_body) == {f"{f:06d}" for f in range(FRAMES)}
    for v in scene.views:
        p_world = geo.transform(scene.T_world_board[v.board], scene.corners[v.board][v.ids])
        seen = scene.rig.project(p_world, scene.T_world_body[v.frame])[v.camera]
        assert seen.in_image.all()
        np.testing.assert_allclose(v.uv, seen.uv, atol=1e-9, rtol=0)
    truth = scene.truth
    assert truth.rig is scene.rig and truth.board_pose("000003", "b2") is scene.T_world_board["b2"]


def test_kept_views_are_the_detectable_ones(scene):
    """Recount every (frame, camera, board) by hand: a view is present exactly when at least
    8 corners are inside the image (2 px margin), and it holds exactly those corners. (The
    walls face the rig, which stays near the room's centre: no view here is grazing.)"""
    kept = {(v.frame, v.camera, v.board): v for v in scene.views}
    for frame, T_w_body in scene.T_world_body.items():
        for cam in scene.rig.cameras:
            for board, T_w_board in scene.T_world_board.items():
                pr = scene.rig.project(geo.transform(T_w_board, scene.corners[board]), T_w_body)[cam.name]
                ok = pr.valid & cam.intrinsics.in_image(pr.uv, margin=2.0)
                v = kept.pop((frame, cam.name, board), None)
                if ok.sum() < 8:
                    assert v is None, (frame, cam.name, board)
                else:
                    assert v is not None and np.array_equal(v.ids, np.nonzero(ok)[0]), (frame, cam.name, board)
    assert not kept


@pytest.mark.parametrize("tilt_deg, kept", [(60.0, True), (74.0, True), (77.0, False), (85.0, False)])
def test_grazing_board_is_dropped(tilt_deg, kept):
    """A whole board straight ahead, turned about its vertical axis: seen at more than
    acos(0.25) = 75.5 deg from its normal it is dropped, though all its corners are in the image."""
    cam = rigcal.load_rig("rigs/stereo-forward.yaml").cameras[0]
    P = grid_corners(*BOARD)
    R_cam_board = geo.R_from_rotvec([0.0, np.radians(tilt_deg), 0.0])
    T_cam_board = geo.make_T(R_cam_board, np.array([0.0, 0.0, 2.0]) - R_cam_board @ P.mean(0))
    uv, valid = cam.intrinsics.project(geo.transform(T_cam_board, P))
    assert (valid & cam.intrinsics.in_image(uv, margin=2.0)).all()
    seen = board_view(cam, T_cam_board, P, min_corners=8)
    assert (seen is not None) == kept
    if kept:
        np.testing.assert_array_equal(seen[0], np.arange(len(P)))
        np.testing.assert_allclose(seen[1], uv, atol=1e-12)


def test_seeded_and_deterministic():
    rig = rigcal.load_rig(RIG)
    a, b = (room_scene(rig, np.random.default_rng(5), 4, board=(6, 5, 0.2)) for _ in range(2))
    c = room_scene(rig, np.random.default_rng(6), 4, board=(6, 5, 0.2))
    key = lambda s: [(v.camera, v.frame, v.board, v.ids.tobytes(), v.uv.tobytes()) for v in s.views]  # noqa: E731
    assert key(a) == key(b) and key(a) != key(c)
    assert len(a.corners["b0"]) == 30 and len(grid_corners(*BOARD)) == 70


def test_with_noise_is_seeded_gaussian_and_keeps_the_views(scene):
    n1 = with_noise(scene.views, 0.2, np.random.default_rng(1))
    n2 = with_noise(scene.views, 0.2, np.random.default_rng(1))
    assert all(np.array_equal(x.uv, y.uv) for x, y in zip(n1, n2))
    d = np.concatenate([x.uv - v.uv for x, v in zip(n1, scene.views)])
    assert len(d) > 1000 and d.std() == pytest.approx(0.2, rel=0.05) and abs(d.mean()) < 0.02
    assert [(x.camera, x.frame, x.board) for x in n1] == [(v.camera, v.frame, v.board) for v in scene.views]
    assert all(x.ids is v.ids for x, v in zip(n1, scene.views))
    assert all(np.array_equal(x.uv, v.uv) for x, v in zip(with_noise(scene.views, 0.0, np.random.default_rng(1)),
                                                             scene.views))
