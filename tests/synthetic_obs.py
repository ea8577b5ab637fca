"""Synthetic corner observations (no rendering) for solver tests: exact projections of
known boards through a known rig, plus Gaussian pixel noise. Seeded."""

from __future__ import annotations

import numpy as np

from rigcal import geometry as geo
from rigcal.core import ViewIn
from rigcal.rig import Camera, Rig


def grid_corners(nx: int, ny: int, s: float) -> np.ndarray:
    k = np.arange(nx * ny)
    return np.column_stack([(k % nx + 1) * s, (k // nx + 1) * s, np.zeros(len(k))])


def perturb(rig: Rig, rng, mm=5.0, deg=1.0, focal=0.02, pp=5.0, dist=True) -> Rig:
    cams = []
    for c in rig.cameras:
        m = c.intrinsics
        T = c.T_body_cam.copy()
        T[:3, :3] = geo.R_from_rotvec(rng.normal(0, np.radians(deg), 3)) @ T[:3, :3]
        T[:3, 3] += rng.normal(0, mm / 1000, 3)
        if m.model == "fisheye":
            d = tuple(np.array(m.dist) + rng.normal(0, [0.01, 0.005, 0.002, 0.001]))
        else:
            d = (rng.normal(0, 0.05), rng.normal(0, 0.02), rng.normal(0, 5e-4), rng.normal(0, 5e-4),
                 rng.normal(0, 0.002)) if dist else m.dist
        f = 1 + rng.normal(0, focal)
        mm_ = m.with_(fx=m.fx * f, fy=m.fy * f * (1 + rng.normal(0, 0.001)), cx=m.cx + rng.uniform(-pp, pp),
                      cy=m.cy + rng.uniform(-pp, pp), dist=tuple(float(x) for x in d))
        cams.append(Camera(c.name, mm_, T))
    return rig.with_cameras(cams)


def room_scene(rig: Rig, rng, n_frames=50, n_boards=4, board=(10, 7, 0.14), dist=2.0, noise_px=0.05,
               min_corners=8):
    """Boards on the four walls around the rig; the rig turns through full yaw with +-20 deg
    pitch/roll. Returns (views, corners_by_board, T_world_board, T_world_body)."""
    nx, ny, s = board
    corners = grid_corners(nx, ny, s)
    centre = corners.mean(0)
    boards, T_wb = {}, []
    for b in range(n_boards):
        yaw = 2 * np.pi * b / n_boards
        n_in = np.array([np.cos(yaw), np.sin(yaw), 0.0])  # board faces the origin: its z points away
        z = n_in
        x = np.cross([0, 0, 1.0], z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.column_stack([x, y, z])
        t = dist * n_in - R @ centre
        T_wb.append(geo.make_T(R, t))
        boards[f"b{b}"] = corners
    T_wB = []
    views = []
    for f in range(n_frames):
        yaw = rng.uniform(-np.pi, np.pi)
        pitch, roll = rng.uniform(-np.radians(20), np.radians(20), 2)
        R = geo.R_from_rotvec([0, 0, yaw]) @ geo.R_from_rotvec([0, pitch, 0]) @ geo.R_from_rotvec([roll, 0, 0])
        T = geo.make_T(R, rng.uniform(-0.4, 0.4, 3))
        T_wB.append(T)
        for cam in rig.cameras:
            for b, name in enumerate(boards):
                T_cam_board = geo.inv_T(cam.T_body_cam) @ geo.inv_T(T) @ T_wb[b]
                p_cam = geo.transform(T_cam_board, corners)
                uv, valid = cam.intrinsics.project(p_cam)
                ok = valid & cam.intrinsics.in_image(uv, margin=2)
                # grazing views are useless; a real detector would drop them too
                n_cam = T_cam_board[:3, 2]
                if ok.sum() < min_corners or abs(n_cam @ (p_cam[ok].mean(0) / np.linalg.norm(p_cam[ok].mean(0)))) < 0.25:
                    continue
                ids = np.nonzero(ok)[0]
                views.append(ViewIn(cam.name, f"{f:06d}", name, ids,
                                    uv[ok] + rng.normal(0, noise_px, (len(ids), 2))))
    return views, boards, np.array(T_wb), np.array(T_wB)
