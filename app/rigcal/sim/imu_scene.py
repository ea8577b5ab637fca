"""`rigcal simulate --scene imu`: a moving recording with cameras and IMUs (docs/formats.md#motion-datasets).

The rig is carried by hand-held-like motion (imu.SineTrajectory: analytic derivatives)
in front of static ChArUco boards, one board per viewing direction of the rig, about
BOARD_DISTANCE_M in front of its cameras at the average pose. Everything on the IMU clock
starts at EPOCH_NS; the IMUs sample from 0 to duration + 2 * MARGIN_S, the cameras from
MARGIN_S on, so every image time (shifted by its clock offset, exposure and readout)
lies inside the IMU stream.

Clocks: camera frame k is taken at t_cam = MARGIN_S + k / camera_rate on its own clock
(its stem, integer ns: mid-exposure of the first row), which is t_cam + time_offset_s on
the IMU clock (docs/formats.md#motion-datasets). All cameras share the stem grid, so equal stems name the same
camera-clock instant; the true offsets (up to --time-offset-ms) differ per camera.
Each camera may have its own rate (then the grids coincide only where k / rate does).
Free-running cameras (`free_running`) each take frames on their own schedule: a start
phase uniform over one frame period, a frame period off the nominal by up to
RATE_ERROR (relative), a jitter of JITTER_S (1-sigma) per frame, and a start up to
STAGGER_S late and a stop up to STAGGER_S early; their stems (the true capture times on
the camera clock) then practically never coincide. `drop` removes that fraction of every
camera's frames at random (dropped frames).

An image is the average of sub-exposure renders spread over --exposure (enough that the
image moves less than half a pixel between them: true motion blur), and with a rolling
shutter (line_delay_s) each band of BAND_ROWS rows is rendered at its own time
t + r_mid * line_delay_s: the rows really are exposed one after the other.

Randomness: one seed; streams [seed, 1] truth rig, [seed, 2] trajectory, [seed, 3] clock
offsets and IMU mounts, [seed, 4, i] IMU i's noise, [seed, camera, frame, IMAGE_KEY] each image,
[seed, SCHEDULE_KEY, camera] a camera's free-running schedule and dropped frames.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.sim import imu_model
from rigcal.sim import render
from rigcal.errors import InputError, OutputError
from rigcal.core.io import atomic_dir
from rigcal.data.imu_csv import imu_csv
from rigcal.core.rig import Imu, Rig, load_rig, rig_file, rig_to_dict
from rigcal.sim.simulate import (DICTIONARY, MARKER_RATIO, OPTICS_SIGMA_PX, RenderSettings, Scene, CameraCoverage,
                                 coverage, perturb_rig, prepare_state, run_render_tasks)
from rigcal.core.target import Board, Target, dump_target

EPOCH_NS = 1_600_000_000_000_000_000  # IMU clock at t = 0 (2020-09-13, EuRoC-like absolute stamps)
MARGIN_S = 0.5  # IMU samples before the first and after the last image
BOARD_DISTANCE_M = 1.3
BOARD_SQUARES = (8, 6)
BOARD_VIEW_DEG = 45.0  # the board spans about this much of a camera's view
GROUP_ANGLE_DEG = 35.0  # cameras looking within this angle of each other share a board
BAND_ROWS = 8  # rolling shutter: rows rendered at one time (their middle row's)
MAX_SUBSTEP_PX = 0.5  # image motion between two sub-exposure renders
MAX_SUB_EXPOSURES = 16
IMAGE_KEY = 0x1A0
SCHEDULE_KEY = 0x5C4  # the random stream of frame schedules (free-running, dropped frames)
RATE_ERROR = 1e-3  # free-running: a camera's frame period is off the nominal by up to this (relative)
JITTER_S = 1e-4  # free-running: 1-sigma jitter of each frame's capture time
STAGGER_S = 1.0  # free-running: a camera starts up to this late and stops up to this early
DEFAULTS = {"duration": 30.0, "camera_rate": 20.0, "exposure": 0.005, "time_offset_ms": 10.0}
TRAJECTORY_HEADER = "#t_ns,px [m],py [m],pz [m],qw,qx,qy,qz"


# ----------------------------------------------------------------------------- the truth


def perturb_imus(imus: Sequence[Imu], rng: np.random.Generator, mount_error_mm: float, mount_error_deg: float
                 ) -> tuple[Imu, ...]:
    """True IMU mounts: the declared ones moved like perturb_rig moves cameras."""
    out = []
    for i in imus:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        T = i.T_body_imu.copy()
        T[:3, :3] = geo.R_from_rotvec(axis * math.radians(rng.normal(0.0, mount_error_deg))) @ T[:3, :3]
        T[:3, 3] += rng.normal(0.0, mount_error_mm / 1000.0, 3)
        out.append(replace(i, T_body_imu=T))
    return tuple(out)


def true_rig_for_motion(rig: Rig, seed: int, time_offset_ms: float, perturbation: dict[str, float]) -> Rig:
    """Cameras as perturb_rig makes them, plus a true clock offset: the declared one (0 when
    none) plus uniform in +-time_offset_ms per camera (declared line delays kept), and
    perturbed IMU mounts."""
    cams = perturb_rig(rig, np.random.default_rng([seed, 1]), **perturbation).cameras
    rng = np.random.default_rng([seed, 3])
    offsets = rng.uniform(-time_offset_ms, time_offset_ms, len(cams)) / 1000.0
    # a declared offset is the nominal one: the truth differs from it like a mount from its design
    cams = tuple(replace(c, time_offset_s=float((rig.camera(c.name).time_offset_s or 0.0) + o),
                         line_delay_s=rig.camera(c.name).line_delay_s) for c, o in zip(cams, offsets))
    imus = perturb_imus(rig.imus, rng, perturbation["mount_error_mm"], perturbation["mount_error_deg"])
    return replace(rig, cameras=cams, imus=imus)


# ----------------------------------------------------------------------------- boards


def camera_groups(rig: Rig) -> list[list[int]]:
    """Camera indices grouped by viewing direction (within GROUP_ANGLE_DEG of the group's first)."""
    groups: list[list[int]] = []
    for ci, cam in enumerate(rig.cameras):
        z = cam.T_body_cam[:3, 2]
        for g in groups:
            if np.degrees(np.arccos(np.clip(z @ rig.cameras[g[0]].T_body_cam[:3, 2], -1, 1))) < GROUP_ANGLE_DEG:
                g.append(ci)
                break
        else:
            groups.append([ci])
    return groups


def plan_boards(rig: Rig, T_world_body: np.ndarray, target: Target | None = None) -> tuple[Target, np.ndarray]:
    """One board per camera group, facing the group's mean optical axis at BOARD_DISTANCE_M from
    its mean pinhole (body pose T_world_body), tilted 15 degrees so its depth varies across the
    image. Generated boards span about BOARD_VIEW_DEG; a given target's boards are used in
    order. Returns the target and T_world_board (B, 4, 4)."""
    groups = camera_groups(rig)
    if target is not None and len(target.boards) < len(groups):
        raise InputError(f"--target: the imu scene needs {len(groups)} boards (one per viewing direction of the "
                         f"rig), the target has {len(target.boards)}")
    poses, boards = [], []
    for gi, g in enumerate(groups):
        Ts = np.stack([T_world_body @ rig.cameras[ci].T_body_cam for ci in g])
        z = Ts[:, :3, 2].mean(axis=0)
        z /= np.linalg.norm(z)
        centre = Ts[:, :3, 3].mean(axis=0) + BOARD_DISTANCE_M * z
        if target is not None:
            board = target.boards[gi]
        else:
            width = 2 * BOARD_DISTANCE_M * math.tan(math.radians(BOARD_VIEW_DEG / 2))
            square = round(width / BOARD_SQUARES[0] * 1000.0, 1) / 1000.0
            per = BOARD_SQUARES[0] * BOARD_SQUARES[1] // 2
            board = Board(name=f"board{gi}", type="charuco", square_length=square, squares=BOARD_SQUARES,
                          dictionary=DICTIONARY, marker_length=round(square * MARKER_RATIO * 1000.0, 1) / 1000.0,
                          first_marker_id=gi * per)
        # board z into the printed face = away from the camera; board y down the print = world down
        x = np.cross(np.array([0.0, 0.0, -1.0]), z)
        if np.linalg.norm(x) < 1e-6:
            x = np.cross(np.array([0.0, 1.0, 0.0]), z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z]) @ geo.R_from_rotvec(np.radians([10.0, 11.0, 0.0]))
        w, h = board.size_m
        poses.append(geo.make_T(R, centre - R @ np.array([w / 2, h / 2, 0.0])))
        boards.append(board)
    return (target if target is not None else Target(boards=tuple(boards))), np.stack(poses)


# ----------------------------------------------------------------------------- timing


@dataclass(frozen=True)
class Timing:
    """Per camera (rig order) its stems (F_c,) int64 ns on its own clock and the IMU-clock
    seconds (since EPOCH_NS) of each frame's mid-exposure first row (F_c,). Synchronised
    cameras at one rate share their stems; free-running ones do not."""

    stems_ns: tuple[np.ndarray, ...]
    t_imu_s: tuple[np.ndarray, ...]
    rates_hz: tuple[float, ...] = ()  # per camera its nominal frame rate

    @property
    def n_images(self) -> int:
        return sum(len(s) for s in self.stems_ns)


def camera_rates(rig: Rig, camera_rate: float | Mapping[str, float]) -> tuple[float, ...]:
    """Per camera (rig order) its frame rate: one rate for all, or name -> rate (InputError
    naming a camera the rig does not declare, or one left without a rate)."""
    if not isinstance(camera_rate, Mapping):
        return tuple(float(camera_rate) for _ in rig.cameras)
    for name in camera_rate:
        if name not in rig.names:
            raise InputError(f"--camera-rate {name}=...: {name} is not a camera of the rig (it declares "
                             f"{', '.join(rig.names)})")
    missing = [c.name for c in rig.cameras if c.name not in camera_rate]
    if missing:
        raise InputError(f"--camera-rate: no rate for camera {missing[0]}; give one rate for all (--camera-rate HZ) "
                         f"or NAME=HZ for every camera")
    return tuple(float(camera_rate[c.name]) for c in rig.cameras)


def camera_schedule(rate: float, duration: float, rng: np.random.Generator, free_running: bool = False,
                    drop: float = 0.0) -> np.ndarray:
    """Capture times (camera clock, s) of one camera within [MARGIN_S, MARGIN_S + duration):
    the grid MARGIN_S + k / rate, or (free_running) its own phase, period error, jitter,
    late start and early stop drawn from `rng`; then `drop` of them removed at random (the
    first and last kept). Strictly increasing."""
    if not free_running:
        n = max(1, int(math.floor(duration * rate + 1e-9)))
        t = MARGIN_S + np.arange(n) / rate
    else:
        period = (1.0 + rng.uniform(-RATE_ERROR, RATE_ERROR)) / rate
        stagger = min(STAGGER_S, duration / 4)
        start = rng.uniform(0.0, stagger) + rng.uniform(0.0, period)
        stop = duration - rng.uniform(0.0, stagger)
        n = max(1, int(math.floor((stop - start) / period)))
        jitter = np.clip(rng.normal(0.0, JITTER_S, n), -0.25 * period, 0.25 * period)
        t = MARGIN_S + start + np.arange(n) * period + jitter
    if drop > 0 and len(t) > 2:
        keep = rng.uniform(size=len(t)) >= drop
        keep[[0, -1]] = True  # the span stays the one asked for
        t = t[keep]
    return t


def frame_timing(rig: Rig, duration: float, camera_rate: float | Mapping[str, float], free_running: bool = False,
                 drop: float = 0.0, seed: int = 0) -> Timing:
    """Every camera's stems and IMU-clock frame times (see the module text: Clocks)."""
    stems, t_imu = [], []
    rates = camera_rates(rig, camera_rate)
    for ci, (c, rate) in enumerate(zip(rig.cameras, rates)):
        t_cam = camera_schedule(rate, duration, np.random.default_rng([seed, SCHEDULE_KEY, ci]), free_running, drop)
        s = EPOCH_NS + np.rint(t_cam * 1e9).astype(np.int64)
        # the stem as written is the truth: offsets apply to the integer time, not to t_cam
        stems.append(s)
        t_imu.append((s - EPOCH_NS) * 1e-9 + (c.time_offset_s or 0.0))
    return Timing(tuple(stems), tuple(t_imu), rates)


def exposure_times(t_first: float, exposure: float, n_sub: int, row_mid: np.ndarray, line_delay: float) -> np.ndarray:
    """(bands, n_sub) IMU-clock times: sub-exposure s of a band whose middle row is row_mid."""
    sub = (np.arange(n_sub) + 0.5) / n_sub * exposure - exposure / 2.0
    return t_first + row_mid[:, None] * line_delay + sub[None, :]


def sub_exposures(motion: imu_model.Motion, fx: float, exposure: float, depth_m: float = BOARD_DISTANCE_M) -> int:
    """Renders to average so the image moves at most MAX_SUBSTEP_PX between two of them."""
    speed_px = fx * (np.linalg.norm(motion.omega_body, axis=1) + np.linalg.norm(motion.v_world, axis=1) / depth_m)
    return int(np.clip(math.ceil(float(speed_px.max()) * exposure / MAX_SUBSTEP_PX), 1, MAX_SUB_EXPOSURES))


# ----------------------------------------------------------------------------- rendering


_STATE: dict[str, Any] = {}


def _set_state(state: dict[str, Any], worker: bool = True) -> None:
    _STATE.clear()
    _STATE.update(state)
    if worker:
        cv2.setNumThreads(1)


def _bands(height: int, line_delay: float | None) -> list[tuple[int, int]]:
    if not line_delay:
        return [(0, height)]
    return [(r, min(r + BAND_ROWS, height)) for r in range(0, height, BAND_ROWS)]


def band_rays(rays: render.SampleRays, bands: list[tuple[int, int]], ss: int) -> list[render.SampleRays]:
    if len(bands) == 1:
        return [rays]
    return [render.SampleRays.from_grid(np.ascontiguousarray(rays.grid[r0 * ss:r1 * ss])) for r0, r1 in bands]


def render_motion_image(ci: int, fi: int) -> np.ndarray:
    """One image (uint8 (H, W)) of camera ci at frame fi from _STATE: the boards averaged over
    the sub-exposures, each band of rows at its own time."""
    rig: Rig = _STATE["rig"]
    st: RenderSettings = _STATE["settings"]
    traj: imu_model.SineTrajectory = _STATE["trajectory"]
    cam = rig.cameras[ci]
    m = cam.intrinsics
    textures = _STATE["textures"]
    T_world_board = _STATE["T_world_board"]
    rng = np.random.default_rng([st.seed, ci, fi, IMAGE_KEY])
    nb = len(textures)
    black, white = rng.uniform(10.0, 60.0), rng.uniform(150.0, 235.0)
    grey = [(black * g, min(white * g, 250.0)) for g in rng.uniform(0.85, 1.08, nb)]
    t_first = float(_STATE["t_imu_s"][ci][fi])
    exposure = _STATE["exposure"]
    bands = _STATE["bands"][ci]
    rows_mid = np.array([(r0 + r1 - 1) / 2.0 for r0, r1 in bands])
    delay = cam.line_delay_s or 0.0
    span = np.array([t_first - exposure / 2, t_first + rows_mid[-1] * delay + exposure / 2])
    n_sub = sub_exposures(traj.at(span), m.fx, exposure) if exposure > 0 else 1
    times = exposure_times(t_first, exposure, n_sub, rows_mid, delay)
    T_world_cam = traj.at(times.ravel()).T_world_body @ cam.T_body_cam  # (bands * n_sub, 4, 4)
    T_cam_world = geo.inv_T(T_world_cam).reshape(len(bands), n_sub, 4, 4)
    fg = np.zeros((m.height, m.width), np.float32)
    alpha = np.zeros_like(fg)
    for b, ((r0, r1), rays) in enumerate(zip(bands, _STATE["band_rays"][ci])):
        band_model = m.with_(cy=m.cy - r0, height=r1 - r0) if len(bands) > 1 else m
        for s in range(n_sub):
            v, a = render.render_boards(band_model, rays, [T_cam_world[b, s] @ T for T in T_world_board], textures,
                                        grey, st.ss)
            fg[r0:r1] += v
            alpha[r0:r1] += a
    fg /= n_sub
    alpha /= n_sub
    bg = render.background(m.width, m.height, rng)
    look = render.Look(noise=st.noise, blur_px=0.0, blur_angle=0.0, optics_sigma_px=st.optics_sigma_px)
    return render.finish(fg, alpha, bg, _STATE["vignettes"][ci], look, rng)


def _render_and_write(ci: int, fi: int, path: str) -> float:
    t0 = time.process_time()
    img = render_motion_image(ci, fi)
    if not cv2.imwrite(path, img, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        raise OutputError(f"{path}: cannot write the image")
    return time.process_time() - t0


# ----------------------------------------------------------------------------- files


def _num(x: float) -> str:
    return repr(float(x))  # shortest text that reads back to the same double


def trajectory_csv(t_ns: np.ndarray, T_world_body: np.ndarray) -> str:
    """truth_trajectory.csv: t_ns, position and unit quaternion (w >= 0) of T_world_body."""
    rows = []
    for t, T in zip(t_ns, T_world_body):
        q = geo.quat_from_R(T[:3, :3])
        q = -q if q[0] < 0 else q
        rows.append(f"{int(t)}," + ",".join(_num(x) for x in (*T[:3, 3], *q)))
    return TRAJECTORY_HEADER + "\n" + "\n".join(rows) + "\n"


def _pose_dict(T: np.ndarray) -> dict[str, Any]:
    return {"rotation": [[float(x) + 0.0 for x in row] for row in T[:3, :3]],
            "position": [float(x) + 0.0 for x in T[:3, 3]]}


def _bias_samples(stream: imu_model.ImuStream, rate: float) -> dict[str, Any]:
    step = max(1, int(round(rate / imu_model.BIAS_SAMPLE_HZ)))
    idx = np.arange(0, len(stream.t), step)
    t_ns = [int(x) for x in EPOCH_NS + np.rint(stream.t[idx] * 1e9).astype(np.int64)]
    return {"gyroscope_bias": {"t_ns": t_ns, "values": stream.gyro_bias[idx].tolist()},
            "accelerometer_bias": {"t_ns": t_ns, "values": stream.accel_bias[idx].tolist()}}


# ----------------------------------------------------------------------------- the library entry


@dataclass(frozen=True)
class MotionSimResult:
    """What simulate_motion_dataset wrote and the truth it used."""

    out_dir: Path
    declared: Rig
    truth: Rig
    target: Target
    T_world_board: np.ndarray
    trajectory: imu_model.SineTrajectory
    timing: Timing
    streams: dict[str, imu_model.ImuStream]
    image_paths: dict[str, tuple[Path, ...]]
    coverage: dict[str, CameraCoverage]
    excitation: dict[str, list[float]]
    seconds: float
    image_cpu_seconds: float


def check_motion_settings(rig: Rig, duration: float, camera_rate: float | Mapping[str, float], exposure: float,
                          time_offset_ms: float, label: str, drop: float = 0.0) -> None:
    if not rig.imus:
        raise InputError(f"{label}: imus: --scene imu needs a rig that declares an IMU (docs/formats.md#motion-datasets)")
    rates = camera_rates(rig, camera_rate) if rig.cameras else ()
    for flag, v, lo, hi in (("--duration", duration, 0.0, 3600.0),
                            *(("--camera-rate", r, 0.0, 1000.0) for r in rates),
                            ("--time-offset-ms", time_offset_ms, -1e-12, 100.0)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo < v <= hi):
            raise InputError(f"{flag}: expected a number above {max(lo, 0):g} and at most {hi:g}, got {v!r}")
    if not (isinstance(drop, (int, float)) and 0.0 <= drop < 1.0):
        raise InputError(f"--drop-frames: expected a fraction from 0 to below 1, got {drop!r}")
    fastest = max(rates, default=1.0)
    if not (isinstance(exposure, (int, float)) and math.isfinite(exposure) and 0 <= exposure < 1.0 / fastest):
        raise InputError(f"--exposure: expected seconds from 0 to below one frame period ({1 / fastest:g} s), "
                         f"got {exposure!r}")


def simulate_motion_dataset(rig: Rig, out_dir: str | Path, *, duration: float = DEFAULTS["duration"],
                            camera_rate: float | Mapping[str, float] = DEFAULTS["camera_rate"],
                            exposure: float = DEFAULTS["exposure"], free_running: bool = False, drop: float = 0.0,
                            time_offset_ms: float = DEFAULTS["time_offset_ms"], seed: int = 0, noise: float = 2.0,
                            mount_error_mm: float = 5.0, mount_error_deg: float = 1.0, focal_error: float = 0.02,
                            target: Target | None = None, imu_noise: bool = True, force: bool = False,
                            jobs: int | None = None, progress: bool = False, rig_text: str | None = None,
                            target_text: str | None = None, label: str = "<rig>") -> MotionSimResult:
    """Render a motion dataset (docs/formats.md#motion-datasets) of `rig` into out_dir, whole or not at all. camera_rate:
    one rate or camera name -> rate; free_running: every camera on its own schedule (module
    text); drop: the fraction of frames dropped at random."""
    t0 = time.perf_counter()
    check_motion_settings(rig, duration, camera_rate, exposure, time_offset_ms, label, drop)
    for cam in rig.cameras:
        if cam.T_body_cam is None:
            raise InputError(f"{label}: cameras.{cam.name}: has no pose; simulate needs every camera's pose")
    jobs = jobs or os.cpu_count() or 1
    perturbation = {"mount_error_mm": mount_error_mm, "mount_error_deg": mount_error_deg, "focal_error": focal_error}
    truth = true_rig_for_motion(rig, seed, time_offset_ms, perturbation)
    traj = imu_model.hand_held_trajectory(np.random.default_rng([seed, 2]))
    target, T_world_board = plan_boards(truth, _mean_pose(traj), target)
    timing = frame_timing(truth, duration, camera_rate, free_running, drop, seed)
    t_end = duration + 2 * MARGIN_S
    _check_inside_imu_stream(truth, timing, exposure, t_end, label)
    settings = RenderSettings(seed=seed, noise=float(noise), blur=0.0, optics_sigma_px=OPTICS_SIGMA_PX)
    streams = {}
    for ii, i in enumerate(truth.imus):
        t = np.arange(int(math.floor(t_end * i.update_rate)) + 1) / i.update_rate
        streams[i.name] = imu_model.synthesize(traj.at(t), i, np.random.default_rng([seed, 4, ii]), noise=imu_noise)
    cover = {}
    for c, stems, t in zip(truth.cameras, timing.stems_ns, timing.t_imu_s):  # each camera at its own times
        own = Scene(name="imu", target=target, frames=tuple(str(x) for x in stems),
                    T_world_body=traj.at(t).T_world_body,
                    T_world_board=np.repeat(T_world_board[None], len(stems), axis=0), moving_boards=False)
        cover.update(coverage(truth.with_cameras([c]), own))
        scene = own  # prepare_state reads the target from it
    out_dir = Path(out_dir)
    with atomic_dir(out_dir, force=force) as tmp:
        state = prepare_state(truth, scene, settings, jobs)
        state.update(trajectory=traj, T_world_board=list(T_world_board), t_imu_s=timing.t_imu_s, exposure=exposure,
                     bands=[_bands(c.intrinsics.height, c.line_delay_s) for c in truth.cameras])
        state["band_rays"] = [band_rays(r, b, settings.ss) for r, b in zip(state["rays"], state["bands"])]
        tasks, paths = [], {}
        for ci, cam in enumerate(truth.cameras):
            d = tmp / "images" / cam.name
            d.mkdir(parents=True)
            paths[cam.name] = tuple(out_dir / "images" / cam.name / f"{s}.png" for s in timing.stems_ns[ci])
            tasks += [(ci, fi, str(d / f"{s}.png")) for fi, s in enumerate(timing.stems_ns[ci])]
        cpu = run_render_tasks(state, tasks, jobs, progress, work=_render_and_write, init=_set_state,
                               preload="rigcal.sim.imu_scene")
        _write_files(tmp, rig, truth, target, T_world_board, traj, streams, timing, settings, exposure, rig_text,
                     target_text, perturbation)
        if truth.magnetometers:  # docs/magnetometer.md: mag/ along the same motion, its truth in truth.yaml
            from rigcal.sim.mag_scene import add_magnetometers

            add_magnetometers(tmp, truth, traj, seed, t_end)
    return MotionSimResult(out_dir, rig, truth, target, T_world_board, traj, timing, streams, paths, cover,
                           imu_model.excitation(traj.at(np.arange(0.0, t_end, 0.005))), time.perf_counter() - t0, cpu)


def _check_inside_imu_stream(truth: Rig, timing: Timing, exposure: float, t_end: float, label: str) -> None:
    """Every row of every image is exposed while the IMUs sample (0 .. t_end on their clock)."""
    for c, t in zip(truth.cameras, timing.t_imu_s):
        readout = (c.line_delay_s or 0.0) * c.intrinsics.height
        if t[0] - exposure / 2 < 0 or t[-1] + readout + exposure / 2 > t_end:
            raise InputError(f"{label}: cameras.{c.name}: its clock offset ({c.time_offset_s:+.3f} s with the "
                             f"perturbation) and readout ({readout:.3f} s) put images outside the IMU stream, which "
                             f"starts {MARGIN_S:g} s before the first image; declare a smaller time_offset_s")


def _mean_pose(traj: imu_model.SineTrajectory) -> np.ndarray:
    """The trajectory's centre: position p0, level, at its base heading."""
    return geo.make_T(geo.R_from_rotvec(np.array([0.0, 0.0, traj.ypr0[0]])), traj.p0)


def _write_files(tmp: Path, declared: Rig, truth: Rig, target: Target, T_world_board: np.ndarray,
                 traj: imu_model.SineTrajectory, streams: dict[str, imu_model.ImuStream], timing: Timing,
                 settings: RenderSettings, exposure: float, rig_text: str | None, target_text: str | None,
                 perturbation: dict[str, float]) -> None:
    dump = lambda d: yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=120)  # noqa: E731
    (tmp / "rig.yaml").write_text(rig_text if rig_text is not None else dump(rig_to_dict(declared)), encoding="utf-8")
    (tmp / "target.yaml").write_text(target_text if target_text is not None else dump_target(target), encoding="utf-8")
    (tmp / "imu").mkdir()
    first = next(iter(streams.values()))
    for name, s in streams.items():
        t_ns = EPOCH_NS + np.rint(s.t * 1e9).astype(np.int64)
        (tmp / "imu" / f"{name}.csv").write_text(imu_csv(t_ns, s.gyro, s.accel), encoding="utf-8")
    t_ns = EPOCH_NS + np.rint(first.t * 1e9).astype(np.int64)
    (tmp / "truth_trajectory.csv").write_text(trajectory_csv(t_ns, traj.at(first.t).T_world_body), encoding="utf-8")
    rates = {i.name: i.update_rate for i in truth.imus}
    doc = {
        "rig": rig_to_dict(truth),
        "imus": {n: _bias_samples(s, rates[n]) for n, s in streams.items()},
        "gravity_world": [float(x) + 0.0 for x in imu_model.G_WORLD],
        "boards": {b.name: _pose_dict(T) for b, T in zip(target.boards, T_world_board)},
        "render": {"seed": int(settings.seed), "scene": "imu", "noise_sigma": float(settings.noise),
                   **_frames_truth(truth, timing), "exposure_s": float(exposure),
                   "supersampling": int(settings.ss), "optics_sigma_px": float(settings.optics_sigma_px),
                   "rolling_shutter_band_rows": BAND_ROWS, "epoch_ns": EPOCH_NS,
                   **{k: float(v) for k, v in perturbation.items()}},
    }
    (tmp / "truth.yaml").write_text(dump(doc), encoding="utf-8")


def _frames_truth(truth: Rig, timing: Timing) -> dict[str, Any]:
    """truth.yaml's render.frames and camera_rate_hz: numbers when every camera has the same
    stems, else per camera (name -> value), with free_running when the stems differ."""
    first = timing.stems_ns[0]
    if all(len(s) == len(first) and np.array_equal(s, first) for s in timing.stems_ns):
        return {"frames": len(first), "camera_rate_hz": float(1e9 / np.diff(first).mean()) if len(first) > 1 else None}
    return {"frames": {c.name: len(s) for c, s in zip(truth.cameras, timing.stems_ns)},
            "camera_rate_hz": {c.name: float(r) for c, r in zip(truth.cameras, timing.rates_hz)},
            "shared_stems": False}


# ----------------------------------------------------------------------------- the command


def parse_camera_rates(values: Sequence[str] | None) -> float | dict[str, float] | None:
    """`--camera-rate` given any number of times: None (not given), one HZ for every camera,
    or NAME=HZ per camera (InputError on anything else: one line naming the value)."""
    if not values:
        return None
    plain = [v for v in values if "=" not in v]
    if plain and len(values) > 1:
        raise InputError(f"--camera-rate: give one HZ for every camera or NAME=HZ per camera, not both "
                         f"({', '.join(values)})")
    out: dict[str, float] = {}
    for v in values:
        name, _, hz = v.rpartition("=")
        try:
            rate = float(hz)
        except ValueError:
            raise InputError(f"--camera-rate: {v!r}: expected HZ or NAME=HZ (a number of images per second)") from None
        if not plain:
            if name in out:
                raise InputError(f"--camera-rate: camera {name} given twice")
            out[name.strip()] = rate
        else:
            return rate
    return out


def run(rig_path, out_dir, duration=None, camera_rate=None, exposure=None, time_offset_ms=None, seed=0, noise=2.0,
        mount_error_mm=5.0, mount_error_deg=1.0, focal_error=0.02, target_path=None, force=False, jobs=None,
        free_running=False, drop=0.0) -> str:
    """`rigcal simulate --scene imu`: returns the summary for stdout. rig_path: a file or a
    shipped rig's name; camera_rate: a number, name -> number, or --camera-rate's texts."""
    from rigcal.core.target import load_target
    from rigcal.core.validate import read_text
    from rigcal.errors import RigFileError, TargetFileError

    rig_path = rig_file(rig_path)  # a shipped rig's name gives its file
    rig = load_rig(rig_path)
    if isinstance(camera_rate, (list, tuple)):
        camera_rate = parse_camera_rates(camera_rate)
    target = target_text = None
    if target_path is not None:
        target = load_target(target_path)
        target_text = read_text(target_path, TargetFileError)
    res = simulate_motion_dataset(
        rig, out_dir, duration=DEFAULTS["duration"] if duration is None else duration,
        camera_rate=DEFAULTS["camera_rate"] if camera_rate is None else camera_rate,
        exposure=DEFAULTS["exposure"] if exposure is None else exposure,
        time_offset_ms=DEFAULTS["time_offset_ms"] if time_offset_ms is None else time_offset_ms, seed=seed,
        noise=noise, mount_error_mm=mount_error_mm, mount_error_deg=mount_error_deg, focal_error=focal_error,
        target=target, force=force, jobs=jobs, progress=sys.stderr.isatty(), free_running=free_running, drop=drop,
        rig_text=read_text(rig_path, RigFileError),
        target_text=target_text, label=str(rig_path))
    return summary(res)


def summary(res: MotionSimResult) -> str:
    n_img = sum(len(v) for v in res.image_paths.values())
    ex = res.excitation
    fmt = lambda v, d=0: "/".join(f"{x:.{d}f}" for x in v)  # noqa: E731
    counts = sorted({len(s) for s in res.timing.stems_ns})
    per = str(counts[0]) if len(counts) == 1 else "/".join(str(len(s)) for s in res.timing.stems_ns)
    shared = all(np.array_equal(s, res.timing.stems_ns[0]) for s in res.timing.stems_ns)
    lines = [f"wrote {res.out_dir}: imu scene, {per} frames per camera"
             f"{'' if shared else ' (own stems per camera)'}, {n_img} images, "
             f"{len(res.streams)} IMU stream(s), {len(res.target.boards)} board(s), {res.seconds:.1f} s",
             f"  motion: peak rate {fmt(ex['peak_rate_deg_s'])} deg/s (body x/y/z), peak acceleration "
             f"{fmt(ex['peak_accel_m_s2'], 1)} m/s^2 (world x/y/z), position range {fmt(ex['position_range_m'], 2)} m"]
    for c in res.truth.cameras:
        cov = res.coverage[c.name]
        lines.append(f"  {c.name}: sees a board in {cov.frames_with_board}/{cov.frames} frames; true clock offset "
                     f"{c.time_offset_s * 1000:+.2f} ms" + (f", rolling shutter {c.line_delay_s * 1e6:g} us/row"
                                                            if c.line_delay_s else ""))
    for name, s in res.streams.items():
        lines.append(f"  {name}: {len(s.t)} samples; turn-on gyro bias {fmt(np.degrees(s.gyro_bias[0]) * 3600)} "
                     f"deg/h, accel bias {fmt(s.accel_bias[0], 3)} m/s^2")
    weak = [c for c, v in res.coverage.items() if v.frames_with_board == 0]
    if weak:
        lines.append(f"warning: {', '.join(weak)} never see a board")
    return "\n".join(lines)
