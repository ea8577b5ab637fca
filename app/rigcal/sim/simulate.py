"""`rigcal simulate`: synthetic ChArUco datasets with ground truth (docs/formats.md#dataset).

The declared rig is the nominal design. The true rig differs from it by seeded
mounting errors, focal and principal point errors and small lens distortion
(`perturb_rig`); images are rendered through the *true* rig (render.py) and the
truth is written to truth.yaml, so a calibration that echoes the declared rig is
visibly wrong.

Scenes (world frame z up):

* ``board``: one board moved in front of a static rig (T_world_body = identity),
  0.5-3 m away, tilted up to 50 degrees, partly out of view at times; poses are
  chosen greedily from random candidates so every camera sees it in most frames,
  cameras that share a view see it together, and every part of every image gets
  corners.
* ``room``: boards on the four walls (and floor / ceiling when a camera looks down /
  up) of a 3 m room around a rig that turns through every heading, pitches and rolls
  by up to 30 degrees and moves by up to 0.5 m; poses again chosen greedily so every
  camera sees every board it can.

Randomness: one seed; separate streams for the truth, the scene and every image
(image streams are keyed by (seed, camera index, frame index), so the worker
order never changes a byte).
"""

from __future__ import annotations

import math
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.sim import render
from rigcal.core.camera import CameraModel
from rigcal.errors import InputError, OutputError, RigFileError, TargetFileError
from rigcal.core.io import atomic_dir
from rigcal.core.rig import Camera, Rig, load_rig, rig_file, rig_to_dict
from rigcal.core.target import Board, Target, board_label, dump_target, load_target
from rigcal.core.validate import read_text
from rigcal.core.workers import interrupts_deferred, worker_pool

SCENES = ("room", "board")
DEFAULT_FRAMES = {"room": 60, "board": 40}
DICTIONARY = "DICT_5X5_1000"
MARKER_RATIO = 0.7  # marker / square: leaves a white margin round each corner for sub-pixel refinement
ROOM_HALF_M = 1.5  # walls, floor and ceiling this far from the room's centre
BOARD_RANGE_M = (0.5, 3.0)  # board scene distances
MIN_SQUARE_PX = 18.0  # generated boards keep squares at least this big at the far end of a scene
SEEN_MIN_CORNERS = 6  # a ChArUco board counts as seen with this many corners in view (a chessboard: all)
MIN_CORNER_SCALE_PX = 10.0  # ... each on a square at least this big, ...
MAX_VIEW_ANGLE_DEG = 75.0  # ... and seen less obliquely than this
GRID = 4  # image coverage cells per side
PP_OFFSET_PX = 5.0  # principal point errors are uniform in +-this
OPTICS_SIGMA_PX = 0.5  # the lens's own blur (Gaussian), on top of the pixel's area
VIGNETTING = 0.25
PNG_COMPRESSION = 1  # fast; noisy images hardly compress anyway


# ----------------------------------------------------------------------------- the truth


def perturb_rig(rig: Rig, rng: np.random.Generator, mount_error_mm: float = 5.0, mount_error_deg: float = 1.0,
                focal_error: float = 0.02) -> Rig:
    """The true rig: the declared one with seeded mounting and lens errors.

    Per camera: position + N(0, mount_error_mm) per body axis; rotation by
    N(0, mount_error_deg) about a uniformly random body-frame axis (applied on the
    body side: R_true = R_err @ R_declared); fx *= 1 + N(0, focal_error), fy the same
    plus N(0, focal_error / 10) more (so fx != fy); cx, cy + U(-5, 5) px; distortion
    the declared coefficients plus small non-zero terms (pinhole: k1, k2, p1, p2 -
    k3 and higher stay as declared, so a 4- or 5-coefficient model fits exactly;
    at least 4 coefficients are written; fisheye: k1..k4), at full, half or quarter
    size, the first that leaves a ray at every image-border pixel the declared lens has
    one at, else the declared coefficients. The focal and principal-point errors are
    kept either way."""
    cams = []
    for cam in rig.cameras:
        if cam.T_body_cam is None:
            raise InputError(f"cameras.{cam.name}: has no pose; simulate needs every camera's position and orientation")
        dt = rng.normal(0.0, mount_error_mm / 1000.0, 3)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = math.radians(rng.normal(0.0, mount_error_deg))
        T = cam.T_body_cam.copy()
        T[:3, :3] = geo.R_from_rotvec(axis * angle) @ T[:3, :3]
        T[:3, 3] += dt
        m = cam.intrinsics
        e1 = rng.normal(0.0, focal_error)
        e2 = rng.normal(0.0, focal_error / 10.0)
        pp = rng.uniform(-PP_OFFSET_PX, PP_OFFSET_PX, 2)
        draws = rng.uniform(-1.0, 1.0, 6)  # drawn once so retries below do not shift the stream
        # the focal and principal-point errors are kept whatever becomes of the distortion draw
        lens = m.with_(fx=m.fx * (1 + e1), fy=m.fy * (1 + e1 + e2), cx=m.cx + pp[0], cy=m.cy + pp[1])
        declared_field = field_border(m)
        true_m = lens  # the declared distortion, when no scaled draw passes
        for scale in (1.0, 0.5, 0.25):
            cand = lens.with_(dist=_perturbed_distortion(m, draws, scale))
            # the errors must not make the lens fold back where the declared one does not
            if np.all(field_border(cand) | ~declared_field):
                true_m = cand
                break
        cams.append(Camera(name=cam.name, intrinsics=true_m, T_body_cam=T))
    return rig.with_cameras(cams)


def _perturbed_distortion(m: CameraModel, u: np.ndarray, scale: float) -> tuple[float, ...]:
    """Declared coefficients plus small terms; u: six uniform(-1, 1) draws."""
    d = list(m.dist)
    if m.model == "fisheye":
        extra = [np.sign(u[0]) * (0.005 + 0.015 * abs(u[0])), 0.005 * u[1], 0.001 * u[2], 0.0003 * u[3]]
    else:
        d += [0.0] * max(0, 4 - len(d))
        extra = [np.sign(u[0]) * (0.01 + 0.04 * abs(u[0])), 0.02 * u[1], 5e-4 * u[2], 5e-4 * u[3]]
    for i, e in enumerate(extra):
        d[i] += scale * float(e)
    return tuple(float(x) for x in d)


def field_border(m: CameraModel) -> np.ndarray:
    """(N,) bool: which sample pixels on the image border have a ray through the model (a
    fisheye's corners may lie outside its field; a pinhole model may fold back)."""
    u = np.linspace(-0.5, m.width - 0.5, 33)
    v = np.linspace(-0.5, m.height - 0.5, 25)
    border = np.concatenate([np.column_stack([u, np.full_like(u, v[0])]), np.column_stack([u, np.full_like(u, v[-1])]),
                             np.column_stack([np.full_like(v, u[0]), v]), np.column_stack([np.full_like(v, u[-1]), v])])
    return np.isfinite(m.unproject(border)).all(axis=1)


# ----------------------------------------------------------------------------- scene choice and target


def _pixel_rays(m: CameraModel, nx: int = 15, ny: int = 11) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, m.width - 1, nx), np.linspace(0, m.height - 1, ny))
    rays = m.unproject(np.column_stack([u.ravel(), v.ravel()]))
    return rays[np.isfinite(rays).all(axis=1)]


def shares_common_view(rig: Rig) -> bool:
    """True when one region in front of the rig is seen by every camera at once (a stereo
    pair, a forward trinocular): then one board moved in front of the rig reaches them all."""
    if len(rig.cameras) < 2:
        return True
    first = rig.cameras[0]
    rays = _pixel_rays(first.intrinsics)
    p_cam = np.concatenate([rays * d for d in (0.8, 1.5, 3.0)])
    p_body = geo.transform(first.T_body_cam, p_cam)
    seen = np.ones(len(p_body), bool)
    for cam in rig.cameras[1:]:
        seen &= cam.project_body(p_body).in_image
    return bool(seen.mean() >= 0.03)


def default_scene(rig: Rig) -> str:
    """`board` when every camera shares one view, else `room` (some camera would never see
    the moving board together with the others)."""
    return "board" if shares_common_view(rig) else "room"


def _room_surfaces(rig: Rig) -> list[str]:
    """Walls always; the floor when a camera looks down (more than 30 degrees below the
    horizon), the ceiling when one looks up."""
    out = ["wall_n", "wall_e", "wall_s", "wall_w"]
    z = [c.T_body_cam[2, 2] for c in rig.cameras if c.T_body_cam is not None]  # optical axis, body up component
    if any(v < -0.5 for v in z):
        out.append("floor")
    if any(v > 0.5 for v in z):
        out.append("ceiling")
    return out


def make_target_for_rig(rig: Rig, scene: str) -> Target:
    """ChArUco boards sized to the rig's cameras: squares at least MIN_SQUARE_PX at the far
    end of the scene, a board spanning a fair part of the image at the near end; one
    board for `board`, one per room surface for `room`, disjoint marker ids."""
    f = float(np.median([c.intrinsics.fx for c in rig.cameras]))
    width = float(np.median([c.intrinsics.width for c in rig.cameras]))
    if scene == "board":
        far = BOARD_RANGE_M[1]
        # a board that fills at most ~1.5 image widths at 0.5 m and has big enough squares at 3 m
        nx = int(np.clip(math.floor(1.5 * width * BOARD_RANGE_M[0] / (MIN_SQUARE_PX * far)), 5, 14))
        names = ["board"]
    else:
        far = 1.6 * ROOM_HALF_M  # farthest wall, seen obliquely from a displaced rig
        nx = int(np.clip(round(0.4 * width / (MIN_SQUARE_PX * 1.6)), 5, 14))
        names = _room_surfaces(rig)
    square = _round_mm(MIN_SQUARE_PX * far / f)
    ny = max(4, int(round(nx * 0.72)))
    per_board = (nx * ny) // 2
    boards = tuple(Board(name=n, type="charuco", square_length=square, squares=(nx, ny), dictionary=DICTIONARY,
                         marker_length=_round_mm(square * MARKER_RATIO), first_marker_id=i * per_board)
                   for i, n in enumerate(names))
    return Target(boards=boards)


def _round_mm(x: float) -> float:
    return round(x * 1000.0, 1) / 1000.0


# ----------------------------------------------------------------------------- visibility


def seen_min(boards: Sequence[Board]) -> np.ndarray:
    """(B,) corners a camera must see for each board to count as seen: a chessboard is only
    found whole (OpenCV's detectors need every corner), a ChArUco board in part."""
    return np.array([b.n_corners if b.type == "chessboard" else min(SEEN_MIN_CORNERS, b.n_corners) for b in boards])


@dataclass(frozen=True)
class Visibility:
    """Corners of one board seen by one camera in one pose."""

    count: int  # corners in view
    cells: np.ndarray  # (GRID*GRID,) bool: image cells holding a seen corner
    needed: int = SEEN_MIN_CORNERS  # corners in view for the board to count as seen

    @property
    def seen(self) -> bool:
        return self.count >= self.needed


def board_visibility(cam: Camera, T_body_board: np.ndarray, board: Board, margin_px: float = 3.0) -> Visibility:
    """Which of the board's corners this camera sees: in the image (less a margin), on the
    printed side, not too oblique, on squares big enough to detect. Occlusion ignored."""
    count, cells = visibility_batch(cam, T_body_board[None, None], [board], margin_px)
    return Visibility(int(count[0, 0]), cells[0, 0], int(seen_min([board])[0]))


def visibility_batch(cam: Camera, T_body_boards: np.ndarray, boards: Sequence[Board], margin_px: float = 3.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """board_visibility for K poses of B boards at once: T_body_boards (K, B, 4, 4) ->
    corner counts (K, B) and image cells (K, B, GRID*GRID)."""
    K, B = T_body_boards.shape[:2]
    which = np.concatenate([np.full(b.n_corners, i) for i, b in enumerate(boards)])  # (N,) board of each corner
    corners = np.concatenate([b.corners for b in boards])  # (N, 3)
    square = np.array([b.square_length for b in boards])[which]
    T_cam_boards = np.einsum("ij,kbjl->kbil", geo.inv_T(cam.T_body_cam), T_body_boards)
    T_sel = T_cam_boards[:, which]  # (K, N, 4, 4): each corner's board pose
    R, t = T_sel[..., :3, :3], T_sel[..., :3, 3]
    p = (R @ corners[None, :, :, None])[..., 0] + t
    m = cam.intrinsics
    N = len(which)
    uv, valid = m.project(p.reshape(-1, 3))
    in_img = (valid & m.in_image(uv, margin_px)).reshape(K, N)
    uv = uv.reshape(K, N, 2)
    normal = R[..., 2]  # board z in the camera frame
    face = np.array([b.print_face for b in boards])[which]  # the sign of board z on the printed side
    front = (normal * t).sum(axis=-1) * face < 0  # the camera is on the printed side
    dist = np.linalg.norm(p, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_view = np.abs((p * normal).sum(axis=-1)) / dist
        ok = (in_img & front & (cos_view > math.cos(math.radians(MAX_VIEW_ANGLE_DEG)))
              & (square * m.fx / dist >= MIN_CORNER_SCALE_PX))
    count = np.stack([ok[:, which == i].sum(axis=1) for i in range(B)], axis=1)
    uv_safe = np.where(ok[..., None], uv, 0.0)
    cu = np.clip((uv_safe[..., 0] / m.width * GRID).astype(int), 0, GRID - 1)
    cv_ = np.clip((uv_safe[..., 1] / m.height * GRID).astype(int), 0, GRID - 1)
    cells = np.zeros((K, B, GRID * GRID), bool)
    kk = np.broadcast_to(np.arange(K)[:, None], (K, N))
    bb = np.broadcast_to(which[None, :], (K, N))
    cells[kk[ok], bb[ok], (cv_ * GRID + cu)[ok]] = True
    return count, cells


# ----------------------------------------------------------------------------- scenes


@dataclass(frozen=True)
class Scene:
    """Poses of everything, per frame: T_world_body (F, 4, 4) and T_world_board (F, B, 4, 4)
    (the same for every frame unless the boards move)."""

    name: str
    target: Target
    frames: tuple[str, ...]
    T_world_body: np.ndarray
    T_world_board: np.ndarray
    moving_boards: bool


def frame_names(n: int) -> tuple[str, ...]:
    return tuple(f"{i:06d}" for i in range(n))


def _look_at(z_axis: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """Rotation whose z column is z_axis and whose x column is as close to up_hint x z as possible."""
    z = z_axis / np.linalg.norm(z_axis)
    x = np.cross(up_hint, z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def plan_board_scene(rig: Rig, target: Target, n_frames: int, rng: np.random.Generator,
                     candidates: int = 40) -> Scene:
    """One board (the target's first) moved in front of a static rig, greedily: every
    frame takes the best of `candidates` random poses, scored by how many cameras see
    the board and how many still-empty image cells it fills."""
    board = target.boards[0]
    need = int(seen_min([board])[0])
    cams = rig.cameras
    hits = np.zeros((len(cams), GRID * GRID))
    poses = []
    for _ in range(n_frames):
        cand = np.stack([_board_candidate(rng, rig, board) for _ in range(candidates)])
        score = np.zeros(candidates)
        seen_all = np.ones(candidates, bool)
        vis = [visibility_batch(cam, cand[:, None], [board]) for cam in cams]
        for ci, (count, cells) in enumerate(vis):
            seen = count[:, 0] >= need
            seen_all &= seen
            score += seen * (3.0 + (cells[:, 0] / (1.0 + hits[ci])).sum(axis=1))
        score += 3.0 * seen_all
        best = int(np.argmax(score))
        for ci, (count, cells) in enumerate(vis):
            if count[best, 0] >= need:
                hits[ci] += cells[best, 0]
        poses.append(cand[best])
    F = n_frames
    T_world_board = np.stack(poses)[:, None]  # (F, 1, 4, 4)
    return Scene(name="board", target=Target(boards=(board,)), frames=frame_names(F),
                 T_world_body=np.repeat(np.eye(4)[None], F, axis=0), T_world_board=T_world_board, moving_boards=True)


def _board_candidate(rng: np.random.Generator, rig: Rig, board: Board) -> np.ndarray:
    """A random board pose in the body frame: centred on a random pixel's ray of a random
    camera (up to 10 % outside its image), at a distance giving the board 0.3-1.3 image
    widths, facing that camera, then tilted up to 50 degrees and rolled up to 30."""
    cam = rig.cameras[int(rng.integers(len(rig.cameras)))]
    m = cam.intrinsics
    w, h = board.size_m
    uv = np.array([rng.uniform(-0.1, 1.1) * m.width, rng.uniform(-0.1, 1.1) * m.height])
    ray = m.unproject(uv)[0]
    if not np.isfinite(ray).all():
        ray = np.array([0.0, 0.0, 1.0])
    q = rng.uniform(0.3, 1.3)
    d = float(np.clip(w * m.fx / (q * m.width), *BOARD_RANGE_M))
    R_facing = _look_at(ray, np.array([0.0, 1.0, 0.0]))  # board x along the camera's x, y down
    tilt_axis = rng.normal(size=2)
    tilt_axis /= np.linalg.norm(tilt_axis)
    tilt = math.radians(rng.uniform(0.0, 50.0))
    roll = math.radians(rng.uniform(-30.0, 30.0))
    R_cam_board = R_facing @ geo.R_from_rotvec(np.array([tilt_axis[0], tilt_axis[1], 0.0]) * tilt) \
        @ geo.R_from_rotvec(np.array([0.0, 0.0, roll]))
    centre = d * ray
    T_cam_print = geo.make_T(R_cam_board, centre - R_cam_board @ np.array([w / 2, h / 2, 0.0]))
    # placed as printed; the board's own frame may differ (Kalibr's AprilGrid)
    return cam.T_body_cam @ T_cam_print @ geo.inv_T(board.T_board_print)


def _surface_pose(surface: str, board: Board, rng: np.random.Generator) -> np.ndarray:
    """T_world_board for a board on a room surface, printed face towards the centre, a
    little off-centre and askew (so no two boards are exactly alike)."""
    w, h = board.size_m
    up = np.array([0.0, 0.0, 1.0])
    normals = {"wall_n": [0, 1, 0], "wall_e": [1, 0, 0], "wall_s": [0, -1, 0], "wall_w": [-1, 0, 0],
               "floor": [0, 0, -1], "ceiling": [0, 0, 1]}
    z = np.array(normals[surface], float)  # board z points into the printed face: away from the viewer
    if surface in ("floor", "ceiling"):
        R = _look_at(z, np.array([0.0, 1.0, 0.0]) if surface == "floor" else np.array([0.0, -1.0, 0.0]))
    else:
        R = _look_at(z, -up)  # board y (down the print) along -up
    R = R @ geo.R_from_rotvec(rng.uniform(-1, 1, 3) * np.radians([6.0, 6.0, 10.0]))
    centre = ROOM_HALF_M * z
    if surface in ("floor", "ceiling"):
        centre = centre + np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 0.0])
    else:
        centre = centre + np.cross(z, up) * rng.uniform(-0.2, 0.2) + up * rng.uniform(-0.2, 0.2)
    T_world_print = geo.make_T(R, centre - R @ np.array([w / 2, h / 2, 0.0]))
    return T_world_print @ geo.inv_T(board.T_board_print)


def plan_room_scene(rig: Rig, target: Target, n_frames: int, rng: np.random.Generator,
                    candidates: int = 24, surfaces: Sequence[str] | None = None) -> Scene:
    """Static boards on the room's surfaces; the rig turns (any heading, pitch and roll
    within 30 degrees) and moves (within 0.5 m); each frame the best of `candidates`
    random body poses, scored by (camera, board) pairs still rarely seen."""
    surfaces = list(surfaces or _room_surfaces(rig))
    boards = target.boards
    # more boards than surfaces: the rest go on the walls again, turned 45 degrees further
    order = [surfaces[i % len(surfaces)] for i in range(len(boards))]
    T_world_board = []
    for i, (b, s) in enumerate(zip(boards, order)):
        T = _surface_pose(s, b, rng)
        if i >= len(surfaces) and s.startswith("wall"):
            T = geo.make_T(geo.R_from_rotvec([0.0, 0.0, math.pi / 4]), [0, 0, 0]) @ T
        T_world_board.append(T)
    T_world_board = np.stack(T_world_board)
    cams = rig.cameras
    need = seen_min(boards)
    count_seen = np.zeros((len(cams), len(boards)))
    hits = np.zeros((len(cams), GRID * GRID))
    bodies = []
    for _ in range(n_frames):
        yaw = rng.uniform(-math.pi, math.pi, candidates)
        pitch, roll = np.radians(rng.uniform(-30.0, 30.0, (2, candidates)))
        shift = rng.uniform(-0.5, 0.5, (candidates, 3))
        R = (geo.R_from_rotvec(np.outer(yaw, [0.0, 0.0, 1.0])) @ geo.R_from_rotvec(np.outer(pitch, [0.0, 1.0, 0.0]))
             @ geo.R_from_rotvec(np.outer(roll, [1.0, 0.0, 0.0])))
        T_world_body = np.zeros((candidates, 4, 4))
        T_world_body[:, :3, :3], T_world_body[:, :3, 3], T_world_body[:, 3, 3] = R, shift, 1.0
        T_body_world = geo.inv_T(T_world_body)
        score = np.zeros(candidates)
        vis = []
        for ci, cam in enumerate(cams):
            count, cells = visibility_batch(cam, T_body_world[:, None] @ T_world_board[None], boards)
            seen = count >= need  # (K, B)
            vis.append((seen, cells))
            score += (seen / (1.0 + count_seen[ci])).sum(axis=1)
            score += 0.1 * (seen[..., None] * cells / (1.0 + hits[ci])).sum(axis=(1, 2))
        best = int(np.argmax(score))
        for ci, (seen, cells) in enumerate(vis):
            count_seen[ci] += seen[best]
            hits[ci] += (seen[best][:, None] * cells[best]).sum(axis=0)
        bodies.append(T_world_body[best])
    F = n_frames
    return Scene(name="room", target=target, frames=frame_names(F), T_world_body=np.stack(bodies),
                 T_world_board=np.repeat(T_world_board[None], F, axis=0), moving_boards=False)


# ----------------------------------------------------------------------------- coverage


@dataclass(frozen=True)
class CameraCoverage:
    """How well one camera saw the simulated boards: frames with a board, views per board, and
    the share of image cells that received corners."""

    frames_with_board: int  # frames in which the camera sees at least one board
    frames: int
    board_views: Mapping[str, int]  # board -> frames in which the camera sees it
    cells_covered: float  # fraction of the GRID x GRID image cells that received corners

    @property
    def fraction(self) -> float:
        return self.frames_with_board / self.frames if self.frames else 0.0


def coverage(rig: Rig, scene: Scene) -> dict[str, CameraCoverage]:
    """What each camera sees over the whole scene (the same test the planner used)."""
    out = {}
    T_body_world = geo.inv_T(scene.T_world_body)  # (F, 4, 4)
    for cam in rig.cameras:
        count, c = visibility_batch(cam, T_body_world[:, None] @ scene.T_world_board, scene.target.boards)
        seen = count >= seen_min(scene.target.boards)  # (F, B)
        per_board = {b.name: int(seen[:, bi].sum()) for bi, b in enumerate(scene.target.boards)}
        seen_any = seen.any(axis=1)
        cells = (seen[..., None] & c).any(axis=(0, 1))
        out[cam.name] = CameraCoverage(int(seen_any.sum()), len(scene.frames), per_board, float(cells.mean()))
    return out


# ----------------------------------------------------------------------------- rendering


@dataclass(frozen=True)
class RenderSettings:
    """How images are rendered: the seed, pixel noise (grey levels), blur (px), supersampling
    and the optics blur sigma (px)."""

    seed: int
    noise: float
    blur: float
    ss: int = render.SS
    optics_sigma_px: float = OPTICS_SIGMA_PX


# Per process: what every image of a run needs (set by the pool's initializer in each
# worker, or in this process when rendering serially).
_STATE: dict[str, Any] = {}


def set_state(state: dict[str, Any], worker: bool = True) -> None:
    _STATE.clear()
    _STATE.update(state)
    if worker:  # one process per core already
        cv2.setNumThreads(1)


def render_image(ci: int, fi: int) -> np.ndarray:
    """One image (uint8 (H, W)) of camera index ci at frame index fi, from _STATE."""
    rig: Rig = _STATE["rig"]
    scene: Scene = _STATE["scene"]
    st: RenderSettings = _STATE["settings"]
    cam = rig.cameras[ci]
    rays = _STATE["rays"][ci]
    textures = _STATE["textures"]
    rng = np.random.default_rng([st.seed, ci, fi, 0x5EED])
    nb = len(scene.target.boards)
    # illumination: the print's black and white grey levels, and a gain per board
    black, white = rng.uniform(10.0, 60.0), rng.uniform(150.0, 235.0)
    gains = rng.uniform(0.85, 1.08, nb)
    look = render.Look(noise=st.noise, blur_px=st.blur, blur_angle=float(rng.uniform(0.0, math.pi)),
                       optics_sigma_px=st.optics_sigma_px)
    T_cam_world = geo.inv_T(scene.T_world_body[fi] @ cam.T_body_cam)
    T_cam_boards = [T_cam_world @ scene.T_world_board[fi, bi] for bi in range(nb)]
    grey = [(black * g, min(white * g, 250.0)) for g in gains]
    fg, alpha = render.render_boards(cam.intrinsics, rays, T_cam_boards, textures, grey, st.ss)
    bg = render.background(cam.intrinsics.width, cam.intrinsics.height, rng)
    return render.finish(fg, alpha, bg, _STATE["vignettes"][ci], look, rng)


def _render_and_write(ci: int, fi: int, path: str) -> float:
    """Render and write one image; returns the CPU seconds it took (for the benchmark)."""
    t0 = time.process_time()
    img = render_image(ci, fi)
    if not cv2.imwrite(path, img, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]):
        raise OutputError(f"{path}: cannot write the image")
    return time.process_time() - t0


def prepare_state(true_rig: Rig, scene: Scene, settings: RenderSettings, threads: int) -> dict[str, Any]:
    models = [c.intrinsics for c in true_rig.cameras]
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:  # numpy releases the GIL
        rays = list(pool.map(lambda m: render.sample_rays(render.ray_map(m, settings.ss)), models))
    return {"rig": true_rig, "scene": scene, "settings": settings, "rays": rays,
            "textures": [render.BoardTexture(b) for b in scene.target.boards],
            "vignettes": [render.vignetting(m, VIGNETTING) * render.field_mask(r, settings.ss)
                          for m, r in zip(models, rays)]}


# ----------------------------------------------------------------------------- truth.yaml


def _pose_dict(T: np.ndarray) -> dict[str, Any]:
    return {"rotation": [[float(x) + 0.0 for x in row] for row in T[:3, :3]],
            "position": [float(x) + 0.0 for x in T[:3, 3]]}


def truth_dict(true_rig: Rig, scene: Scene, settings: RenderSettings, perturbation: Mapping[str, float],
               cover: Mapping[str, CameraCoverage]) -> dict[str, Any]:
    """truth.yaml (docs/formats.md#dataset): the true rig, board poses, body poses per frame (and, for a
    moving board, the board's pose per frame, which overrides `boards`)."""
    names = [b.name for b in scene.target.boards]
    frames = {}
    for fi, stem in enumerate(scene.frames):
        d = _pose_dict(scene.T_world_body[fi])
        if scene.moving_boards:
            d["boards"] = {n: _pose_dict(scene.T_world_board[fi, bi]) for bi, n in enumerate(names)}
        frames[stem] = d
    return {
        "rig": rig_to_dict(true_rig),
        # for a moving board: its pose in the first frame; every frame overrides it
        "boards": {n: _pose_dict(scene.T_world_board[0, bi]) for bi, n in enumerate(names)},
        "frames": frames,
        "render": {
            "seed": int(settings.seed), "noise_sigma": float(settings.noise), "blur_px": float(settings.blur),
            "scene": scene.name, "frames": len(scene.frames), "supersampling": int(settings.ss),
            "optics_sigma_px": float(settings.optics_sigma_px), "vignetting": VIGNETTING,
            "mount_error_mm": float(perturbation["mount_error_mm"]),
            "mount_error_deg": float(perturbation["mount_error_deg"]),
            "focal_error": float(perturbation["focal_error"]), "principal_point_error_px": PP_OFFSET_PX,
            "coverage": {c: {"frames_with_board": v.frames_with_board, "board_views": dict(v.board_views),
                             "cells_covered": round(v.cells_covered, 3)} for c, v in cover.items()},
        },
    }


# ----------------------------------------------------------------------------- the library entry


@dataclass(frozen=True)
class SimResult:
    """What `rigcal simulate` wrote: the dataset folder, its frames, the declared and true rigs,
    the target, the scene poses, the image paths and per camera its coverage."""

    out_dir: Path
    scene: str
    frames: tuple[str, ...]
    declared: Rig
    truth: Rig
    target: Target
    scene_poses: Scene
    image_paths: Mapping[str, tuple[Path, ...]]  # camera -> images in frame order
    coverage: Mapping[str, CameraCoverage]
    seconds: float = field(default=0.0)  # wall time
    image_cpu_seconds: float = field(default=0.0)  # CPU time spent rendering and writing images, all workers


def _check_settings(scene: str | None, frames: int | None, noise: float, blur: float, mount_error_mm: float,
                    mount_error_deg: float, focal_error: float, jobs: int | None) -> None:
    if scene is not None and scene not in SCENES:
        raise InputError(f"--scene: expected one of {', '.join(SCENES)}, got {scene!r}")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 1):
        raise InputError(f"--frames: expected a positive number of frames, got {frames!r}")
    for flag, v, hi in (("--noise", noise, 100.0), ("--blur", blur, 50.0), ("--mount-error-mm", mount_error_mm, 100.0),
                        ("--mount-error-deg", mount_error_deg, 20.0), ("--focal-error", focal_error, 0.2)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= hi):
            raise InputError(f"{flag}: expected a number from 0 to {hi:g}, got {v!r}")
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise InputError(f"--jobs: expected a positive number of processes, got {jobs!r}")


def simulate_dataset(rig: Rig, out_dir: str | Path, *, scene: str | None = None, frames: int | None = None,
                     seed: int = 0, noise: float = 2.0, blur: float = 0.0, mount_error_mm: float = 5.0,
                     mount_error_deg: float = 1.0, focal_error: float = 0.02, target: Target | None = None,
                     force: bool = False, jobs: int | None = None, progress: bool = False,
                     rig_text: str | None = None, target_text: str | None = None, label: str = "<rig>") -> SimResult:
    """Render a dataset (docs/formats.md#dataset) of `rig` into out_dir, whole or not at all.

    rig_text / target_text, when given, are written verbatim as DATASET/rig.yaml and
    target.yaml (the files as the user wrote them); otherwise they are dumped."""
    t0 = time.perf_counter()
    _check_settings(scene, frames, noise, blur, mount_error_mm, mount_error_deg, focal_error, jobs)
    for cam in rig.cameras:
        if cam.T_body_cam is None:
            raise InputError(f"{label}: cameras.{cam.name}: has no pose; simulate needs every camera's "
                             f"position and orientation")
    scene = scene or default_scene(rig)
    n_frames = frames or DEFAULT_FRAMES[scene]
    jobs = jobs or os.cpu_count() or 1
    out_dir = Path(out_dir)
    perturbation = {"mount_error_mm": mount_error_mm, "mount_error_deg": mount_error_deg, "focal_error": focal_error}
    try:
        true_rig = perturb_rig(rig, np.random.default_rng([seed, 1]), **perturbation)
    except InputError as e:
        raise InputError(f"{label}: {e}") from None
    target = target or make_target_for_rig(rig, scene)
    scene_rng = np.random.default_rng([seed, 2])
    if scene == "board":
        plan = plan_board_scene(true_rig, target, n_frames, scene_rng)
    else:
        plan = plan_room_scene(true_rig, target, n_frames, scene_rng)
    cover = coverage(true_rig, plan)
    settings = RenderSettings(seed=seed, noise=float(noise), blur=float(blur))
    with atomic_dir(out_dir, force=force) as tmp:
        paths, image_cpu = render_all(true_rig, plan, settings, tmp, jobs, progress)
        (tmp / "rig.yaml").write_text(rig_text if rig_text is not None else _dump_declared(rig), encoding="utf-8")
        (tmp / "target.yaml").write_text(target_text if target_text is not None else dump_target(target),
                                         encoding="utf-8")
        truth = truth_dict(true_rig, plan, settings, perturbation, cover)
        (tmp / "truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False, default_flow_style=None, width=120),
                                        encoding="utf-8")
    image_paths = {c: tuple(out_dir / p.relative_to(tmp) for p in ps) for c, ps in paths.items()}
    return SimResult(out_dir=out_dir, scene=scene, frames=plan.frames, declared=rig, truth=true_rig,
                     target=plan.target if scene == "board" else target, scene_poses=plan, image_paths=image_paths,
                     coverage=cover, seconds=time.perf_counter() - t0, image_cpu_seconds=image_cpu)


def _dump_declared(rig: Rig) -> str:
    return yaml.safe_dump(rig_to_dict(rig), sort_keys=False, default_flow_style=None, width=120)


def render_all(true_rig: Rig, scene: Scene, settings: RenderSettings, tmp: Path, jobs: int,
                progress: bool) -> tuple[dict[str, list[Path]], float]:
    """Write every image; returns the paths per camera and the CPU seconds spent on images."""
    paths: dict[str, list[Path]] = {}
    tasks = []
    for ci, cam in enumerate(true_rig.cameras):
        d = tmp / "images" / cam.name
        d.mkdir(parents=True, exist_ok=True)
        paths[cam.name] = []
        for fi, stem in enumerate(scene.frames):
            p = d / f"{stem}.png"
            paths[cam.name].append(p)
            tasks.append((ci, fi, str(p)))
    state = prepare_state(true_rig, scene, settings, jobs)
    return paths, run_render_tasks(state, tasks, jobs, progress)


def run_render_tasks(state: dict[str, Any], tasks: list, jobs: int, progress: bool, work=None, init=None,
                     preload: str = "rigcal.sim.simulate") -> float:
    """work(*task) for every task (default: this module's render-and-write), here when jobs is 1,
    else in forkserver workers (rigcal.core.workers) set up by init(state) (default: set_state),
    each receiving the state (the ray maps) once, pickled. work and init must be module-level
    functions of `preload`. Returns the CPU seconds the tasks report."""
    work = work or _render_and_write
    init = init or set_state
    bar = RenderProgress(len(tasks)) if progress else None
    cpu = 0.0
    try:
        if jobs == 1 or len(tasks) == 1:
            init(state, worker=False)
            for t in tasks:
                cpu += work(*t)
                if bar:
                    bar.advance()
        else:
            with worker_pool(min(jobs, len(tasks)), preload, init, (state,)) as pool:
                with interrupts_deferred():  # a worker interrupted while it starts prints a traceback
                    futures = [pool.submit(work, *t) for t in tasks]
                for fut in as_completed(futures):
                    cpu += fut.result()
                    if bar:
                        bar.advance()
    finally:
        if bar:
            bar.close()
        init({}, worker=False)  # drop the state (ray maps) this process holds
    return cpu


class RenderProgress:
    """A rich progress bar on stderr."""

    def __init__(self, total: int):
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._p = Progress(TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                           console=Console(stderr=True), transient=True)
        self._p.start()
        self._task = self._p.add_task("render", total=total)

    def advance(self) -> None:
        self._p.advance(self._task)

    def close(self) -> None:
        self._p.stop()


# ----------------------------------------------------------------------------- the command


def run(rig_path, out_dir, scene=None, frames=None, seed=0, noise=2.0, blur=0.0, mount_error_mm=5.0,
        mount_error_deg=1.0, focal_error=0.02, target_path=None, force=False, jobs=None) -> str:
    """`rigcal simulate`: returns the summary for stdout."""
    rig_path = rig_file(rig_path)  # a shipped rig's name gives its file
    rig = load_rig(rig_path)
    rig_text = read_text(rig_path, RigFileError)  # as load_rig read it (UTF-16 too)
    target = target_text = None
    if target_path is not None:
        target = load_target(target_path)
        target_text = read_text(target_path, TargetFileError)
    res = simulate_dataset(rig, out_dir, scene=scene, frames=frames, seed=seed, noise=noise, blur=blur,
                           mount_error_mm=mount_error_mm, mount_error_deg=mount_error_deg, focal_error=focal_error,
                           target=target, force=force, jobs=jobs, progress=sys.stderr.isatty(), rig_text=rig_text,
                           target_text=target_text, label=str(rig_path))
    return summary(res)


def summary(res: SimResult) -> str:
    n_img = sum(len(v) for v in res.image_paths.values())
    lines = [f"wrote {res.out_dir}: {res.scene} scene, {len(res.frames)} frames, {n_img} images, "
             f"{len(res.target.boards)} board(s), {res.seconds:.1f} s"]
    for b in res.target.boards:
        lines.append(f"  {board_label(b)}")
    for c in res.truth.cameras:
        d = res.declared.camera(c.name)
        cov = res.coverage[c.name]
        dpos = np.linalg.norm(c.T_body_cam[:3, 3] - d.T_body_cam[:3, 3]) * 1000
        drot = geo.rotation_angle_deg(c.T_body_cam[:3, :3] @ d.T_body_cam[:3, :3].T)
        views = ", ".join(f"{k} {v}" for k, v in cov.board_views.items())
        lines.append(f"  {c.name}: sees a board in {cov.frames_with_board}/{cov.frames} frames ({views}); "
                     f"{cov.cells_covered * 100:.0f}% of image cells; truth differs from declared by "
                     f"{dpos:.1f} mm, {drot:.2f} deg, f {c.intrinsics.fx:.1f}/{c.intrinsics.fy:.1f} px")
    weak = [c for c, v in res.coverage.items() if v.frames_with_board == 0]
    if weak:
        lines.append(f"warning: {', '.join(weak)} never see a board; use more --frames or another --scene")
    return "\n".join(lines)
