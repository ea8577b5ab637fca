"""Stereo pairs: rectification with OpenCV's stereoRectify, rectified pixels, Z = B f / d.

OpenCV's pair convention is x_right = R x_left + T, i.e. (R, T) = T_right_left.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from . import geometry as geo


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
    T_rl = geo.inv_T(cam_right.T_body_cam) @ cam_left.T_body_cam
    R, T = T_rl[:3, :3], T_rl[:3, 3].reshape(3, 1)
    mL, mR = cam_left.intrinsics, cam_right.intrinsics
    size = (mL.width, mL.height)
    if mL.model == "fisheye" and mR.model == "fisheye":
        R1, R2, P1, P2, Q = cv2.fisheye.stereoRectify(
            mL.K, mL.D.reshape(1, -1), mR.K, mR.D.reshape(1, -1), size, R, T,
            flags=cv2.CALIB_ZERO_DISPARITY, balance=0.0, fov_scale=1.0)[:5]
    else:
        R1, R2, P1, P2, Q = cv2.stereoRectify(
            mL.K, _cv_dist(mL), mR.K, _cv_dist(mR), size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha)[:5]
    return StereoRectification(cam_left.name, cam_right.name, T_rl, R1, R2, P1, P2, Q, size)


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
    """Per point: rectified pixels, disparity d = u_left - u_right (px), depth Z = B f / d (m),
    and the true rectified depth (the left rectified frame's z) for comparison."""

    uv_left: np.ndarray
    uv_right: np.ndarray
    disparity: np.ndarray
    depth: np.ndarray
    z_rect: np.ndarray


def depth_from_disparity(rect: StereoRectification, disparity: np.ndarray) -> np.ndarray:
    d = np.asarray(disparity, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(d > 0, rect.baseline_m * rect.f / np.where(d > 0, d, 1.0), np.nan)


def stereo_depth_of_points(rect: StereoRectification, p_body: np.ndarray, rig=None) -> StereoDepth:
    """Body-frame points (N, 3) -> disparity and depth in the pair's rectified frame."""
    from_left = rect.T_right_left  # x_right = T_right_left x_left
    T_left_body = None
    if rig is not None:
        T_left_body = geo.inv_T(rig.camera(rect.left).T_body_cam)
    else:
        raise ValueError("stereo_depth_of_points needs the rig")
    p_left = geo.transform(T_left_body, np.atleast_2d(p_body))
    p_right = geo.transform(from_left, p_left)
    uv_l = rectified_from_ray(rect, p_left, "left")
    uv_r = rectified_from_ray(rect, p_right, "right")
    disp = uv_l[:, 0] - uv_r[:, 0]
    z_rect = (p_left @ rect.R1.T)[:, 2]
    return StereoDepth(uv_l, uv_r, disp, depth_from_disparity(rect, disp), z_rect)
