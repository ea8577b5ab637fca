"""A board pose seen off a fisheye's axis, shared by the detection and guided-pass tests."""

from __future__ import annotations

import math

import cv2
import numpy as np

from rigcal.core.target import Board


def fisheye_view(model, rays, tex, board: Board, off_deg: float, az: float, tilt_deg: float, dist: float):
    """R, t of a board whose centre lies off_deg from a fisheye's axis at azimuth az,
    turned tilt_deg away from facing the camera."""
    d = np.array([math.sin(math.radians(off_deg)) * math.cos(az), math.sin(math.radians(off_deg)) * math.sin(az),
                  math.cos(math.radians(off_deg))])
    x = np.cross([0.0, 1.0, 0.0], d)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(d, x), d])
    R = R @ cv2.Rodrigues(np.array([math.cos(az + 1), math.sin(az + 1), 0.0]) * math.radians(tilt_deg))[0]
    bw, bh = board.size_m
    return R, dist * d - R @ [bw / 2, bh / 2, 0]
