"""Camera models against OpenCV (cv2.projectPoints, cv2.fisheye.projectPoints), their
invalid regions, unprojection round trips, and stereo rectification against
cv2.stereoRectify + cv2.undistortPoints."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.core.rig import Camera
from rigcal.core.stereo import rectify_pair, rectify_pixels, stereo_depth_in_left

PX_TOL = 1e-9
RAY_TOL = 1e-9

# Mild but non-trivial coefficients per OpenCV pinhole model length.
PINHOLE_DIST = {
    2: (-0.21, 0.04),
    4: (-0.21, 0.04, 0.0012, -0.0009),
    5: (-0.21, 0.04, 0.0012, -0.0009, 0.01),
    8: (-0.21, 0.04, 0.0012, -0.0009, 0.01, 0.03, -0.01, 0.005),
    12: (-0.21, 0.04, 0.0012, -0.0009, 0.01, 0.03, -0.01, 0.005, 0.001, -0.0007, 0.0005, 0.0003),
}
FISHEYE_DIST = (0.02, -0.01, 0.003, -0.0006)


def pinhole(n: int) -> CameraModel:
    return CameraModel("pinhole", 1280, 800, 910.5, 905.25, 641.3, 398.7, PINHOLE_DIST[n])


def fisheye(dist=FISHEYE_DIST) -> CameraModel:
    return CameraModel("fisheye", 800, 800, 251.0, 250.5, 401.2, 398.9, dist)


def opencv_dist(m: CameraModel) -> np.ndarray:
    """OpenCV takes 4, 5, 8, 12 or 14 pinhole coefficients: pad 2 with p1 = p2 = 0."""
    d = np.array(m.dist, dtype=float)
    return np.concatenate([d, [0.0, 0.0]]) if len(d) == 2 else d


def points_in_view(rng: np.random.Generator, n: int, half_angle_deg: float) -> np.ndarray:
    """(n, 3) points in front of the camera, within half_angle_deg of the axis, 0.3-20 m away."""
    theta = np.radians(half_angle_deg) * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return rays * rng.uniform(0.3, 20, n)[:, None]


# ----------------------------------------------------------------------------- projection vs OpenCV


@pytest.mark.parametrize("n", sorted(PINHOLE_DIST))
def test_pinhole_projection_matches_opencv(n):
    m = pinhole(n)
    p_cam = points_in_view(np.random.default_rng(n), 2000, 40.0)
    uv, valid = m.project(p_cam)
    assert valid.all()
    uv_cv = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), m.K, opencv_dist(m))[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, uv_cv, atol=PX_TOL, rtol=0)


def test_fisheye_projection_matches_opencv():
    m = fisheye()
    p_cam = points_in_view(np.random.default_rng(1), 2000, 89.0)  # OpenCV's model stops at 90 deg
    uv, valid = m.project(p_cam)
    assert valid.all()
    uv_cv = cv2.fisheye.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), m.K, m.D)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, uv_cv, atol=PX_TOL, rtol=0)


def test_projection_of_a_pose_matches_opencv_rvec_tvec():
    # the same through a camera pose: p_cam = R_cam_board p_board + t_cam_board
    rng = np.random.default_rng(4)
    m = pinhole(5)
    rt_cam_board = np.array([0.1, -0.2, 0.05, 0.1, -0.05, 3.0])
    p_board = rng.uniform(-0.5, 0.5, size=(200, 3))
    uv, valid = m.project(geo.transform(geo.T_from_rt(rt_cam_board), p_board))
    uv_cv = cv2.projectPoints(p_board, rt_cam_board[:3], rt_cam_board[3:], m.K, opencv_dist(m))[0].reshape(-1, 2)
    assert valid.all()
    np.testing.assert_allclose(uv, uv_cv, atol=PX_TOL, rtol=0)


def test_principal_point_and_pixel_centre_convention():
    m = CameraModel("pinhole", 640, 480, 300.0, 300.0, 319.5, 239.5)
    uv, _ = m.project([[0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(uv, [[319.5, 239.5]])  # the centre of a 640x480 image, pixel centres at integers
    assert m.in_image(np.array([[-0.5, -0.5], [639.5, 479.5]])).all()
    assert not m.in_image(np.array([[-0.51, 0.0], [0.0, 479.51]])).any()


# ----------------------------------------------------------------------------- invalid points


def assert_invalid(uv, valid, which):
    assert not valid[which].any()
    assert np.isnan(uv[which]).all()
    assert valid[~which].all() and np.isfinite(uv[~which]).all()


@pytest.mark.parametrize("m", [pinhole(5), pinhole(8), fisheye()], ids=["pinhole5", "pinhole8", "fisheye"])
def test_points_behind_the_camera_get_no_pixel(m):
    p = np.array([[0.1, 0.2, 1.0], [0.1, 0.2, -1.0], [0.0, 0.0, -2.0], [0.3, 0.1, 0.0], [0.0, 0.0, 0.0]])
    uv, valid = m.project(p)
    # a fisheye sees a point exactly at 90 degrees; nothing sees the pinhole itself
    side_on = m.model == "pinhole"
    assert_invalid(uv, valid, np.array([False, True, True, side_on, True]))


def test_pinhole_fold_back_is_invalid():
    # r_d = r (1 - 0.5 r^2) turns back at r = sqrt(2/3): past it two rays would share a pixel
    m = CameraModel("pinhole", 640, 480, 300, 300, 320, 240, (-0.5, 0.0, 0.0, 0.0, 0.0))
    r = np.array([0.2, 0.5, 0.8, 0.83, 1.0, 2.0])
    uv, valid = m.project(np.column_stack([r, np.zeros_like(r), np.ones_like(r)]))
    assert_invalid(uv, valid, r > np.sqrt(2 / 3))
    uv_cv = cv2.projectPoints(np.column_stack([r, 0 * r, 1 + 0 * r])[valid], np.zeros(3), np.zeros(3), m.K, m.D)[0]
    np.testing.assert_allclose(uv[valid], uv_cv.reshape(-1, 2), atol=PX_TOL)


def test_fisheye_past_its_field_of_view_is_invalid():
    m = fisheye()
    theta = np.radians([10, 80, 95, 105, 115, 150, 180])
    p = np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)])
    uv, valid = m.project(p)
    # rays up to the model's limit (110 deg) are seen, even past 90 deg; beyond it, none
    assert_invalid(uv, valid, theta > np.radians(110))


def test_fisheye_fold_back_is_invalid():
    # theta_d = theta (1 - 0.3 theta^2) turns back at theta = 1/sqrt(0.9)
    m = fisheye((-0.3, 0.0, 0.0, 0.0))
    theta = np.array([0.2, 0.8, 1.0, 1.06, 1.3])
    uv, valid = m.project(np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)]))
    assert_invalid(uv, valid, theta > 1 / np.sqrt(0.9))


# ----------------------------------------------------------------------------- unprojection


@pytest.mark.parametrize("m", [pinhole(n) for n in sorted(PINHOLE_DIST)] + [fisheye()],
                         ids=[f"pinhole{n}" for n in sorted(PINHOLE_DIST)] + ["fisheye"])
def test_unproject_inverts_project(m):
    half = 105.0 if m.model == "fisheye" else 45.0  # the fisheye sees past 90 degrees
    p_cam = points_in_view(np.random.default_rng(9), 3000, half)
    uv, valid = m.project(p_cam)
    assert valid.all()
    rays = m.unproject(uv)
    np.testing.assert_allclose(rays, p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True), atol=RAY_TOL, rtol=0)


@pytest.mark.parametrize("n", sorted(PINHOLE_DIST))
def test_unproject_far_off_axis(n):
    # 60-80 degrees off the axis, far outside the image: the distorted radius is hundreds
    # of times the true one, where Newton started at the pixel itself used to stall or
    # land on another preimage
    m = pinhole(n)
    rng = np.random.default_rng(100 + n)
    theta, phi = np.radians(rng.uniform(60, 80, 500)), rng.uniform(0, 2 * np.pi, 500)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    uv, valid = m.project(rays)
    assert valid.all() and not m.in_image(uv).any()
    np.testing.assert_allclose(m.unproject(uv), rays, atol=RAY_TOL, rtol=0)


def test_unproject_matches_opencv_undistort_points():
    m = pinhole(5)
    p_cam = points_in_view(np.random.default_rng(12), 500, 40.0)
    uv, _ = m.project(p_cam)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    xn_cv = cv2.undistortPoints(uv.reshape(-1, 1, 2), m.K, m.D, criteria=crit).reshape(-1, 2)
    rays = m.unproject(uv)
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:], xn_cv, atol=1e-9)


def test_unproject_gives_nan_where_the_model_has_no_inverse():
    # pixels beyond the largest radius the folded model reaches have no ray
    m = CameraModel("pinhole", 640, 480, 300, 300, 320, 240, (-0.5, 0.0, 0.0, 0.0, 0.0))
    r_max = np.sqrt(2 / 3) * (1 - 0.5 * 2 / 3)  # largest distorted radius
    uv = np.array([[320 + 300 * 0.5 * r_max, 240.0], [320 + 300 * 1.2 * r_max, 240.0]])
    rays = m.unproject(uv)
    assert np.isfinite(rays[0]).all() and np.isnan(rays[1]).all()
    fe = fisheye()
    rays = fe.unproject(np.array([[401.2, 398.9], [401.2 + 250 * 3.5, 398.9]]))  # theta_d = 3.5 rad: past 110 deg
    np.testing.assert_allclose(rays[0], [0, 0, 1], atol=1e-15)
    assert np.isnan(rays[1]).all()


# ----------------------------------------------------------------------------- stereo


def random_pair(rng: np.random.Generator) -> tuple[Camera, Camera]:
    """A non-trivial stereo pair: different intrinsics and distortion, a few degrees of
    relative rotation, a baseline of ~0.12 m mostly along the left camera's x."""
    def cam(name, t, rot_deg):
        m = CameraModel("pinhole", 1280, 800, rng.uniform(880, 920), rng.uniform(880, 920),
                        rng.uniform(630, 650), rng.uniform(390, 410),
                        (rng.uniform(-0.12, -0.05), rng.uniform(0.0, 0.05), rng.uniform(-1e-3, 1e-3),
                         rng.uniform(-1e-3, 1e-3), rng.uniform(-0.01, 0.01)))
        R = geo.R_from_look("forward") @ geo.R_from_rotvec(np.radians(rot_deg) * rng.normal(size=3))
        return Camera(name, m, geo.make_T(R, t))
    left = cam("left", [0.15, 0.06, 0.0], 1.5)
    right = cam("right", [0.15 + rng.uniform(-0.01, 0.01), -0.06, rng.uniform(-0.005, 0.005)], 1.5)
    return left, right


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rectified_pixels_match_opencv(seed):
    rng = np.random.default_rng(seed)
    left, right = random_pair(rng)
    rect = rectify_pair(left, right)
    T_rl = geo.inv_T(right.T_body_cam) @ left.T_body_cam
    R1, R2, P1, P2 = cv2.stereoRectify(left.intrinsics.K, left.intrinsics.D, right.intrinsics.K, right.intrinsics.D,
                                       (1280, 800), T_rl[:3, :3].copy(), T_rl[:3, 3].reshape(3, 1).copy(),
                                       flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)[:4]
    for ours, theirs in ((rect.R1, R1), (rect.R2, R2), (rect.P1, P1), (rect.P2, P2)):
        np.testing.assert_allclose(ours, theirs, atol=1e-12)
    # points in front of both cameras, 1-30 m, projected through each camera's own lens
    p_left = points_in_view(rng, 500, 25.0) * 1.5 + [0, 0, 1.0]
    p_right = geo.transform(T_rl, p_left)
    uv_l, ok_l = left.intrinsics.project(p_left)
    uv_r, ok_r = right.intrinsics.project(p_right)
    assert ok_l.all() and ok_r.all()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    rect_l_cv = cv2.undistortPoints(uv_l.reshape(-1, 1, 2), left.intrinsics.K, left.intrinsics.D, R=R1, P=P1,
                                    criteria=crit).reshape(-1, 2)
    rect_r_cv = cv2.undistortPoints(uv_r.reshape(-1, 1, 2), right.intrinsics.K, right.intrinsics.D, R=R2, P=P2,
                                    criteria=crit).reshape(-1, 2)
    sd = stereo_depth_in_left(rect, p_left)
    np.testing.assert_allclose(sd.uv_left, rect_l_cv, atol=1e-6)
    np.testing.assert_allclose(sd.uv_right, rect_r_cv, atol=1e-6)
    # the same rectified pixels from the raw pixels through our own unprojection
    np.testing.assert_allclose(rectify_pixels(rect, left, uv_l, "left"), sd.uv_left, atol=1e-6)
    np.testing.assert_allclose(rectify_pixels(rect, right, uv_r, "right"), sd.uv_right, atol=1e-6)
    # rectified rows agree, and Z = B f / d is the depth in the rectified frame
    np.testing.assert_allclose(sd.uv_left[:, 1], sd.uv_right[:, 1], atol=1e-9)
    np.testing.assert_allclose(sd.depth, sd.z_rect, rtol=1e-9)
    assert sd.baseline_m == pytest.approx(np.linalg.norm(T_rl[:3, 3]))


def test_fisheye_pair_depth_and_rows():
    rng = np.random.default_rng(21)
    R = geo.R_from_look("forward")
    left = Camera("left", fisheye(), geo.make_T(R, [0.12, 0.04, 0.0]))
    right = Camera("right", fisheye((0.015, -0.008, 0.002, -0.0005)),
                   geo.make_T(R @ geo.R_from_rotvec([0.01, -0.02, 0.005]), [0.12, -0.04, 0.003]))
    rect = rectify_pair(left, right)
    assert rect.f == pytest.approx(250.5)  # the lens's own focal, not a whole-hemisphere squeeze
    p_left = points_in_view(rng, 300, 50.0) + [0, 0, 1.0]
    sd = stereo_depth_in_left(rect, p_left)
    np.testing.assert_allclose(sd.uv_left[:, 1], sd.uv_right[:, 1], atol=1e-9)
    np.testing.assert_allclose(sd.depth, sd.z_rect, rtol=1e-9)
    # and the rectified pixels agree with OpenCV's fisheye undistortion onto (R1, P1)
    uv_l, ok = left.intrinsics.project(p_left)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    cv = cv2.fisheye.undistortPoints(uv_l[ok].reshape(-1, 1, 2), left.intrinsics.K, left.intrinsics.D,
                                     R=rect.R1, P=rect.P1, criteria=crit).reshape(-1, 2)
    np.testing.assert_allclose(sd.uv_left[ok], cv, atol=1e-6)


def test_rectify_refuses_a_pair_without_baseline_or_pose():
    m = pinhole(5)
    a = Camera("a", m, geo.make_T(np.eye(3), [0, 0, 0]))
    with pytest.raises(ValueError, match="same position"):
        rectify_pair(a, Camera("b", m, geo.make_T(np.eye(3), [0, 0, 0])))
    with pytest.raises(ValueError, match="pose"):
        rectify_pair(a, Camera("b", m, None))
