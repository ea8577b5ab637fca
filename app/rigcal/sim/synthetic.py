"""Synthetic corner observations without rendering, for solver tests and benchmarks.

A scene holds the exact projections of known boards through a known (true) rig; it is
noise-free, and `with_noise` adds seeded Gaussian pixel noise on top, so one scene can
serve many noise draws. Every random draw comes from the generator passed in.

The room (`room_scene`): `n_boards` boards stand upright on the walls of a room around
the rig, `dist` metres from the world origin and facing it (a board's z axis points away
from the rig). World frame: z up. In every frame the body turns to a random heading,
with pitch and roll uniform in +-20 deg and an offset uniform in +-0.4 m per axis. As a
detector would, a camera keeps a board view only with at least `min_corners` corners
inside the image (2 px margin) and drops it when the board is seen grazing.

Boards are `(nx, ny, square)`: nx * ny inner corners on a `square`-metre grid, ids
row-major (`grid_corners`). Frames are named "000000", "000001", ... like a dataset's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from rigcal.core import geometry as geo
from rigcal.data.truth import Truth
from rigcal.core.observations import BoardView
from rigcal.core.rig import Camera, Rig

BOARD = (10, 7, 0.14)  # (nx, ny, square metres)
MAX_TILT_RAD = np.radians(20.0)  # pitch and roll of the body, each uniform in +-this
MAX_OFFSET_M = 0.4  # body offset from the room's centre, uniform in +-this per axis
EDGE_MARGIN_PX = 2.0  # corners nearer the image edge than this are not detected
MIN_GRAZING_COS = 0.25  # |cos| of the angle between board normal and mean viewing ray


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """Noise-free corner views of known boards through a known rig.

    rig: the true rig the corners were projected through.
    views: every kept board view; uv exact.
    corners: board name -> (N, 3) p_board, row = corner id.
    T_world_board: board name -> (4, 4).
    T_world_body: frame name -> (4, 4).
    """

    rig: Rig
    views: tuple[BoardView, ...]
    corners: Mapping[str, np.ndarray]
    T_world_board: Mapping[str, np.ndarray]
    T_world_body: Mapping[str, np.ndarray]

    @property
    def truth(self) -> Truth:
        """The scene as a simulated dataset's truth (static boards)."""
        return Truth(self.rig, dict(self.T_world_board), dict(self.T_world_body), {})


def grid_corners(nx: int, ny: int, square: float) -> np.ndarray:
    """(nx * ny, 3) board-frame corners on a `square`-metre grid, ids row-major, the
    first corner at (square, square, 0)."""
    k = np.arange(nx * ny)
    return np.column_stack([(k % nx + 1) * square, (k // nx + 1) * square, np.zeros(len(k))])


def wall_boards(n_boards: int, centre_board: np.ndarray, dist: float) -> dict[str, np.ndarray]:
    """T_world_board (4, 4) by name "b0", "b1", ... for boards spread evenly in heading
    around the z axis, upright, their centre `centre_board` (3,) `dist` metres out, their
    z axis pointing away from the origin."""
    out = {}
    for b in range(n_boards):
        yaw = 2 * np.pi * b / n_boards
        z = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        x = np.cross([0, 0, 1.0], z)
        x /= np.linalg.norm(x)
        R_world_board = np.column_stack([x, np.cross(z, x), z])
        out[f"b{b}"] = geo.make_T(R_world_board, dist * z - R_world_board @ centre_board)
    return out


def random_body_pose(rng: np.random.Generator) -> np.ndarray:
    """(4, 4) T_world_body: a random heading, pitch and roll uniform in +-20 deg, offset
    uniform in +-0.4 m per axis."""
    yaw = rng.uniform(-np.pi, np.pi)
    pitch, roll = rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD, 2)
    R_world_body = (geo.R_from_rotvec([0, 0, yaw]) @ geo.R_from_rotvec([0, pitch, 0])
                    @ geo.R_from_rotvec([roll, 0, 0]))
    return geo.make_T(R_world_body, rng.uniform(-MAX_OFFSET_M, MAX_OFFSET_M, 3))


def board_view(cam: Camera, T_cam_board: np.ndarray, p_board: np.ndarray,
               min_corners: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(ids (K,), uv (K, 2)) of the corners p_board (N, 3) that `cam` sees inside its image
    (2 px margin), or None when fewer than min_corners are or the board is seen grazing."""
    p_cam = geo.transform(T_cam_board, p_board)
    uv, valid = cam.intrinsics.project(p_cam)
    ok = valid & cam.intrinsics.in_image(uv, margin=EDGE_MARGIN_PX)
    if ok.sum() < min_corners:
        return None
    mean_ray = p_cam[ok].mean(0)
    # a real detector fails on boards seen nearly edge-on, and such views constrain little
    if abs(T_cam_board[:3, 2] @ mean_ray / np.linalg.norm(mean_ray)) < MIN_GRAZING_COS:
        return None
    return np.nonzero(ok)[0], uv[ok]


def room_scene(rig: Rig, rng: np.random.Generator, n_frames: int, n_boards: int = 4,
               board: tuple[int, int, float] = BOARD, dist: float = 2.0, min_corners: int = 8) -> SyntheticScene:
    """Wall boards around `rig` (the truth; every camera needs T_body_cam), seen in
    n_frames random body poses (see the module docstring). Noise-free."""
    p_board = grid_corners(*board)
    T_world_board = wall_boards(n_boards, p_board.mean(0), dist)
    T_world_body, views = {}, []
    for f in range(n_frames):
        frame = f"{f:06d}"
        T_world_body[frame] = T_w_body = random_body_pose(rng)
        for cam in rig.cameras:
            T_cam_world = geo.inv_T(cam.T_body_cam) @ geo.inv_T(T_w_body)
            for name, T_w_board in T_world_board.items():
                seen = board_view(cam, T_cam_world @ T_w_board, p_board, min_corners)
                if seen is not None:
                    views.append(BoardView(cam.name, frame, name, *seen))
    return SyntheticScene(rig, tuple(views), {n: p_board for n in T_world_board}, T_world_board, T_world_body)


def with_noise(views: Sequence[BoardView], sigma: float, rng: np.random.Generator) -> list[BoardView]:
    """The views with isotropic Gaussian noise of `sigma` px added to every corner (drawn
    in view order, so a seed gives the same noise for the same views)."""
    return [BoardView(v.camera, v.frame, v.board, v.ids, v.uv + rng.normal(0.0, sigma, v.uv.shape)) for v in views]
