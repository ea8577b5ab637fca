"""The calibration pipeline: calibrate_views chains the stages, from board views to a calibrated rig.

Each stage is a function with its own named result (docs/how-it-works.md):
usable_views -> start_cameras (initialise) -> resolve_flips (initialise) -> start_rig
(pose_graph) -> first_solve (solve) -> choose_models (model_selection) -> guided_pass ->
weighted_pass -> finish (body_frame). No image I/O here (that is detect.py) and no files
(calibrate.py): BoardViews in, a calibrated Rig and its statistics out, so tests can drive
it with synthetic corners.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace
from typing import Callable, NamedTuple

import numpy as np

from rigcal.core import geometry as geo
from rigcal.camcal.body_frame import check_reference, extrinsic_covariance, reference_transform
from rigcal.core.camera import PINHOLE_MODEL_NAMES, CameraModel
from rigcal.errors import CalibrationError, InputError
from rigcal.camcal.initialise import (MIN_VIEW_CORNERS, RIGIDITY_RATIO, MonoInit, PosedViews, fixed_intrinsics_misfit,
                                      init_camera, opencv_one_thread, own_views_intrinsics, own_views_start,
                                      resolve_flips)
from rigcal.camcal.model_selection import (INTRINSICS_CHOICES, forced_structure, intrinsic_sigmas, intrinsics_model,
                                           reduce_models, solve_covariance)
from rigcal.core.observations import BoardView
from rigcal.camcal.pose_graph import PoseGraph, ViewLink, pose_graph
from rigcal.core.rig import Camera, Rig
from rigcal.camcal.solve import (Intrinsics, NoiseModel, Observations, Problem, SolveResult, State, bundle_adjust,
                                 fit_noise_model, intrinsics_covariance, judge_inliers, noise_weights,
                                 provisional_result, robust_pass)

MIN_FRAMES = 3
# sampled_rigidity (imu_start): the frames its robust pass samples, and how far its rigidity
# factor must exceed the threshold for the verdict to stand without the joint solve over every
# frame (the least-squares rounds lower the factor by a few per cent where it was measured:
# 17.5 -> 17.0 on the 30 s recording)
RIGIDITY_SAMPLE_FRAMES = 150
EARLY_RIGIDITY_MARGIN = 1.5
# A camera whose corners miss the solved rig by more than this share of its image diagonal
# (RMS; at least GROSS_RMS_MIN_PX) failed to calibrate: a target.yaml that misnumbers the
# board, mirrored images, a chessboard declared on a ChArUco print. The real sets stay under
# 0.12 % (the worst, the unsynchronised caliscope webcams: 1.6 px of a 1469 px diagonal).
GROSS_RMS_FRACTION = 0.01
GROSS_RMS_MIN_PX = 5.0
# corner weights: fit each camera's NoiseModel on the residuals, re-weight, re-solve; the
# second fit is on the weighted solve's residuals (the first on the unweighted one's)
NOISE_ROUNDS = 2


@dataclass
class CameraStats:
    """One camera's statistics after the solve: reprojection RMS and counts over its inlier
    corners, outliers (PnP refusals included), the distortion model, sigmas of its pose
    (about and along body F, L, U) and intrinsics, and the model-selection log."""

    name: str
    rms_px: float
    observations: int
    frames: int
    outliers: int
    distortion_model: str
    sigma_position_mm: np.ndarray | None = None
    sigma_rotation_deg: np.ndarray | None = None
    sigma_intrinsics: dict | None = None
    model_selection: list = field(default_factory=list)
    # which intrinsics were estimated: {focal: fx=fy | fx,fy | declared, principal_point:
    # held | free | declared, distortion: model name} (intrinsics_model)
    intrinsics_model: dict | None = None
    # 1-sigma of fx, fy, cx, cy (px) when all four were estimated, before the structure was
    # chosen: how poorly a tied or held parameter is determined (None: not tested)
    sigma_intrinsics_free: dict | None = None


@dataclass
class Calibration:
    """What calibrate_views returns: the calibrated rig (body frame per reference), per camera
    CameraStats, the final solve (state, problem, observations, inliers) with the names its
    indices refer to, T_body_solve, the extrinsics covariance, timings and notes."""

    rig: Rig  # calibrated (body frame per reference)
    stats: dict[str, CameraStats]
    reference: str
    rms_px: float
    sigma_px: float
    state: State
    problem: Problem
    obs: Observations  # all observations fed to the solve
    inliers: np.ndarray
    frames: list[str]
    boards: list[str]
    cam_names: list[str]
    T_body_solve: np.ndarray  # maps the solver's body (gauge camera) frame into the output body frame
    cov_extrinsics: np.ndarray | None  # (6C, 6C) [rot about body axes (rad), position (m)] per camera
    timings: dict
    notes: list[str]
    flips: int = 0
    declared: Rig | None = None  # the rig as declared (initial guess and body-frame reference)
    # per observation (obs order): the detector's own 1-sigma px (NaN unknown; None: no view had one)
    corner_sigma_detected: np.ndarray | None = None
    noise_models: list | None = None  # per camera the NoiseModel the corners were weighted by (or None)
    # (V, 4, 4) per view of obs (obs.view indexes it) a pose T_cam_board for the camera-IMU
    # step's start, where it was made with the intrinsics that step starts from: the PnP of
    # start_cameras, on every corner, when they are held; each camera's own-views solve's
    # when they came from it (own_view_poses). None otherwise (EuRoC without a camera
    # calibration: started from poses of the 20-view start intrinsics, calibrate took 84 s
    # CPU against 58)
    view_T_cam_board: np.ndarray | None = None


# ----------------------------------------------------------------------------- the pipeline


@dataclass(frozen=True)
class Setup:
    """What every stage of calibrate_views reads and none changes: the declared rig, the
    boards' corners (name -> (N, 3) points), the frame names in order, and the options."""

    rig: Rig
    corners: dict[str, np.ndarray]
    frames: list[str]
    distortion: str = "auto"
    fix_intrinsics: bool = False
    intrinsics: str = "auto"
    faces: dict[str, float] | None = None
    # with fix_intrinsics: note cameras whose own views fit the declared intrinsics badly
    # (a calibrateCamera per camera; `rigcal check` tests the intrinsics itself)
    misfit_notes: bool = True
    # the camera-only result is the start of a camera-IMU step that re-estimates the
    # intrinsics: own-views intrinsics start from initialise.own_views_start (no OpenCV
    # fit), the same optimum from there
    imu_start: bool = False

    @property
    def cam_names(self) -> list[str]:
        return list(self.rig.names)

    @property
    def board_names(self) -> list[str]:
        return list(self.corners)

    @property
    def centres(self) -> list[tuple[float, float]]:
        """Per camera the declared principal point (where --intrinsics holds it)."""
        return [(self.rig.camera(n).intrinsics.cx, self.rig.camera(n).intrinsics.cy) for n in self.cam_names]


def calibrate_views(views: list[BoardView], rig: Rig, corners: dict[str, np.ndarray],
                    distortion: str = "auto", fix_intrinsics: bool = False, reference: str = "aligned",
                    weight_corners: bool = False, rerefine: Callable | None = None,
                    intrinsics: str = "auto", faces: dict[str, float] | None = None,
                    imu_start: bool = False) -> Calibration:
    """The whole calibration from detected views. corners: board name -> (N, 3) object points.

    The stages in order (docs/how-it-works.md): usable_views, start_cameras
    (initialise), resolve_flips (initialise), start_rig (pose_graph), first_solve,
    choose_models (model_selection), guided_pass, weighted_pass, finish.

    intrinsics: auto (fx = fy and the principal point held at its declared value unless the
    data show otherwise, INTRINSICS_LEVEL) or a structure of INTRINSICS_CHOICES imposed.
    weight_corners: weight each corner by its detector sigma (BoardView.sigma) calibrated per
    camera (weighted_solve). Off by default: measured over 10 seeds (bench.noise_limit) it
    lowers the fisheye pair's rotation error only 1.61 -> 1.48 x its bound and raises some
    pinhole pairs' errors by 12-28 % (docs/accuracy.md).
    rerefine: `f(obs, state, cam_names, frames, boards) -> (uv, refined, sigma)` re-measures
    the corners once the rig is solved (guided.guided_uv: the cross placed by the calibrated
    model); the rig is then solved again on them. None: the detector's corners are final.
    faces: board name -> the sign of board z on its printed side (-1, OpenCV's boards, when
    absent; +1 for Kalibr's AprilGrid frame: Board.print_face).
    imu_start: the result starts a camera-IMU step that re-estimates the intrinsics (a motion
    dataset with an IMU, --imu-intrinsics joint or prior; held keeps this step's exactly, as
    --camera-only gives them): the rigidity check is made first on a sample of the frames
    (sampled_rigidity), and where the rig is not rigid per frame, each pinhole camera's
    own-views solve starts from initialise.own_views_start (mono()'s views and k3 test, fitted
    by the sparse one-camera solve instead of OpenCV; the solve over every view reaches the
    same optimum; on the 30 s three-camera recording 4.3 -> 1.8 s CPU for the three cameras'
    own-views intrinsics)."""
    t0 = time.perf_counter()
    setup = Setup(rig, corners, sorted({v.frame for v in views}), distortion, fix_intrinsics, intrinsics, faces,
                  imu_start=imu_start)
    check_reference(reference, rig)
    if intrinsics != "auto" and intrinsics not in INTRINSICS_CHOICES:
        raise InputError(f"--intrinsics: expected one of auto, {', '.join(INTRINSICS_CHOICES)}, got {intrinsics!r}")
    usable = usable_views(views, setup.cam_names, fix_intrinsics)
    starts = start_cameras(usable.by_cam, setup)
    timings = {"intrinsics_s": time.perf_counter() - t0}
    flipped = resolve_flips(starts.posed, len(setup.cam_names), [corners[b] for b in setup.board_names])
    rig_start = start_rig(flipped.posed, setup)
    timings["graph_s"] = time.perf_counter() - t0 - timings["intrinsics_s"]
    chosen = choose_models(first_solve(flipped.posed, rig_start, starts.inits, setup), starts.inits, usable.by_cam,
                           setup)
    solved, notes = chosen.solve, usable.notes + starts.notes + flipped.notes + rig_start.notes + chosen.notes
    if rerefine is not None:
        guided = guided_pass(solved, rerefine, setup)
        solved, timings["guided_s"] = guided.solve, guided.rerefine_s
        notes.append(guided.note)
    weighted = weighted_pass(solved, weight_corners)
    solved = weighted.solve
    timings["solve_s"] = solved.seconds
    if not solved.res.converged:
        notes.append("bundle adjustment stopped at its iteration limit before converging")
    logs = {n: starts.selection[n] + chosen.logs.get(c, []) for c, n in enumerate(setup.cam_names)}
    out = finish(solved, setup, reference, starts.inits, starts.refused, chosen, logs)
    timings["total_core_s"] = time.perf_counter() - t0
    res = solved.res
    return Calibration(
        rig=out.rig, stats=out.stats, reference=reference, rms_px=out.rms_px, sigma_px=res.sigma_px,
        state=res.state, problem=res.problem, obs=solved.obs, inliers=res.inliers, frames=setup.frames,
        boards=setup.board_names, cam_names=setup.cam_names, T_body_solve=out.T_body_solve,
        cov_extrinsics=out.cov_extrinsics, timings=timings, notes=notes, flips=flipped.flips, declared=rig,
        corner_sigma_detected=solved.sigma_det, noise_models=weighted.noise_models,
        view_T_cam_board=start_poses(flipped.posed, rig_start) if fix_intrinsics else
        own_view_poses(flipped, rig_start, chosen.own) if imu_start else None)


@dataclass(frozen=True)
class UsableViews:
    """usable_views' answer: per camera name the views the calibration uses (at least
    MIN_VIEW_CORNERS corners, exact repeats dropped), and notes on the repeats."""

    by_cam: dict[str, list[BoardView]]
    notes: list[str]


def usable_views(views: list[BoardView], cam_names: list[str], fix_intrinsics: bool) -> UsableViews:
    """Each camera's views with enough corners, without exact repeats; CalibrationError when
    a camera has no view, or (intrinsics to calibrate) views in fewer than MIN_FRAMES frames."""
    by_cam = {n: [v for v in views if v.camera == n and len(v.ids) >= MIN_VIEW_CORNERS] for n in cam_names}
    repeats, notes = {}, []
    for n in cam_names:
        by_cam[n], repeats[n] = drop_repeated_views(by_cam[n])
        if repeats[n]:
            shown = ", ".join(f"{a} = {b}" for a, b in repeats[n][:3]) + (", ..." if len(repeats[n]) > 3 else "")
            notes.append(f"{n}: {len(repeats[n])} view(s) repeat another frame's corners exactly ({shown}) and were "
                         f"used once: the same image under several names, or a frozen camera?")
    for n, vs in by_cam.items():
        nf = len({v.frame for v in vs})
        if nf == 0:
            raise CalibrationError(f"{n}: no usable board views (no board detected in any image of this camera)")
        if nf < MIN_FRAMES and not fix_intrinsics:
            again = f" (and {len(repeats[n])} exact repeats of them)" if repeats[n] else ""
            raise CalibrationError(f"{n}: boards detected in only {nf} frame(s){again}; at least {MIN_FRAMES} are "
                                   f"needed to calibrate its intrinsics (or use --fix-intrinsics to keep the "
                                   f"declared ones)")
    return UsableViews(by_cam=by_cam, notes=notes)


@dataclass(frozen=True)
class CameraStarts:
    """start_cameras' answer: per camera its MonoInit (intrinsics, per-view PnP, log), the
    views PnP posed (PosedViews), per camera the corners of views PnP refused (C,), the
    model-selection log per camera name, and notes."""

    inits: list[MonoInit]
    posed: PosedViews
    refused: np.ndarray
    selection: dict[str, list[str]]
    notes: list[str]


def start_cameras(by_cam: dict[str, list[BoardView]], setup: Setup) -> CameraStarts:
    """Initial intrinsics and a PnP pose per view, camera by camera (initialise.init_camera).
    Serial on purpose: OpenCV and BLAS already use every core, and a thread per camera
    measured slower (2.3 s vs 1.8 s for 3 cameras, 2 cores)."""
    fi = {n: i for i, n in enumerate(setup.frames)}
    bi = {n: i for i, n in enumerate(setup.board_names)}
    inits, selection, notes, posed = [], {}, [], []
    refused = np.zeros(len(setup.cam_names), int)
    for c, n in enumerate(setup.cam_names):
        declared = setup.rig.camera(n).intrinsics
        mi = init_camera(by_cam[n], setup.corners, declared, setup.distortion, setup.fix_intrinsics, setup.faces)
        inits.append(mi)
        selection[n] = list(mi.log)
        if setup.fix_intrinsics and setup.misfit_notes:
            misfit = fixed_intrinsics_misfit(by_cam[n], setup.corners, declared, mi, setup.faces)
            if misfit is not None:
                notes.append(f"{n}: {misfit}")
        for v, T in zip(by_cam[n], mi.T_cam_board):
            if T is None:  # no pose with the camera in front of the print: mirrored or garbage
                refused[c] += len(v.ids)
                continue
            posed.append((v, c, fi[v.frame], bi[v.board], T[0], T[1]))
    views, cam, frame, board, T_cam_board, rms = (tuple(x) for x in zip(*posed)) if posed else ((),) * 6
    return CameraStarts(inits=inits, posed=PosedViews(views=views, cam=cam, frame=frame, board=board,
                                                      T_cam_board=T_cam_board, rms_px=rms),
                        refused=refused, selection=selection, notes=notes)


@dataclass(frozen=True)
class RigStart:
    """start_rig's answer: the gauge camera (the body frame during the solve), the pose
    graph's start poses, and notes (cameras placed by hand-eye, boards left out)."""

    gauge_cam: int
    graph: PoseGraph
    notes: list[str]


def start_rig(posed: PosedViews, setup: Setup) -> RigStart:
    """The pose graph over the posed views; the gauge camera is the one with the most views
    (best conditioned)."""
    cam_names, board_names = setup.cam_names, setup.board_names
    counts = np.bincount(list(posed.cam), minlength=len(cam_names))
    gauge_cam = int(np.argmax(counts))
    links = [ViewLink(*x) for x in zip(posed.cam, posed.frame, posed.board, posed.T_cam_board)]
    graph = pose_graph(links, len(cam_names), len(setup.frames), len(board_names), gauge_cam, cam_names, board_names)
    notes = [f"{cam_names[c]}: no other camera sees its boards; its start came from the rig's own motion (hand-eye), "
             f"and the joint solve placed it from there" for c in graph.by_hand_eye]
    notes += [f"board {board_names[b]}: could not be linked to the rig; its views are not used"
              for b in graph.missing_boards]
    return RigStart(gauge_cam=gauge_cam, graph=graph, notes=notes)


@dataclass(frozen=True)
class JointSolve:
    """The bundle adjustment as it stands after a stage: its result, the observations it ran
    on, each one's detector sigma (None: no view had one), which cameras' intrinsics are
    held (C,) bool, the gauge camera and board, camera_covariance(res) when already
    computed (else None), and the solver seconds so far. start: where res covers a sample
    of the frames only (sampled_rigidity), the state over every frame to go on from."""

    res: SolveResult
    obs: Observations
    sigma_det: np.ndarray | None
    fix: np.ndarray
    gauge_cam: int
    gauge_board: int
    covariance: tuple | None
    seconds: float
    start: State | None = None


def first_solve(posed: PosedViews, rig_start: RigStart, inits: list[MonoInit], setup: Setup,
                start: list[Intrinsics] | None = None, fix: np.ndarray | None = None) -> JointSolve:
    """Bundle adjustment over every corner of every view the pose graph could place, from
    its start poses and each camera's start intrinsics (structure imposed by --intrinsics).
    start, fix: per camera the intrinsics (values and structure) to start from and which
    are held, instead of the inits' and setup's (`rigcal check`: the rig's own structure)."""
    graph = rig_start.graph
    use = _used_views(posed, graph)
    obs = _observations(posed, use, setup.corners, setup.board_names)
    if start is None:
        start = [Intrinsics(setup.rig.camera(n).intrinsics.model, mi.values.copy())
                 for n, mi in zip(setup.cam_names, inits)]
        if not setup.fix_intrinsics:
            start = [forced_structure(it, setup.intrinsics, setup.centres[c]) for c, it in enumerate(start)]
    state = State(start, graph.T_cam_body, graph.T_body_world, graph.T_world_board)
    if fix is None:
        fix = np.full(len(setup.cam_names), setup.fix_intrinsics)
    sigma_det = _detected_sigma(posed, use)
    if setup.imu_start and not fix.all():
        sampled = sampled_rigidity(obs, state, rig_start.gauge_cam, graph.gauge_board, fix, inits, setup.cam_names)
        if sampled is not None:
            res, start = sampled
            return JointSolve(res=res, obs=obs, sigma_det=sigma_det, fix=fix, gauge_cam=rig_start.gauge_cam,
                              gauge_board=graph.gauge_board, covariance=None, seconds=res.seconds, start=start)
    res = bundle_adjust(obs, state, rig_start.gauge_cam, graph.gauge_board, fix)
    return JointSolve(res=res, obs=obs, sigma_det=sigma_det, fix=fix, gauge_cam=rig_start.gauge_cam,
                      gauge_board=graph.gauge_board, covariance=None, seconds=res.seconds)


def frame_sample(obs: Observations, n_frames: int, n_cams: int, n_boards: int) -> np.ndarray | None:
    """(M,) bool: the corners of every k-th frame in the frames' order (their names sorted:
    time on a motion dataset, whose names are nanosecond stems), k = frames // n_frames, when
    that keeps every camera and every board with MIN_VIEW_CORNERS corners or more; None when
    k < 2 or a camera or board would be lost."""
    frames = np.unique(obs.frame)
    k = len(frames) // n_frames
    if k < 2:
        return None
    m = np.isin(obs.frame, frames[::k])
    if (np.bincount(obs.cam[m], minlength=n_cams) < MIN_VIEW_CORNERS).any() or \
            (np.bincount(obs.board[m], minlength=n_boards) < MIN_VIEW_CORNERS).any():
        return None
    return m


def sampled_rigidity(obs: Observations, state: State, gauge_cam: int, gauge_board: int, fix: np.ndarray,
                     inits: list[MonoInit], cam_names: list[str]) -> tuple[SolveResult, State] | None:
    """The rigidity verdict of a rig the camera-IMU step solves again, intrinsics and all
    (imu_start), from the robust pass over a sample of RIGIDITY_SAMPLE_FRAMES frames evenly
    spread in time (frame_sample): (that pass read as a result, provisional_result; the start
    state over every frame with its intrinsics) when its rigidity factor exceeds the threshold
    by EARLY_RIGIDITY_MARGIN, else None (the joint solve over every frame follows, as
    without the sample). Where the rig is not rigid per frame choose_models replaces the
    joint solve by the own-views one, which needs only a start: the joint solve over every
    frame (1.8 s on the 30 s three-camera recording) is then not run; the sample's takes
    0.25 s and reads the same factor (17.5 against 17.0 converged over every frame)."""
    m = frame_sample(obs, RIGIDITY_SAMPLE_FRAMES, len(cam_names), len(state.T_world_board))
    if m is None:
        return None
    kept, frame = np.unique(obs.frame[m], return_inverse=True)
    sub = replace(obs.subset(m), frame=frame.reshape(-1))
    robust = robust_pass(sub, State(state.intrinsics, state.T_cam_body, state.T_body_world[kept], state.T_world_board),
                         gauge_cam, gauge_board, fix)
    res = provisional_result(sub, robust, gauge_cam, gauge_board, fix)
    if not rigidity_factor(res, inits, cam_names)[0] > EARLY_RIGIDITY_MARGIN * RIGIDITY_RATIO:
        return None
    start = state.copy()
    start.intrinsics[:] = [replace(i, values=i.values.copy()) for i in robust.state.intrinsics]
    return res, start


@dataclass(frozen=True)
class ModelChoice:
    """choose_models' answer: the joint solve with the models chosen, per camera its
    OwnViews (when the rig is not rigid per frame) or None, per camera index the
    intrinsic_sigmas with fx, fy, cx, cy free (where the structure was tested), per camera
    index the log lines, and notes."""

    solve: JointSolve
    own: list
    free_sigma: dict
    logs: dict[int, list[str]]
    notes: list[str]


def choose_models(solved: JointSolve, inits: list[MonoInit], by_cam: dict[str, list[BoardView]],
                  setup: Setup) -> ModelChoice:
    """The camera models the data support. When the joint solve fits each camera far worse
    than its own views did (rigidity_check), intrinsics come from each camera's own views
    and the rig is solved with them held; else, with auto distortion or intrinsics, the
    joint solve's models are reduced where its covariance says so (model_selection)."""
    C = len(setup.cam_names)
    unsynced = None if setup.fix_intrinsics else rigidity_check(solved.res, inits, setup.cam_names)
    if unsynced is not None:
        return _own_views_models(solved, inits, by_cam, setup, unsynced)
    if (setup.distortion == "auto" or setup.intrinsics == "auto") and not setup.fix_intrinsics:
        return _reduced_models(solved, setup)
    return ModelChoice(solve=solved, own=[None] * C, free_sigma={}, logs={}, notes=[])


def _own_views_models(solved: JointSolve, inits: list[MonoInit], by_cam: dict[str, list[BoardView]],
                      setup: Setup, note: str) -> ModelChoice:
    """Intrinsics from each camera's own views (initialise.own_views_intrinsics), then the
    rig solved with them held fixed. The cameras' fits are independent and each runs OpenCV
    on one thread (initialise.opencv_one_thread, for reproducible sums; with imu_start the
    start is initialise.own_views_start's, no OpenCV), so they run on a thread per core: the
    same numbers, in about half the time on 2 cores."""
    from concurrent.futures import ThreadPoolExecutor

    st = (solved.res.state if solved.start is None else solved.start).copy()
    own, free_sigma, logs = [], {}, {}

    def fit(c):
        got = None
        if setup.imu_start and st.intrinsics[c].model == "pinhole":
            got = own_views_start(by_cam[setup.cam_names[c]], setup.corners, st.intrinsics[c], setup.distortion,
                                  setup.faces)
        v, line = got if got is not None else inits[c].mono()
        return own_views_intrinsics(by_cam[setup.cam_names[c]], setup.corners,
                                    Intrinsics(st.intrinsics[c].model, np.array(v, float)), setup.centres[c],
                                    setup.intrinsics, setup.faces), line

    # one OpenCV thread set here for all of them: each fit's own setting and restoring of
    # the process-wide count would otherwise race with the other threads' fits
    with opencv_one_thread(), ThreadPoolExecutor(max_workers=max(1, min(len(inits), os.cpu_count() or 1))) as ex:
        fits = list(ex.map(fit, range(len(inits))))
    for c, (o, line) in enumerate(fits):
        own.append(o)
        st.intrinsics[c] = o.intrinsics
        if o.cov_free is not None:
            free_sigma[c] = intrinsic_sigmas(o.cov_free)
        logs[c] = [f"rig not rigid per frame: intrinsics {line}"] + list(o.log)
    fix = np.ones(len(setup.cam_names), bool)
    res = bundle_adjust(solved.obs, st, solved.gauge_cam, solved.gauge_board, fix)
    return ModelChoice(solve=replace(solved, res=res, fix=fix, covariance=None, seconds=solved.seconds + res.seconds),
                       own=own, free_sigma=free_sigma, logs=logs, notes=[note])


def _reduced_models(solved: JointSolve, setup: Setup) -> ModelChoice:
    """k3 dropped (auto distortion) and the intrinsics structure chosen (auto intrinsics)
    where the joint solve's covariance does not support them, and the rig re-solved."""
    res = solved.res
    t_m = time.perf_counter()  # model selection's covariance and refits are solver time too
    covariance = solve_covariance(res)
    reduced, logs = reduce_models(res, covariance, setup.centres, setup.distortion == "auto",
                                  setup.intrinsics == "auto")
    seconds = solved.seconds + time.perf_counter() - t_m
    free_sigma = {}
    if setup.intrinsics == "auto" and covariance is not None:
        free_sigma = {c: intrinsic_sigmas(C) for c, C in
                      enumerate(intrinsics_covariance(covariance[0], covariance[1], res.state.intrinsics))
                      if C is not None}
    if reduced is not None:
        res = bundle_adjust(solved.obs, reduced, solved.gauge_cam, solved.gauge_board, solved.fix,
                            inliers=res.inliers)
        seconds += res.seconds
        covariance = None
    return ModelChoice(solve=replace(solved, res=res, covariance=covariance, seconds=seconds),
                       own=[None] * len(setup.cam_names), free_sigma=free_sigma, logs=logs, notes=[])


class GuidedPass(NamedTuple):
    """guided_pass's answer: the joint solve on the re-measured corners (unchanged when no
    camera keeps them), the seconds the re-measuring took, and a note."""

    solve: JointSolve
    rerefine_s: float
    note: str


def guided_pass(solved: JointSolve, rerefine: Callable, setup: Setup) -> GuidedPass:
    """The corners re-measured with the solved rig (rerefine, guided.py) and the rig solved
    again on them (_guided_solve); the detector's sigma replaced where a corner was."""
    t_g = time.perf_counter()
    uv_g, refined, sigma_g = rerefine(solved.obs, solved.res.state, setup.cam_names, setup.frames,
                                      setup.board_names)
    rerefine_s = time.perf_counter() - t_g
    g = _guided_solve(solved.res, solved.obs, uv_g, refined, setup.cam_names, solved.gauge_cam,
                      solved.gauge_board, solved.fix)
    solved = replace(solved, seconds=solved.seconds + g.seconds)
    if g.res is not None:
        sigma_det = solved.sigma_det if solved.sigma_det is None else np.where(g.refined, sigma_g, solved.sigma_det)
        solved = replace(solved, res=g.res, obs=g.obs, covariance=None, sigma_det=sigma_det)
    return GuidedPass(solve=solved, rerefine_s=rerefine_s, note=g.note)


class WeightedPass(NamedTuple):
    """weighted_pass's answer: the joint solve (weighted, or as it was) and per camera the
    NoiseModel its corners were weighted by (None: not weighted)."""

    solve: JointSolve
    noise_models: list | None


def weighted_pass(solved: JointSolve, weight_corners: bool) -> WeightedPass:
    """With weight_corners and a detector sigma: the rig solved with each corner weighted
    by its calibrated noise (weighted_solve)."""
    if not (weight_corners and solved.sigma_det is not None):
        return WeightedPass(solved, None)
    w = weighted_solve(solved.res, solved.obs, solved.sigma_det, solved.gauge_cam, solved.gauge_board, solved.fix)
    covariance = None if w.obs.weight is not None else solved.covariance
    return WeightedPass(replace(solved, res=w.res, obs=w.obs, covariance=covariance,
                                seconds=solved.seconds + w.seconds), w.models)


@dataclass(frozen=True)
class Finished:
    """finish's answer: the calibrated rig (body frame per reference), per camera its
    CameraStats, the RMS over every inlier corner, T_body_solve (solver body -> output
    body) and the (6C, 6C) covariance of the cameras' output poses (None: singular)."""

    rig: Rig
    stats: dict[str, CameraStats]
    rms_px: float
    T_body_solve: np.ndarray
    cov_extrinsics: np.ndarray | None


def finish(solved: JointSolve, setup: Setup, reference: str, inits: list[MonoInit], refused: np.ndarray,
           chosen: ModelChoice, logs: dict[str, list[str]]) -> Finished:
    """The solved rig in the output body frame (reference_transform) with each camera's
    statistics and sigmas; CalibrationError when a camera failed grossly or lost every corner."""
    res, obs, rig, cam_names = solved.res, solved.obs, setup.rig, setup.cam_names
    T_body_cam_solve = np.array([geo.inv_T(T) for T in res.state.T_cam_body])
    T_out_solve = reference_transform(T_body_cam_solve, rig, reference)
    cov = extrinsic_covariance(res, rig, reference, T_body_cam_solve,
                                solved.covariance if solved.covariance is not None else solve_covariance(res))
    r_all = res.problem.residuals(res.problem.x0()).reshape(-1, 2)
    lost = [n for c, n in enumerate(cam_names) if not np.any(obs.cam[res.inliers] == c)]
    judged = _judged_rms(obs, res, solved.fix, len(cam_names))
    _refuse_gross_rms([_gross_rms(n, judged[c], inits[c].rms_px, rig.camera(n).intrinsics.width,
                                  rig.camera(n).intrinsics.height) for c, n in enumerate(cam_names)])
    if lost:
        raise CalibrationError(f"{', '.join(lost)}: every corner was rejected as an outlier; the views of "
                               f"this camera disagree with the rest of the rig (wrong target, or a moved camera?)")
    cams, stats = [], {}
    for c, n in enumerate(cam_names):
        model = rig.camera(n).intrinsics.with_values(res.state.intrinsics[c].values)
        stats[n] = _camera_stats(c, n, model, solved, r_all, int(refused[c]), cov, chosen, logs[n],
                                 setup.fix_intrinsics)
        cams.append(Camera(n, model, T_out_solve @ T_body_cam_solve[c], None))
    return Finished(rig=replace(rig, cameras=tuple(cams)), stats=stats,
                    rms_px=float(np.sqrt(np.mean(np.sum(r_all**2, axis=1)))), T_body_solve=T_out_solve,
                    cov_extrinsics=cov["extrinsics"] if cov is not None else None)


def _camera_stats(c: int, name: str, model: CameraModel, solved: JointSolve, r_all: np.ndarray, refused: int,
                  cov: dict | None, chosen: ModelChoice, log: list[str], fixed: bool) -> CameraStats:
    """Camera c's CameraStats: RMS and counts over its inlier corners (r_all: the solve's
    residuals, inliers only), outliers including the corners PnP refused, sigmas."""
    res, obs = solved.res, solved.obs
    inl_obs = obs.subset(res.inliers)
    m = inl_obs.cam == c
    rms = float(np.sqrt(np.mean(np.sum(r_all[m] ** 2, axis=1)))) if m.any() else float("nan")
    st = CameraStats(
        name=name, rms_px=rms, observations=int(m.sum()), frames=int(len(np.unique(inl_obs.frame[m]))),
        outliers=int((~res.inliers & (obs.cam == c)).sum()) + refused,
        distortion_model=("fisheye" if model.model == "fisheye" else PINHOLE_MODEL_NAMES[len(model.dist)]),
        model_selection=log)
    st.intrinsics_model = intrinsics_model(res.state.intrinsics[c], st.distortion_model, fixed)
    if cov is not None:
        blk = cov["extrinsics"][6 * c:6 * c + 6, 6 * c:6 * c + 6]
        sd = np.sqrt(np.clip(np.diag(blk), 0, None))
        st.sigma_rotation_deg = np.degrees(sd[:3])
        st.sigma_position_mm = sd[3:] * 1000.0
        st.sigma_intrinsics = cov["intrinsics"][c]
    own = chosen.own[c]
    if st.sigma_intrinsics is None and own is not None and own.cov is not None:
        st.sigma_intrinsics = intrinsic_sigmas(own.cov)
    st.sigma_intrinsics_free = chosen.free_sigma.get(c)
    return st


# ----------------------------------------------------------------------------- views


def drop_repeated_views(views: list[BoardView]) -> tuple[list[BoardView], list[tuple[str, str]]]:
    """One camera's views without those whose board, corner ids and pixels repeat an
    earlier view's exactly, and the (repeat, original) frame pairs. Two photographs never
    give bit-identical corners (noise); one image copied under several names, or a camera
    whose stream froze, does. Counted as independent views, such copies shrink every sigma
    and can carry the intrinsics: one pose copied 11 times calibrated to a focal length 28 %
    off and a 174 mm baseline for 120 mm, with exit 0."""
    seen: dict[tuple, str] = {}
    kept, repeats = [], []
    for v in views:
        key = (v.board, np.asarray(v.ids).tobytes(), np.asarray(v.uv, float).tobytes())
        if key in seen:
            repeats.append((v.frame, seen[key]))
            continue
        seen[key] = v.frame
        kept.append(v)
    return kept, repeats


# A camera's guided corners are kept unless the solved rig fits them this much worse than
# the detector's (reprojection RMS over the corners both solves kept). On renders the guided
# corners fit 10-40 % better; a rise means the pass measured worse than the detector on
# these images, e.g. a lens the calibrated model does not follow locally.
GUIDED_KEEP_RATIO = 1.1


def _camera_rms(res: SolveResult, cam: np.ndarray, keep: np.ndarray, C: int) -> np.ndarray:
    """(C,) reprojection RMS px per camera at res's solution over the corners `keep` (a
    subset of res.inliers; cam: every observation's camera), nan where none: from the
    residuals the solve already holds."""
    sel = keep[res.inliers]
    c = cam[res.inliers][sel]
    e2 = np.sum(res.residuals[sel] ** 2, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.bincount(c, e2, minlength=C) / np.bincount(c, minlength=C))


class GuidedSolve(NamedTuple):
    """_guided_solve's answer: the solve on the guided corners (None when no camera keeps
    them), its observations, which corners were re-measured and kept (M,) bool, the solver
    seconds, and a note."""

    res: SolveResult | None
    obs: Observations
    refined: np.ndarray
    seconds: float
    note: str


def _guided_solve(res: SolveResult, obs: Observations, uv_g: np.ndarray, refined: np.ndarray, cam_names: list[str],
                  gauge_cam: int, gauge_board: int, fix) -> GuidedSolve:
    """The rig solved again on the guided corners, cameras whose guided corners fit worse
    (GUIDED_KEEP_RATIO) put back to the detector's corners. -> (result or None when no
    camera keeps its guided corners, observations, refined mask kept, solve seconds, note)
    as a GuidedSolve."""
    C = len(cam_names)
    seconds = 0.0
    guided = [c for c in range(C) if np.any(refined & (obs.cam == c))]
    if not guided:
        return GuidedSolve(None, obs, refined, seconds, "guided refinement not used: no corner could be re-measured")
    res_g = bundle_adjust(replace(obs, uv=uv_g), res.state, gauge_cam, gauge_board, fix, inliers=res.inliers)
    seconds += res_g.seconds
    both = res.inliers & res_g.inliers
    before, after = _camera_rms(res, obs.cam, both, C), _camera_rms(res_g, obs.cam, both, C)
    worse = [c for c in guided if after[c] > GUIDED_KEEP_RATIO * before[c]]
    kept = [c for c in guided if c not in worse]
    why = "; ".join(f"{cam_names[c]}: reprojection RMS {before[c]:.3f} -> {after[c]:.3f} px, so its detector "
                    f"corners were kept" for c in worse)
    if not kept:
        return GuidedSolve(None, obs, refined, seconds, f"guided refinement not used ({why})")
    if worse:
        refined = refined & ~np.isin(obs.cam, worse)
        uv_g = np.where(refined[:, None], uv_g, obs.uv)
        res_g = bundle_adjust(replace(obs, uv=uv_g), res.state, gauge_cam, gauge_board, fix, inliers=res.inliers)
        seconds += res_g.seconds
    line = (f"guided refinement: {int(refined.sum())} of {len(refined)} corners re-measured with the calibrated "
            f"model ({', '.join(cam_names[c] for c in kept)}); the rest keep the detector's position"
            + (f" ({why})" if why else ""))
    return GuidedSolve(res=res_g, obs=replace(obs, uv=uv_g), refined=refined, seconds=seconds, note=line)


def noise_models(res, obs: Observations, sigma_det: np.ndarray) -> list[NoiseModel | None]:
    """Each camera's NoiseModel from a solve's inlier residuals (plain px; divided by
    the solve's redundancy, its share of residual degrees of freedom)."""
    r = res.residuals
    redundancy = max(r.size - res.problem.layout.size, 1) / max(r.size, 1)
    r2 = np.sum(r**2, axis=1) / 2.0 / redundancy
    s_in, cam_in = sigma_det[res.inliers], obs.cam[res.inliers]
    return [fit_noise_model(s_in[cam_in == c], r2[cam_in == c]) for c in range(len(res.state.intrinsics))]


class WeightedSolve(NamedTuple):
    """weighted_solve's answer: the solve, its observations with weights, per camera the
    NoiseModel (or None), and the solver seconds."""

    res: SolveResult
    obs: Observations
    models: list
    seconds: float


def weighted_solve(res, obs: Observations, sigma_det: np.ndarray, gauge_cam: int, gauge_board: int,
                   fix: np.ndarray) -> WeightedSolve:
    """The solve re-done with each corner weighted by its calibrated noise (NoiseModel).

    res: the unweighted solve, whose outlier rejection does not depend on where it started.
    Fit the models on its residuals, re-weight, solve on its inliers; judge the inliers
    once on the weighted residuals (bundle_adjust's rule); fit the models again on that
    solve's residuals, re-weight, solve on that set, frozen. Each step is a function of
    the one before, so the result is too, wherever the first solve started (an iterated
    rejection with weights could settle on either side of a corner near its threshold).
    Returns (result, observations with weights, models, seconds); unchanged and
    unweighted when no camera has enough corners with a sigma."""
    models = noise_models(res, obs, sigma_det)
    if all(m is None for m in models):
        return WeightedSolve(res, obs, models, 0.0)
    seconds = 0.0
    inliers = res.inliers
    for k in range(NOISE_ROUNDS):
        if k:
            models = noise_models(res, obs, sigma_det)
            inliers = judge_inliers(obs, res.state, res.inliers, gauge_cam, gauge_board, fix)
        obs = replace(obs, weight=noise_weights(sigma_det, obs.cam, models))
        res = bundle_adjust(obs, res.state, gauge_cam, gauge_board, fix, inliers=inliers, max_rounds=0)
        seconds += res.seconds
    return WeightedSolve(res=res, obs=obs, models=models, seconds=seconds)


def rigidity_factor(res, inits: list[MonoInit], cam_names: list[str]) -> tuple[float, list]:
    """rigidity_check's measure: the median over cameras of (the camera's reprojection RMS
    in the joint solve res) / (its own-views fit's RMS), and per camera (joint px, own px,
    name); nan when fewer than two cameras have both."""
    r = res.residuals
    cam = res.problem.obs.cam
    ratios = []
    for c, mi in enumerate(inits):
        m = cam == c
        if mi.rms_px is None or mi.mono is None or not m.any() or mi.rms_px <= 0:
            continue
        ratios.append((float(np.sqrt(np.mean(np.sum(r[m] ** 2, axis=1)))), mi.rms_px, cam_names[c]))
    if len(ratios) < 2:
        return float("nan"), ratios
    return float(np.median([j / o for j, o, _ in ratios])), ratios


def rigidity_check(res, inits: list[MonoInit], cam_names: list[str]) -> str | None:
    """A note when the joint solve fits each camera's corners far worse than that camera's
    own-views fit, else None.

    One rigid rig per frame is the joint model's one extra assumption. When it holds, a
    camera's RMS in the joint solve is within some 10-20 % of its own fit (1.0-1.1x on
    the Bumblebee2, OpenCV-sample, wide-angle and trinocular real sets). Cameras triggered in software see a moving
    board at different instants (caliscope's webcams: up to 43 ms; joint 0.88 px against
    0.04-0.08 px alone); the joint solve then bends every camera's intrinsics to absorb
    the motion (focal lengths 10-16 % off). The intrinsics must then come from each
    camera's own views, as tools for such rigs do."""
    factor, ratios = rigidity_factor(res, inits, cam_names)
    if not factor > RIGIDITY_RATIO:
        return None
    detail = ", ".join(f"{n} {j:.2f} vs {o:.2f}" for j, o, n in ratios)
    return (f"the cameras' views disagree with one rigid rig per frame: reprojection RMS in the joint solve is "
            f"{factor:.1f}x each camera's own fit (px: {detail}); are the frames synchronised, and did the rig "
            f"stay rigid? Intrinsics were taken from each camera's own views and held fixed for the extrinsics")


def _judged_rms(obs: Observations, res: SolveResult, fix: np.ndarray, C: int) -> np.ndarray:
    """(C,) each camera's reprojection RMS px for the gross-failure test: over its inlier
    corners, or over all its corners when more than half were rejected. A camera whose
    images are mirrored can otherwise lose nearly every corner as an outlier and pass on
    the few that happen to fit."""
    pb = Problem(obs, res.state, res.problem.gauge_cam, res.problem.gauge_board, fix)
    e2 = np.sum(pb.residuals(pb.x0()).reshape(-1, 2) ** 2, axis=1)
    n_all = np.bincount(obs.cam, minlength=C)
    n_in = np.bincount(obs.cam[res.inliers], minlength=C)
    use = res.inliers | (n_in < 0.5 * n_all)[obs.cam]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.bincount(obs.cam[use], e2[use], minlength=C) / np.bincount(obs.cam[use], minlength=C))


def _gross_rms(name: str, rms: float, own_rms: float | None, width: int, height: int) -> str | None:
    """'name: RMS x px (own views y px)' when a camera's final RMS says its calibration
    failed (GROSS_RMS_*), else None. Its own views' fit tells where to look: small there,
    the rig is at fault (mirrored or unsynchronised images); large, the board or model."""
    limit = max(GROSS_RMS_MIN_PX, GROSS_RMS_FRACTION * float(np.hypot(width, height)))
    if not rms > limit:
        return None
    own = f", its own views alone {own_rms:.2f} px" if own_rms is not None else ""
    return f"{name} {rms:.1f} px (limit {limit:.1f}{own})"


def _refuse_gross_rms(gross: list[str | None]) -> None:
    gross = [g for g in gross if g is not None]
    if gross:
        raise CalibrationError(
            f"the calibration failed: reprojection RMS after the joint solve: {'; '.join(gross)}. The corners do "
            f"not fit one camera model and one rigid rig: check target.yaml (board type, squares, first_marker_id, "
            f"legacy_pattern), the camera models, mirrored or rotated images, and that the frames are "
            f"synchronised; nothing was written")


def _detected_sigma(posed: PosedViews, use: list[int]) -> np.ndarray | None:
    """(M,) the detector's own 1-sigma of every corner of the views `use` in _observations'
    order (NaN where unknown), or None when none of them has one."""
    views = [posed.views[k] for k in use]
    if all(v.sigma is None for v in views):
        return None
    return np.concatenate([np.full(len(v.ids), np.nan) if v.sigma is None else np.asarray(v.sigma, float).ravel()
                           for v in views])


def _used_views(posed: PosedViews, graph: PoseGraph) -> list[int]:
    """The posed views (indices) the joint solve uses: those of frames and boards the pose
    graph placed."""
    return [k for k in range(len(posed.views)) if graph.frame_posed[posed.frame[k]]
            and posed.board[k] not in graph.missing_boards]


def own_view_poses(flipped, rig_start: RigStart, own: list) -> np.ndarray | None:
    """(V, 4, 4) as start_poses, each view's pose from its camera's own-views solve (with the
    intrinsics the camera-IMU step starts from: OwnViews.T_cam_board), the start pose where
    that solve did not pose it; None when the intrinsics did not come from the cameras' own
    views, or when a chessboard's corner order was flipped after them (resolve_flips). The
    camera-IMU step's start then needs no PnP of its own (0.4 s on the 30 s three-camera
    recording)."""
    if flipped.flips or any(o is None for o in own):
        return None
    posed = flipped.posed
    use = _used_views(posed, rig_start.graph)
    return np.array([own[posed.cam[k]].T_cam_board.get((posed.views[k].frame, posed.views[k].board),
                                                       posed.T_cam_board[k]) for k in use], float).reshape(-1, 4, 4)


def start_poses(posed: PosedViews, rig_start: RigStart) -> np.ndarray:
    """(V, 4, 4): the start pose T_cam_board of each view first_solve's observations hold,
    in their order (obs.view)."""
    use = _used_views(posed, rig_start.graph)
    return np.array([posed.T_cam_board[k] for k in use], float).reshape(-1, 4, 4)


def _observations(posed: PosedViews, use: list[int], corners: dict, board_names: list[str]) -> Observations:
    """The solver's observations: every corner of the posed views `use` (indices), in order."""
    n = [len(posed.views[k].ids) for k in use]
    cam = np.concatenate([np.full(m, posed.cam[k]) for k, m in zip(use, n)])
    frame = np.concatenate([np.full(m, posed.frame[k]) for k, m in zip(use, n)])
    board = np.concatenate([np.full(m, posed.board[k]) for k, m in zip(use, n)])
    P = np.concatenate([corners[board_names[posed.board[k]]][posed.views[k].ids] for k in use])
    uv = np.concatenate([np.asarray(posed.views[k].uv, float).reshape(-1, 2) for k in use])
    view = np.concatenate([np.full(m, j) for j, m in enumerate(n)])
    return Observations(cam, frame, board, P, uv, view)
