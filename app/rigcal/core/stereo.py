"""Stereo pairs: rectification with OpenCV's stereoRectify, rectified pixels, Z = B f / d.

OpenCV's pair convention is x_right = R x_left + T, i.e. (R, T) = T_right_left.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rigcal.core import geometry as geo


@dataclass(frozen=True, eq=False)
class StereoRectification:
    """R1, R2 rotate each camera's frame into the common rectified frame; P1, P2 are
    the rectified projections (P2[0, 3] = -f B); Q reprojects disparity to depth."""

    left: str
    right: str
    T_right_left: np.ndarray
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    size: tuple[int, int]

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T_right_left[:3, 3]))

    @property
    def f(self) -> float:
        return float(self.P1[0, 0])


def rectify_pair(cam_left, cam_right, alpha: float = -1.0) -> StereoRectification:
    """cv2.stereoRectify (or cv2.fisheye.stereoRectify) for two posed rig cameras."""
    if cam_left.T_body_cam is None or cam_right.T_body_cam is None:
        raise ValueError(f"stereo pair {cam_left.name}/{cam_right.name}: both cameras need a pose")
    T_right_left = geo.inv_T(cam_right.T_body_cam) @ cam_left.T_body_cam
    if np.linalg.norm(T_right_left[:3, 3]) < 1e-9:
        raise ValueError(f"stereo pair {cam_left.name}/{cam_right.name}: the cameras are at the same position")
    # OpenCV 5's fisheye code refuses non-contiguous views ("matrix is not continuous").
    R, T = np.ascontiguousarray(T_right_left[:3, :3]), np.ascontiguousarray(T_right_left[:3, 3].reshape(3, 1))
    mL, mR = cam_left.intrinsics, cam_right.intrinsics
    size = (mL.width, mL.height)
    if mL.model == "fisheye" and mR.model == "fisheye":
        R1, R2, P1, P2 = cv2.fisheye.stereoRectify(
            mL.K, mL.D.reshape(1, -1), mR.K, mR.D.reshape(1, -1), size, R, T,
            flags=cv2.CALIB_ZERO_DISPARITY, balance=0.0, fov_scale=1.0)[:4]
        P1, P2, Q = _fisheye_rectified_projections(P2, min(mL.fx, mL.fy, mR.fx, mR.fy), mL.cx, mL.cy)
    else:
        R1, R2, P1, P2, Q = cv2.stereoRectify(
            mL.K, _cv_dist(mL), mR.K, _cv_dist(mR), size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha)[:5]
    return StereoRectification(cam_left.name, cam_right.name, T_right_left, R1, R2, P1, P2, Q, size)


def _fisheye_rectified_projections(P2_cv: np.ndarray, f: float, cx: float, cy: float):
    """Rectified P1, P2 (3, 4) and Q (4, 4) with focal f at (cx, cy), keeping OpenCV's
    rectified baseline direction from P2_cv.

    OpenCV fits the whole field of view into the rectified image; for a ~180 degree lens
    that shrinks f to a few pixels, and rectified disparities (and their vertical RMS)
    would shrink with it. Keeping the lens's own central focal keeps pixels comparable."""
    t_rect = P2_cv[:2, 3] / np.diag(P2_cv)[:2]  # rectified right-camera offset (x or y), metres
    P1 = np.array([[f, 0.0, cx, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    P2 = P1.copy()
    P2[:2, 3] = f * t_rect
    t_base = t_rect[0] if abs(t_rect[0]) >= abs(t_rect[1]) else t_rect[1]
    Q = np.array([[1.0, 0.0, 0.0, -cx], [0.0, 1.0, 0.0, -cy], [0.0, 0.0, 0.0, f], [0.0, 0.0, -1.0 / t_base, 0.0]])
    return P1, P2, Q


def _cv_dist(m) -> np.ndarray:
    # OpenCV's pinhole functions take 4, 5, 8, 12 or 14 coefficients; 2 is padded.
    d = m.D if m.model == "pinhole" else np.zeros(5)
    if len(d) == 2:
        d = np.concatenate([d, [0.0, 0.0]])
    return d.reshape(1, -1)


def rectified_from_ray(rect: StereoRectification, rays_cam: np.ndarray, side: str) -> np.ndarray:
    """Camera-frame rays or points (N, 3) of one side -> rectified pixels (N, 2)."""
    R, P = (rect.R1, rect.P1) if side == "left" else (rect.R2, rect.P2)
    q = rays_cam @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.column_stack([P[0, 0] * q[:, 0] / q[:, 2] + P[0, 2], P[1, 1] * q[:, 1] / q[:, 2] + P[1, 2]])


def rectify_pixels(rect: StereoRectification, cam, uv: np.ndarray, side: str) -> np.ndarray:
    """Raw pixels of one camera -> rectified pixels, via the exact unprojection of its model."""
    return rectified_from_ray(rect, cam.intrinsics.unproject(uv), side)


@dataclass(frozen=True)
class StereoDepth:
    """Per point (N,): rectified pixels (N, 2), disparity d = u_left - u_right (px), depth
    Z = B f / d (m; NaN where d <= 0), and the true rectified depth (the left rectified
    frame's z) for comparison; plus the pair's B (m) and rectified f (px)."""

    uv_left: np.ndarray
    uv_right: np.ndarray
    disparity: np.ndarray
    depth: np.ndarray
    z_rect: np.ndarray
    baseline_m: float
    f: float


def depth_from_disparity(rect: StereoRectification, disparity: np.ndarray) -> np.ndarray:
    """Z = B f / d for disparities (N,); NaN where d <= 0 (at infinity or behind)."""
    d = np.asarray(disparity, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d > 0, rect.baseline_m * rect.f / np.where(d > 0, d, 1.0), np.nan)


def stereo_depth_in_left(rect: StereoRectification, p_left: np.ndarray) -> StereoDepth:
    """Points (N, 3) in the left camera frame -> disparity and depth in the rectified frame."""
    p_left = np.atleast_2d(np.asarray(p_left, dtype=float))
    p_right = geo.transform(rect.T_right_left, p_left)
    uv_l = rectified_from_ray(rect, p_left, "left")
    uv_r = rectified_from_ray(rect, p_right, "right")
    disp = uv_l[:, 0] - uv_r[:, 0]
    z_rect = (p_left @ rect.R1.T)[:, 2]
    return StereoDepth(uv_l, uv_r, disp, depth_from_disparity(rect, disp), z_rect, rect.baseline_m, rect.f)


def stereo_depth_of_points(rect: StereoRectification, p_body: np.ndarray, rig) -> StereoDepth:
    """Body-frame points (N, 3) -> disparity and depth in the pair's rectified frame."""
    T_left_body = geo.inv_T(rig.camera(rect.left).T_body_cam)
    return stereo_depth_in_left(rect, geo.transform(T_left_body, np.atleast_2d(p_body)))
