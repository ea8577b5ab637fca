"""`rigcal calibrate` on a motion dataset with an IMU (docs/formats.md#motion-datasets):
the camera-only calibration's corners, intrinsics and board poses in, every camera's
T_imu_cam, clock offset (and line delay), the IMU's biases and gravity out, through the
public API of rigcal.imucal.estimator.

Defaults from the data: the spline's knot spacing from how well a spline follows the IMU's
own signal (imu_start.choose_knot_spacing); the intrinsics (`--imu-intrinsics auto`) held at
the declared rig's when it is itself a camera calibration (resolve_intrinsics: the
two-recording workflow of Kalibr and basalt), else estimated with the rest (`joint`;
`held` keeps the camera-only step's, `prior` weighs them by the declared calibration's
sigmas). The sigmas are checked on the recording's halves (subset_check) and raised where
the formal ones are smaller than the halves show.

The intrinsics (when estimated) and every board's pose but the gauge board's (most corners:
the world frame whose gravity direction the estimator finds) are estimated with the
trajectory. The camera-only calibration's board poses are not a safe start for the
trajectory: it treats images of different cameras with equal stems as the same instant, so
with clock offsets of milliseconds a board seen by only some cameras is placed off by the
motion in between. So the start is the trajectory from the gauge board and the IMU alone
(`estimate`).

The IMU model (`--imu-model`, rigcal.imucal.residuals): `calibrated` (M = I) unless the data
show scale and misalignment: `auto` fits `calibrated`, then `scale-misalignment` from that
solution (imu_calib.refine), and keeps it only when the likelihood ratio of the 12 added
parameters passes model_selection's test (select_imu_model).

Times are seconds since the IMU's first sample, on each sensor's own clock, so the
estimator's offsets are the motion-dataset format's `time_offset_s` (t_imu = t_cam + time_offset_s).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
# chdtri(k, q): the chi-square quantile with upper tail q; scipy.stats costs 1 s to import
from scipy.special import chdtri

from rigcal.core import geometry as geo
from rigcal.core import spline as spl
from rigcal.imucal import estimator as ic
from rigcal.imucal import residuals as ir
from rigcal.imucal import start as imu_start
from rigcal.errors import CalibrationError, DatasetError, InputError
from rigcal.camcal.initialise import pnp_views
from rigcal.camcal.model_selection import IMU_MODEL_LEVEL, intrinsic_sigmas, likelihood_ratio_test
from rigcal.camcal.solve import within_robust_sigmas
from rigcal.data.imu_csv import ImuSamples
from rigcal.core.rig import Imu

# the estimate is refined with the corners re-weighted by the noise it measured when that
# differs from the assumed by more than this fraction
REWEIGHT_ABOVE = 0.2
# corners further than this many robust sigmas from the estimate's projection are left out
# (the camera-only step's level, camcal.solve.bundle_adjust), and the estimate refined
# without them when they are more than a handful: under Gaussian noise one corner in
# 270,000 lies beyond, and a few corners do not move the answer
REJECT_SIGMA = 5.0
REJECT_REFIT = 1e-3  # ... more than this share of the corners, and at least REJECT_MIN
REJECT_MIN = 5
MIN_KNOTS = 20  # the images and IMU must share at least this many knot spacings
MIN_FRAMES = 10  # per camera: the clock-offset search needs rates over ~10 frame intervals
MIN_PNP_CORNERS = 8
NOISE_WARN_RATIO = 3.0  # residual RMS vs what the declared density predicts, either way
IMU_MODELS = ("auto", "calibrated", "scale-misalignment")
# auto: held when the declared rig is itself a camera calibration (every camera carries
# calibration.sigma.intrinsics: the two-recording workflow), else joint (resolve_intrinsics);
# prior: estimated with the rest, weighted by that calibration's values and sigmas
INTRINSICS = ("auto", "joint", "held", "prior")
SCALE_PARAMETERS = 12  # L of M_gyro and of M_accel, 6 each


@dataclass(frozen=True)
class Options:
    """The camera-IMU step's options, named as `rigcal calibrate`'s (--offset-window ->
    offset_window): the IMU (name), gravity's magnitude, the clock-offset search half-width,
    whether every camera's line delay is estimated (None: where declared non-zero), the
    spline's knot spacing (None: chosen from the IMU's readings, start.choose_knot_spacing),
    the IMU model (IMU_MODELS; auto: chosen by imu_model_test), the intrinsics (INTRINSICS:
    estimated with the rest, held at the camera-only step's, or a prior; auto:
    resolve_intrinsics), whether the sigmas are checked on the recording's halves
    (subset_sigmas). None for gravity and offset_window means the default."""

    imu: str
    gravity: float | None = None
    offset_window: float | None = None
    rolling_shutter: bool | None = None
    knot_spacing: float | None = None
    imu_model: str = "auto"
    imu_intrinsics: str = "auto"
    subsets: bool = True
    intrinsics_from_rig: bool = False  # held intrinsics are the declared rig's own calibration

    def __post_init__(self):
        if self.gravity is None:
            object.__setattr__(self, "gravity", ir.GRAVITY)
        if self.offset_window is None:
            object.__setattr__(self, "offset_window", 0.2)
        # calibrate.run builds these before detection: a typo (--gravity 981) is then one
        # line at once, not an error after the camera-only calibration
        for option, value, lo, hi, what in (
                ("--gravity", self.gravity, 9.7, 9.9, "m/s^2 (on Earth 9.76-9.84)"),
                ("--offset-window", self.offset_window, 0.0, 10.0, "seconds"),
                ("--knot-spacing", self.knot_spacing, 0.0, 1.0, "seconds")):
            if value is not None and not lo < value <= hi:
                raise InputError(f"{option}: expected {what} in ({lo:g}, {hi:g}], got {value:g}")
        if self.imu_model not in IMU_MODELS:
            raise InputError(f"--imu-model: expected one of {', '.join(IMU_MODELS)}, got {self.imu_model!r}")
        if self.imu_intrinsics not in INTRINSICS:
            raise InputError(f"--imu-intrinsics: expected one of {', '.join(INTRINSICS)}, "
                             f"got {self.imu_intrinsics!r}")


@dataclass(frozen=True, eq=False)
class Inputs:
    """The estimator's inputs built from a camera-only calibration: per camera the PnP
    poses as T_board_cam with their board, the corners in board coordinates, the IMU."""

    cams: tuple  # imu_calib.CameraInput (T_world_cam from the current boards)
    board_of_pose: tuple  # per camera (F,) board index of each PnP pose
    T_board_cam: tuple  # per camera (F, 4, 4)
    cam: np.ndarray  # (M,) per corner
    board: np.ndarray
    t_cam: np.ndarray
    uv: np.ndarray
    p_board: np.ndarray
    imu: ic.ImuInput
    t_base_ns: int  # the IMU's first sample: time 0
    intrinsics: tuple = ()  # per camera rigcal.camcal.solve.Intrinsics of the camera-only step
    gauge: int | None = None  # the gauge board when fixed (corners_subset), else the one with most corners

    def corners_subset(self, keep: np.ndarray) -> "Inputs":
        """These inputs with only the corners `keep` (M,) bool, the gauge board kept: the
        estimate's boards stay in the same order whatever the corners left out."""
        gauge = self.gauge if self.gauge is not None else _most_corners(self.board, None)
        return replace(self, cam=self.cam[keep], board=self.board[keep], t_cam=self.t_cam[keep],
                       uv=self.uv[keep], p_board=self.p_board[keep], gauge=gauge)


@dataclass(frozen=True, eq=False)
class ImuCalibration:
    """The outcome: the estimator's result, the boards it ended with (T_world_board (B, 4, 4),
    world = the gauge board's frame), the 1-sigma of every reported parameter
    (parameter_sigmas, corners weighted by their measured noise), the mean biases over the
    recording, the residual RMS of the IMU in units
    (rad/s, m/s^2) and what the declared densities predict, the IMU model kept (`imu_model`)
    with the test behind it (`model_test`: ImuModelTest or None when forced), the intrinsics
    when estimated with the rest (their sigma under sigma['intrinsics']), warnings and notes."""

    result: ic.CameraImuResult
    imu: Imu
    T_world_board: np.ndarray
    sigma: dict  # parameter_sigmas
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_rms: float
    accel_rms: float
    gyro_predicted: float
    accel_predicted: float
    corner_rms_px: float
    passes: int
    seconds: float
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    imu_model: str = "calibrated"
    model_test: "ImuModelTest | None" = None
    intrinsics: tuple = ()  # per camera rigcal.camcal.solve.Intrinsics when estimated with the rest
    knot: imu_start.KnotChoice | None = None  # None: --knot-spacing given
    knot_dt: float = 0.05
    subsets: "SubsetCheck | None" = None  # the halves' re-estimate behind the sigmas (None: not run)
    intrinsics_source: str = "joint"  # joint | camera-only (held) | declared (held: the rig's own calibration)


@dataclass(frozen=True)
class ImuModelTest:
    """`--imu-model auto`'s test of scale-misalignment against calibrated: the likelihood
    ratio of the two fits (statistic), the share of it in the IMU's own residuals (gyroscope,
    accelerometer, bias walk: imu_statistic), the chi-square threshold of SCALE_PARAMETERS
    degrees of freedom at model_selection.IMU_MODEL_LEVEL, and the seconds the larger fit took."""

    statistic: float
    imu_statistic: float
    threshold: float
    level: float
    seconds: float

    @property
    def significant(self) -> bool:
        # M describes the IMU: a gain that the IMU's own residuals do not show at the larger
        # model's optimum is M absorbing a misfit elsewhere. On EuRoC the whole ratio was
        # 3,358 from the corners (RMS 0.2999 -> 0.2992 px: the held intrinsics' error) while
        # the IMU's residuals grew (-35), and keeping M moved the cameras 12.6 -> 14.5 mm
        # from EuRoC's T_BS
        return self.statistic > self.threshold and self.imu_statistic > self.threshold

    def line(self) -> str:
        return (f"likelihood ratio {self.statistic:.1f}, {self.imu_statistic:.1f} of it in the IMU's residuals, "
                f"on {SCALE_PARAMETERS} parameters (both need {self.threshold:.1f}, p = {self.level:g}) -> "
                f"{'scale-misalignment' if self.significant else 'calibrated'}")


IMU_BLOCKS = ("gyro", "accel", "bias_walk")


def imu_model_test(small: ic.CameraImuResult, large: ic.CameraImuResult) -> ImuModelTest:
    """The likelihood ratio of `large` (scale-misalignment, fitted from `small`'s solution
    on the same corners and weights) against `small` (calibrated): each block's drop in cost
    in units of its measured noise, i.e. divided by the larger fit's mean squared normalised
    residual (as select_structure divides by the measured corner noise sigma_px^2); the
    bias random-walk prior's is taken as declared. Also the drops of the IMU's blocks alone,
    at `large`'s optimum (a fit stopped early gives another split: on EuRoC after 1-2
    iterations the IMU's share was +790-840, converged -35)."""
    drop = {k: (c - large.costs[k]) / (1.0 if k == "bias_walk" else max(large.normalised_rms[k] ** 2, 1e-12))
            for k, c in small.costs.items()}
    stat = sum(drop.values())
    _, need = likelihood_ratio_test(stat, SCALE_PARAMETERS, IMU_MODEL_LEVEL)
    return ImuModelTest(float(stat), float(sum(drop[k] for k in IMU_BLOCKS)), need, IMU_MODEL_LEVEL, large.seconds)


def imu_input(samples: ImuSamples, imu: Imu, t_base_ns: int) -> ic.ImuInput:
    return ic.ImuInput((samples.t_ns - t_base_ns) * 1e-9, samples.gyro, samples.accel, imu.update_rate,
                       imu.gyroscope_noise_density, imu.gyroscope_random_walk, imu.accelerometer_noise_density,
                       imu.accelerometer_random_walk, imu.T_body_imu.copy())


def _frame_poses(model, uv, p_board, view, frame, board, faces, view_T_cam_board=None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One pose per frame, of its view with most corners (>= MIN_PNP_CORNERS): (frames (F,),
    boards (F,), T_board_cam (F, 4, 4)). Views are grouped by one sort. view_T_cam_board
    (V, 4, 4): the camera-only step's start pose of every view (indexed by `view`), taken as
    they are; else a PnP on the view's corners (on EuRoC 1 s to redo what that start did)."""
    order = np.argsort(view, kind="stable")
    _, first, count = np.unique(view[order], return_index=True, return_counts=True)
    f, b = frame[order][first], board[order][first]
    # per frame the largest view: sort by (frame, -count) and keep each frame's first
    best = np.lexsort((-count, f))
    best = best[np.concatenate([[True], np.diff(f[best]) != 0])] if len(best) else best
    best = best[count[best] >= MIN_PNP_CORNERS]
    if view_T_cam_board is not None:
        ids = view[order][first][best]
        return f[best], b[best], geo.inv_T(np.asarray(view_T_cam_board)[ids]).reshape(-1, 4, 4)
    groups = np.split(order, np.cumsum(count)[:-1])
    m = model
    fits = pnp_views([p_board[groups[k]] for k in best], [uv[groups[k]] for k in best],
                     np.array([m.fx, m.fy, m.cx, m.cy, *m.dist]), m.model, [faces[int(b[k])] for k in best])
    ok = [j for j, fit in enumerate(fits) if fit is not None]
    T = np.stack([geo.inv_T(fits[j][0]) for j in ok]) if ok else np.zeros((0, 4, 4))
    return f[best[ok]], b[best[ok]], T


def build_inputs(cal, samples: ImuSamples, imu: Imu, faces: list[float], t_declared: dict[str, float],
                 line_delays: dict[str, float], image_t_ns=None) -> Inputs:
    """The inlier corners of the camera-only calibration `cal` (rigcal.camcal.pipeline.Calibration) on
    each camera's clock (frames are integer-ns stems), one pose per image (its largest board
    view: the camera-only step's start pose, cal.view_T_cam_board, where it kept them, else
    a PnP with its intrinsics) for the start, and the IMU. image_t_ns: camera -> frame -> the image's own
    stem (ns) where it differs from the frame's name (free-running cameras grouped into
    shared frames for the camera-only start, rigcal.data.dataset.associate_by_time)."""
    t_base = int(samples.t_ns[0])
    # grouped free-running images are not one instant: the camera-only step's outlier test
    # rejected corners for the motion between them, which this step models; all are used
    ok = cal.inliers if not image_t_ns else np.ones_like(cal.inliers)
    o = cal.obs
    t_frame = np.array([(int(f) - t_base) * 1e-9 for f in cal.frames])
    t_frame = np.tile(t_frame, (len(cal.cam_names), 1))  # (C, F): each image at its own time
    for c, name in enumerate(cal.cam_names):
        own = (image_t_ns or {}).get(name, {})
        for fi, f in enumerate(cal.frames):
            if f in own:
                t_frame[c, fi] = (int(own[f]) - t_base) * 1e-9
    cams, boards_of, T_board_cam = [], [], []
    for c, name in enumerate(cal.cam_names):
        m = cal.rig.camera(name).intrinsics
        s = ok & (o.cam == c)
        frames, b, T = _frame_poses(m, o.uv[s], o.p_board[s], o.view[s], o.frame[s], o.board[s], faces,
                                    getattr(cal, "view_T_cam_board", None))
        if len(frames) < MIN_FRAMES:
            raise CalibrationError(f"camera {name}: a board pose in only {len(frames)} images; the clock offset "
                                   f"needs at least {MIN_FRAMES}")
        by_time = np.argsort(t_frame[c, frames], kind="stable")  # frame order is the camera-only step's
        frames, b, T = frames[by_time], b[by_time], T[by_time]
        T_world_cam = cal.state.T_world_board[b] @ T
        cams.append(ic.CameraInput(m, cal.rig.camera(name).T_body_cam.copy(), t_frame[c, frames], T_world_cam,
                                   line_delays.get(name, 0.0), t_declared.get(name, 0.0)))
        boards_of.append(b)
        T_board_cam.append(T)
    return Inputs(tuple(cams), tuple(boards_of), tuple(T_board_cam), o.cam[ok], o.board[ok],
                  t_frame[o.cam[ok], o.frame[ok]],
                  o.uv[ok], o.p_board[ok], imu_input(samples, imu, t_base), t_base, tuple(cal.state.intrinsics))


def check_span(inp: Inputs, names: list[str], knot_dt: float) -> None:
    """Refuse (DatasetError, exit 2) a recording whose images and IMU samples share fewer
    than MIN_KNOTS knot spacings."""
    t_imu = inp.imu.t
    for c, name in zip(inp.cams, names):
        lo = max(c.t_cam.min() + c.time_offset_guess_s, t_imu[0])
        hi = min(c.t_cam.max() + c.time_offset_guess_s, t_imu[-1])
        if hi - lo < MIN_KNOTS * knot_dt:
            raise DatasetError(f"camera {name}: its images and the IMU samples share {max(hi - lo, 0.0):.2f} s; the "
                               f"camera-IMU calibration needs at least {MIN_KNOTS * knot_dt:g} s ({MIN_KNOTS} knots "
                               f"every {knot_dt:g} s): record longer")


def _with_boards(inp: Inputs, T_world_board: np.ndarray) -> list:
    """The cameras' start poses T_world_cam through the boards' poses."""
    return [replace(c, T_world_cam=T_world_board[b] @ T) for c, b, T in zip(inp.cams, inp.board_of_pose,
                                                                          inp.T_board_cam)]


def _most_corners(board: np.ndarray, n_boards: int | None) -> int:
    return int(np.argmax(np.bincount(board, minlength=n_boards or 0)))


def judge_corners(res: ic.CameraImuResult, obs: ir.Corners, models: list) -> tuple[np.ndarray, float]:
    """((M,) bool over obs: the corners the estimate `res` (its state; the corners it used)
    projects more than REJECT_SIGMA robust sigmas away from where they were measured, the
    sigma per camera from its median error (camcal.solve.within_robust_sigmas, the
    camera-only step's rule); the other corners' RMS error per coordinate, px). The
    camera-only step's test cannot judge free-running images (grouped, their residuals
    carry the motion between them) and misses what only the continuous-time model shows;
    a corner whose refinement window took in another object's edge (a board or a hand in
    front) is off by a pixel or more, a hundred of them move a principal point."""
    used = np.flatnonzero(res.corners_used)
    sub = obs.subset(used)
    e = np.linalg.norm(ir.corner_errors(res.state, sub, models), axis=1)
    out = np.zeros(len(obs.cam), bool)
    for c in np.unique(sub.cam):
        k = sub.cam == c
        out[used[k]] = ~within_robust_sigmas(e[k], REJECT_SIGMA)
    e_in = e[~out[used]]
    return out, float(np.sqrt(np.mean(e_in ** 2) / 2.0)) if len(e_in) else 0.0


def estimator_corners(inp: Inputs, n_boards: int) -> tuple[int, np.ndarray, ir.Corners]:
    """(gauge, order, corners): the gauge board (most corners: it fixes the world frame and is
    held), the boards in the estimator's order (B,) (the gauge first, then the others as
    they come) and the corners with their boards numbered in that order."""
    gauge = inp.gauge if inp.gauge is not None else _most_corners(inp.board, n_boards)
    order = np.r_[gauge, [b for b in range(n_boards) if b != gauge]].astype(int)
    rank = np.empty(n_boards, int)
    rank[order] = np.arange(n_boards)
    return gauge, order, ir.Corners(inp.cam, inp.t_cam, inp.uv, inp.p_board, rank[inp.board])


def _settings_with(settings: ic.Settings, res: ic.CameraImuResult) -> ic.Settings:
    """The corner noise the last estimate found: the next pass weighs the corners by it, so
    the reported sigmas rest on the measured noise, not on a guess."""
    return replace(settings, sigma_px=settings.sigma_px * max(res.normalised_rms["corners"], 1e-3))


def _gauge_pass(inp: Inputs, T_world_board: np.ndarray, gauge: int, settings: ic.Settings
                ) -> tuple[ir.State, ic.Settings]:
    """The trajectory from the IMU and the gauge board's corners alone (cameras that see it),
    then every camera's T_body_cam and offset in it: those that see the gauge board from
    this estimate, the others from their rate start (imu_start) and declared position. The
    boards the camera-only step placed through unsynchronised frames do not enter. Also the
    settings with the corner noise this pass measured."""
    sees = np.zeros(len(inp.cams), bool)
    sees[np.unique(inp.cam[inp.board == gauge])] = True
    idx = np.flatnonzero(sees)
    remap = np.full(len(inp.cams), -1)
    remap[idx] = np.arange(len(idx))
    cams = _with_boards(inp, T_world_board)
    k = (inp.board == gauge) & sees[inp.cam]
    T = T_world_board[gauge]  # its corners in the world frame: this pass's only board
    sub = ir.Corners(remap[inp.cam[k]], inp.t_cam[k], inp.uv[k], geo.transform(T, inp.p_board[k]))
    res = ic.calibrate_camera_imu([cams[i] for i in idx], sub, inp.imu, settings, sigmas=False)
    st = res.state
    T_body_cam = np.stack([c.T_body_cam for c in cams])
    off = np.array([c.time_offset_guess_s for c in cams])
    T_body_imu = inp.imu.T_body_imu
    for c in np.flatnonzero(~sees):
        s = imu_start.rate_start(cams[c].t_cam, cams[c].T_world_cam[:, :3, :3], inp.imu.t, inp.imu.gyro,
                                 cams[c].time_offset_guess_s, settings.window_s, what=f"camera {c}")
        T_body_cam[c, :3, :3] = T_body_imu[:3, :3] @ s.R_imu_cam
        off[c] = s.time_offset_s
    T_body_cam[idx], off[idx] = st.T_body_cam, st.time_offset_s
    delay = np.array([c.line_delay_s for c in cams])
    delay[idx] = st.line_delay_s
    return replace(st, T_body_cam=T_body_cam, time_offset_s=off, line_delay_s=delay), _settings_with(settings, res)


def estimate(inp: Inputs, T_world_board: np.ndarray, settings: ic.Settings
             ) -> tuple[ic.CameraImuResult, ic.Settings, int, Inputs, int]:
    """The camera-IMU estimate, every board's pose in it but the gauge's (most corners: the
    world frame). With several boards the start is the trajectory from the gauge board and
    the IMU alone (_gauge_pass), the other boards where the camera-only step put them, the
    cameras that do not see the gauge board from their rate start; the joint estimate moves
    them all (re-fitting the boards to the start trajectory first, by a separate least
    squares, gave the same optimum in the same number of iterations on the 4 s test
    recording and cost 2.6 s on the 30 s one). The estimate is refined once more with the
    corners weighted by the noise it measured when that differs from the assumed by over
    REWEIGHT_ABOVE (the first pass then stopped at REFINE_COST_TOL: only the refinement's
    start), or without the corners it puts beyond REJECT_SIGMA (judge_corners) when they are
    more than a handful. Returns (result, the settings it used, estimates run, the inputs
    without those corners, how many were left out); its state's
    boards are in estimator_corners' order, its `sigma` is not computed (parameter_sigmas
    gives every sigma the output needs)."""
    gauge, order, obs = estimator_corners(inp, len(T_world_board))
    models = [c.model for c in inp.cams]
    joint = settings.intrinsics  # the gauge pass (some cameras only) holds them
    intrinsics = inp.intrinsics if joint else ()
    # where the corners' measured noise already says the re-weighted refinement follows, the
    # first pass only starts it: it ends at REFINE_COST_TOL (the refinement converges from there
    # in as many steps; 30 s recording: the pass's last step, which gained 0.0002, not taken)
    loose = (ic.REFINE_COST_TOL, lambda blocks: abs(blocks[0].residual_rms - 1.0) >= REWEIGHT_ABOVE)
    if len(np.unique(inp.board)) > 1:
        # the corners weighted by the noise the gauge pass measured: the camera-only step's is
        # inflated by treating unsynchronised frames as one instant
        start, settings = _gauge_pass(inp, T_world_board, gauge, replace(settings, intrinsics=False))
        settings = replace(settings, intrinsics=joint)
        res = ic.solve_from(replace(start, T_world_board=T_world_board[order], intrinsics=intrinsics), obs, models,
                            inp.imu, settings, sigmas=False, loose=loose)
    else:
        res = ic.calibrate_camera_imu(_with_boards(inp, T_world_board), obs, inp.imu, settings,
                                      T_world_board[order], intrinsics, sigmas=False, loose=loose)
    out, inlier_px = judge_corners(res, obs, models)
    n_out = int(out.sum())
    if n_out <= max(REJECT_MIN, REJECT_REFIT * len(out)):
        n_out = 0  # a handful: kept
        if abs(res.normalised_rms["corners"] - 1.0) < REWEIGHT_ABOVE:
            return res, settings, 1, inp, 0
        settings = _settings_with(settings, res)
    else:
        # refined without them, weighted by the inliers' noise (the outliers inflated what the
        # first pass measured): the pass that re-weighting would run anyway
        inp = inp.corners_subset(~out)
        obs = estimator_corners(inp, len(T_world_board))[2]
        res = replace(res, corners_used=res.corners_used[~out])
        settings = replace(settings, sigma_px=max(inlier_px, 1e-3))
    return ic.refine(res, models, obs, inp.imu, settings, cost_tol=ic.ESTIMATE_COST_TOL), settings, 2, inp, n_out


def jacobian(res: ic.CameraImuResult, inp: Inputs, settings: ic.Settings):
    """(J, layout) of the final estimate: the residual blocks imu_calib minimises
    (imu_calib.residual_blocks) at its state, with `settings`' corner weights; those the
    estimate's last iteration made, re-weighted (estimator.reweighted_blocks), where it can."""
    state, imu = res.state, inp.imu
    lay = ir.layout_for(state, ic.held_groups(settings))
    blocks = ic.reweighted_blocks(res, settings)  # the last LM iteration's, when it made them
    if blocks is None:
        obs = estimator_corners(inp, len(state.T_world_board))[2].subset(res.corners_used)
        blocks = ic.residual_blocks(state, lay, obs, [c.model for c in inp.cams], imu,
                                    ic.imu_span(state.spline, imu.t), settings)
    return ir.assemble(ir.normal_rows(blocks), lay.size)[0], lay


def linear_sigmas(J, A: np.ndarray, lay: ir.Layout, factored=None) -> np.ndarray:
    """1-sigma of the linear combinations A (K, n) @ x under covariance (J^T J)^-1 (held
    parameters have empty columns and are left out): K solves with estimator.normal_factor's LU
    (`factored` when already made)."""
    solve, active = factored or ic.normal_factor(J, lay)
    a = np.asarray(A[:, active].T, dtype=float)
    return np.sqrt(np.maximum(np.einsum("ik,ik->k", a, solve(a)), 0.0))


def mean_weights(n: int) -> np.ndarray:
    """Trapezoid weights (n,) of the mean of a piecewise-linear function over its knots."""
    w = np.ones(n)
    if n > 1:
        w[[0, -1]] = 0.5
    return w / w.sum()


def parameter_sigmas(J, lay: ir.Layout, estimate_delay: bool, estimate_scale: bool = False,
                     intrinsics: tuple = (), factored=None) -> dict:
    """1-sigma of each camera's pose (C, 6: rotation rad about body axes, position m) and
    clock offset (C,), the mean gyroscope and accelerometer biases (3,) and, when estimated,
    every camera's line delay (C,), the 12 scale-misalignment parameters (`scale`: L of
    M_gyro, then of M_accel, in imu_residuals.SCALE_ROWS / SCALE_COLS order) and, given the
    estimated `intrinsics`, each camera's intrinsic values (`intrinsics`: per camera
    model_selection.intrinsic_sigmas' dict; held values 0). factored: estimator.normal_factor(J, lay)
    when already made."""
    w = mean_weights(lay.n_bias)
    C = lay.n_cam

    def unit(cols):
        A = np.zeros((len(cols), lay.size))
        A[np.arange(len(cols)), cols] = 1.0
        return A

    mean = np.zeros((6, lay.size))
    for k, start in enumerate((lay.bg, lay.ba)):
        for axis in range(3):
            mean[3 * k + axis, start + 3 * np.arange(lay.n_bias) + axis] = w
    parts = [unit(lay.cam + np.arange(6 * C)), unit(lay.offset + np.arange(C)), mean]
    if estimate_delay:
        parts.append(unit(lay.line_delay + np.arange(C)))
    if estimate_scale:
        parts.append(unit(lay.scale + np.arange(SCALE_PARAMETERS)))
    n_values = [len(i.values) for i in intrinsics]
    for c, intr in enumerate(intrinsics):  # each value as a combination of its camera's parameters
        E = intr.basis()
        A = np.zeros((len(intr.values), lay.size))
        A[:, lay.intr_start(c):lay.intr_start(c) + E.shape[1]] = E
        parts.append(A)
    sd = linear_sigmas(J, np.concatenate(parts), lay, factored)
    out = {"pose": sd[:6 * C].reshape(C, 6), "offset": sd[6 * C:7 * C], "gyro_bias": sd[7 * C:7 * C + 3],
           "accel_bias": sd[7 * C + 3:7 * C + 6]}
    k = 7 * C + 6
    out["line_delay"] = sd[k:k + C] if estimate_delay else None
    k += C if estimate_delay else 0
    out["scale"] = sd[k:k + SCALE_PARAMETERS] if estimate_scale else None
    k += SCALE_PARAMETERS if estimate_scale else 0
    out["intrinsics"] = [intrinsic_sigmas(np.diag(part ** 2)) for part in np.split(sd[k:], np.cumsum(n_values)[:-1])
                         ] if intrinsics else None
    return out


def intrinsics_coupling(J, lay: ir.Layout, intrinsics: tuple, factored=None) -> np.ndarray:
    """B (6 C, 4 C): how every camera's pose (rotation rad about body axes, position m: the
    sigmas' parameters) follows every camera's fx, fy, cx, cy at the optimum, from the formal
    covariance: B = C_PI C_II^+ (the regression of the poses on the intrinsics; held values
    have zero rows and drop out of the pseudo-inverse). When the intrinsics are less certain
    than the formal covariance says by Delta, the poses are by B Delta B^T. factored:
    estimator.normal_factor(J, lay) when already made."""
    C = lay.n_cam
    A_P = np.zeros((6 * C, lay.size))
    A_P[np.arange(6 * C), lay.cam + np.arange(6 * C)] = 1.0
    A_I = np.zeros((4 * C, lay.size))
    for c, intr in enumerate(intrinsics):
        E = intr.basis()[:4]
        A_I[4 * c:4 * c + 4, lay.intr_start(c):lay.intr_start(c) + E.shape[1]] = E
    solve, active = factored or ic.normal_factor(J, lay)
    S = solve(np.asarray(A_I[:, active].T, dtype=float))
    C_II, C_PI = A_I[:, active] @ S, A_P[:, active] @ S
    return C_PI @ np.linalg.pinv(C_II, rcond=1e-12, hermitian=True)


def noise_warnings(imu: Imu, gyro: tuple[float, float], accel: tuple[float, float]) -> list[str]:
    """A warning per sensor whose residual RMS differs from the declared density's
    prediction by more than NOISE_WARN_RATIO either way: the figures look wrong."""
    out = []
    for what, key, (rms, pred), unit in (("gyroscope", "gyroscope_noise_density", gyro, "rad/s"),
                                         ("accelerometer", "accelerometer_noise_density", accel, "m/s^2")):
        ratio = rms / pred
        if not 1 / NOISE_WARN_RATIO <= ratio <= NOISE_WARN_RATIO:
            out.append(f"{imu.name}: {what} residual RMS {rms:.3g} {unit} is {ratio:.2g}x what {key} predicts "
                       f"({pred:.3g} {unit} at {imu.update_rate:g} Hz); the declared noise figures look wrong "
                       f"(the sigmas rest on them; measure them from a still recording with `rigcal imu-noise`)")
    return out


def calibrate_imu(cal, samples: ImuSamples, imu: Imu, options: Options, faces: list[float],
                  line_delays: dict[str, float], time_offsets: dict[str, float],
                  settings: ic.Settings | None = None, image_t_ns=None) -> ImuCalibration:
    """The camera-IMU calibration after the camera-only one (`cal`): see the module text.
    Raises CalibrationError (exit 1) when the recording cannot determine it, DatasetError
    (exit 2) when it is too short."""
    t0 = time.perf_counter()
    estimate_delay = options.rolling_shutter if options.rolling_shutter is not None else any(
        v > 0 for v in line_delays.values())
    inp = build_inputs(cal, samples, imu, faces, time_offsets, line_delays, image_t_ns)
    freed = options.imu_intrinsics in ("auto", "joint") and motion_unmodelled(line_delays, estimate_delay,
                                                                             image_t_ns)
    if freed:
        inp = replace(inp, intrinsics=free_structure(inp.intrinsics))
    base = settings or ic.Settings()
    knot = None
    if options.knot_spacing is not None:
        base = replace(base, knot_dt=options.knot_spacing)
    elif settings is None:
        knot = choose_knots(inp.imu)
        base = replace(base, knot_dt=knot.knot_dt)
    check_span(inp, list(cal.cam_names), base.knot_dt)
    # the camera-only RMS is of each corner's residual norm; the estimator's sigma_px is per
    # coordinate. Started at the norm's, a single-board recording needed a second full pass
    # to correct the weights (EuRoC: 2 x 60 s)
    settings = replace(base, sigma_px=max(float(cal.rms_px) / math.sqrt(2.0), 0.01), gravity=options.gravity,
                       window_s=options.offset_window, line_delay=estimate_delay,
                       scale_misalignment=options.imu_model == "scale-misalignment",
                       # auto unresolved (a caller other than calibrate.run, which resolves it against the
                       # declared rig first): estimated with the rest, as before there was a choice
                       intrinsics=options.imu_intrinsics in ("auto", "joint", "prior"))
    if options.imu_intrinsics == "prior":
        inp, prior = with_prior(inp, cal.declared if cal.declared is not None else cal.rig, list(cal.cam_names))
        settings = replace(settings, intrinsics_prior=prior)
    try:
        res, settings, passes, inp, n_out = estimate(inp, cal.state.T_world_board, settings)
        test = None
        _, order, obs = estimator_corners(inp, len(cal.state.T_world_board))
        if options.imu_model == "auto":
            # scale-misalignment from the calibrated solution, on the same corners and weights,
            # the boards estimated with it
            models = [c.model for c in inp.cams]
            sm_settings = replace(settings, scale_misalignment=True)
            sm = ic.refine(res, models, obs, inp.imu, sm_settings)
            test = imu_model_test(res, sm)
            if test.significant:
                # kept: the test's fit is the estimate. It stopped at a step gaining under
                # REFINE_COST_TOL (chi-square units), i.e. within sqrt(0.05) = 0.22 of a
                # standard deviation of the optimum at most, in practice far closer: on EuRoC
                # its last steps gained 0.28 and 0.001, and running it to convergence cost 8 s
                # and moved the YAML's numbers by under 1e-6 relative
                res, settings = sm, sm_settings
    except CalibrationError as e:
        if "search window" in str(e):
            raise CalibrationError(f"{e} (calibrate --offset-window SECONDS; now {options.offset_window:g} s)") from None
        raise
    # sigmas with the corners weighted by their measured noise (the variance factor)
    J, lay = jacobian(res, inp, _settings_with(settings, res))
    res = replace(res, blocks=())  # used: not kept in the answer
    factored = ic.normal_factor(J, lay)  # one LU for the sigmas and the intrinsics' coupling
    sig = parameter_sigmas(J, lay, estimate_delay, settings.scale_misalignment,
                           res.state.intrinsics if settings.intrinsics else (), factored)
    names = list(cal.cam_names)
    check = None
    warnings = []
    if options.subsets:
        _, _, obs_all = estimator_corners(inp, len(cal.state.T_world_board))
        coupling = intrinsics_coupling(J, lay, res.state.intrinsics, factored) if settings.intrinsics else None
        check = subset_check(res, obs_all, [c.model for c in inp.cams], inp.imu, settings, sig, estimate_delay,
                             coupling)
        if check is not None:
            sig = check.sigma
            warnings += intrinsics_warnings(check, names, bool(settings.intrinsics_prior))
    w = mean_weights(lay.n_bias)
    rate = math.sqrt(imu.update_rate)
    pred = imu.gyroscope_noise_density * rate, imu.accelerometer_noise_density * rate
    rms = res.normalised_rms["gyro"] * pred[0], res.normalised_rms["accel"] * pred[1]
    reweighted = (f" (the second without the {n_out} corners the first put beyond {REJECT_SIGMA:g} robust sigmas, "
                  f"e.g. near the edge of something in front of the board, and re-weighted by the others' noise)"
                  if n_out else " (the second with the corners re-weighted by the noise the first measured)"
                  if passes > 1 else "")
    source = ("prior" if settings.intrinsics_prior else "joint") if settings.intrinsics else (
        "declared" if options.intrinsics_from_rig else "camera-only")
    held = {"joint": "too" + (" (fx, fy, cx, cy each: the camera-only step chose its structure on residuals that "
                                 "carry the rolling shutter's or the free-running images' motion)" if freed else ""),
            "declared": "held at the declared rig's own calibration (--imu-intrinsics joint "
                                        "re-estimates them)",
            "prior": "too, weighted by the declared rig's own calibration and its sigmas (--imu-intrinsics prior)",
            "camera-only": "held at the camera-only ones (--imu-intrinsics held)"}[source]
    notes = [knot.line() if knot is not None else f"knot spacing {settings.knot_dt:g} s (--knot-spacing)",
             f"camera-IMU: {passes} estimate(s){reweighted}, {res.iterations} "
             f"Levenberg-Marquardt iterations in the last, every board but the gauge estimated with it, the "
             f"intrinsics {held}, corners weighted at {settings.sigma_px:.3g} px"]
    if check is not None:
        notes.append(check.line(names))
    elif options.subsets:
        notes.append("sigmas: formal only (the recording's halves could not be estimated apart)")
    chosen = "scale-misalignment" if settings.scale_misalignment else "calibrated"
    notes.append(f"IMU model {chosen}: " + (test.line() + f" (the larger fit {test.seconds:.1f} s)" if test is not None
                                            else f"--imu-model {chosen} (not tested)"))
    T_world_board = np.empty_like(res.state.T_world_board)
    T_world_board[order] = res.state.T_world_board
    warnings = noise_warnings(imu, (rms[0], pred[0]), (rms[1], pred[1])) + warnings
    return ImuCalibration(res, imu, T_world_board, sig, w @ res.state.gyro_bias, w @ res.state.accel_bias,
                          rms[0], rms[1], pred[0], pred[1], settings.sigma_px * res.normalised_rms["corners"], passes,
                          time.perf_counter() - t0, tuple(warnings),
                          tuple(notes), chosen, test, res.state.intrinsics if settings.intrinsics else (), knot,
                          settings.knot_dt, check, source)


def motion_unmodelled(line_delays: dict[str, float], estimate_delay: bool, image_t_ns) -> bool:
    """Whether the camera-only step's residuals carry motion it does not model: a rolling
    shutter (declared or estimated: each row at its own time) or free-running images grouped
    into one instant (image_t_ns)."""
    return bool(image_t_ns) or estimate_delay or any(v > 0 for v in line_delays.values())


def free_structure(intrinsics: tuple) -> tuple:
    """The intrinsics with fx, fy, cx and cy each a parameter of its own. The camera-only step
    tests fx = fy and a held principal point against its measured corner noise; where its
    residuals carry motion it does not model (motion_unmodelled) that noise is inflated (0.30-
    0.37 px against the camera-IMU fit's 0.01-0.02 px on a rendered rolling-shutter recording)
    and it accepts reductions the data reject: on that recording fx = fy with fx and fy 0.7 px
    apart, and the joint estimate moved the principal point 2 px to absorb it, the camera's
    rotation 0.19 deg; with the structure free, 0.008 deg."""
    return tuple(replace(i, tie_focal=False, hold_centre=False) for i in intrinsics)


# ----------------------------------------------------------------------------- defaults


def choose_knots(imu: ic.ImuInput) -> imu_start.KnotChoice:
    """The knot spacing the IMU's own signal asks for (imu_start.choose_knot_spacing)."""
    sg, sa = ic.imu_sigmas(imu)
    return imu_start.choose_knot_spacing(imu.t, imu.gyro, imu.accel, sg, sa, imu.update_rate)


def is_camera_calibration(rig) -> bool:
    """Every camera of the declared rig carries calibration.sigma.intrinsics: the rig is the
    output of an earlier `rigcal calibrate` (a camera calibration)."""
    def has(c):
        sigma = (c.calibration or {}).get("sigma")
        return isinstance(sigma, dict) and bool(sigma.get("intrinsics"))

    return bool(rig.cameras) and all(has(c) for c in rig.cameras)


def resolve_intrinsics(choice: str, rig) -> tuple[str, bool]:
    """(`joint`, `held` or `prior`, whether the intrinsics start from the declared rig's own
    calibration) for --imu-intrinsics `choice`: auto holds a camera calibration's intrinsics
    (Kalibr's and basalt's workflow: calibrate the cameras on a recording made for it, then
    camera-IMU), else estimates them with the rest; prior needs a camera calibration."""
    calibrated = is_camera_calibration(rig)
    if choice == "auto":
        return ("held", True) if calibrated else ("joint", False)
    if choice == "prior" and not calibrated:
        raise InputError("--imu-intrinsics prior: the declared rig is not a camera calibration (every camera needs "
                         "calibration.sigma.intrinsics, as `rigcal calibrate` writes); pass one with --rig")
    return choice, choice in ("held", "prior") and calibrated


def with_prior(inp: Inputs, declared, names: list[str]) -> tuple[Inputs, tuple]:
    """(inputs whose intrinsics have fx, fy, cx, cy as parameters of their own, per camera
    (fx fy cx cy, their 1-sigma) of the declared camera calibration) for --imu-intrinsics
    prior. The camera-only step held the declared intrinsics, so they are the start too."""
    intr = tuple(replace(i, tie_focal=False, hold_centre=False) for i in inp.intrinsics)
    prior = []
    for name, i in zip(names, intr):
        sig = declared.camera(name).calibration["sigma"]["intrinsics"]
        prior.append((i.values[:4].copy(), np.array([max(float(sig[k]), 1e-6) for k in INTRINSIC_KEYS])))
    return replace(inp, intrinsics=intr), tuple(prior)


# ----------------------------------------------------------------------------- subset sigmas

SUBSET_MAX_ITER = 8  # each half from the full solution: LM needs few steps
SUBSET_COST_TOL = 0.5  # chi-square units: a step gaining less ends a half's estimate
MIN_SUBSET_CORNERS = 200  # per camera and half, else that camera is not compared
INTRINSICS_SPREAD_PX = 1.0  # halves differing by more (fx, fy, cx or cy): the intrinsics are poorly determined
FORMAL_TOO_SMALL = 3.0  # ... or the halves' sigma over the formal one beyond this
SUBSET_LEVEL = 0.01  # a group's halves disagreeing beyond the formal sigmas at this level: the group is scaled
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True, eq=False)
class SubsetCheck:
    """The estimate repeated on each half of the recording (in time) from the full
    solution: per camera the halves' difference of rotation (rad, body axes), position
    (m), clock offset (s), line delay (s) and intrinsics (fx, fy, cx, cy px; None when held),
    `compared` (C,) bool (each half saw the camera), the formal and the reported sigma dicts
    (parameter_sigmas' form), per camera `factor` {group: reported / formal, max over the
    group} and the seconds it took."""

    d_rot: np.ndarray
    d_pos: np.ndarray
    d_offset: np.ndarray
    d_delay: np.ndarray | None
    d_intr: np.ndarray | None
    compared: np.ndarray
    formal: dict
    sigma: dict
    factor: list
    seconds: float
    split_s: float

    def source(self, c: int) -> str:
        """`subsets` when any of camera c's sigmas was raised to what the halves show."""
        return "subsets" if max(self.factor[c].values(), default=1.0) > 1.0 else "formal"

    def line(self, names: list[str]) -> str:
        raised = [f"{n} {k} x{v:.1f}" for n, f in zip(names, self.factor) for k, v in f.items() if v > 1.0]
        what = ("raised to what the halves show where the formal ones were smaller: " + ", ".join(raised)
                if raised else "the formal ones cover the halves' differences")
        return (f"sigmas checked on the recording's halves (split at {self.split_s:.1f} s, each estimated from the "
                f"whole recording's solution, {self.seconds:.1f} s): {what}")


def state_window(state: ir.State, t_lo: float, t_hi: float) -> ir.State:
    """The state restricted to the IMU-clock times [t_lo, t_hi]: the spline's controls and
    the bias knots that reach them (same curve there), everything else as is."""
    sp_ = state.spline
    n_seg = len(sp_.p) - spl.ORDER + 1
    i0 = int(np.clip(np.floor((t_lo - sp_.t0) / sp_.dt), 0, n_seg - 1))
    i1 = int(np.clip(np.ceil((t_hi - sp_.t0) / sp_.dt), i0 + 1, n_seg))
    spline = spl.Spline(sp_.t0 + i0 * sp_.dt, sp_.dt, sp_.R[i0:i1 + spl.ORDER - 1], sp_.p[i0:i1 + spl.ORDER - 1])
    nb = len(state.gyro_bias)
    j0 = int(np.clip(np.floor((spline.t0 - state.bias_t0) / state.bias_dt), 0, nb - 2))
    j1 = int(np.clip(np.ceil((spline.t_end - state.bias_t0) / state.bias_dt), j0 + 1, nb - 1))
    return replace(state, spline=spline, bias_t0=state.bias_t0 + j0 * state.bias_dt,
                   gyro_bias=state.gyro_bias[j0:j1 + 1].copy(), accel_bias=state.accel_bias[j0:j1 + 1].copy())


def _values(st: ir.State, estimate_delay: bool, intrinsics: bool):
    """(T_body_cam, offsets, line delays or None, intrinsics (C, 4) or None) of a state."""
    intr = np.stack([i.values[:4] for i in st.intrinsics]) if intrinsics and st.intrinsics else None
    return st.T_body_cam, st.time_offset_s, st.line_delay_s if estimate_delay else None, intr


def halves_differences(a: ir.State, b: ir.State, estimate_delay: bool, intrinsics: bool) -> tuple:
    """(rotation (C, 3) rad about body axes, position (C, 3) m, offset (C,), line delay (C,)
    or None, intrinsics (C, 4) or None): a's values minus b's, as the sigmas are expressed
    (rotations perturbed on the left: Log(R_a R_b^T))."""
    Ta, oa, la, ia = _values(a, estimate_delay, intrinsics)
    Tb, ob, lb, ib = _values(b, estimate_delay, intrinsics)
    d_rot = geo.rotvecs_from_R(Ta[:, :3, :3] @ np.swapaxes(Tb[:, :3, :3], 1, 2))
    return (d_rot, Ta[:, :3, 3] - Tb[:, :3, 3], oa - ob, None if la is None else la - lb,
            None if ia is None else ia - ib)


def inflated(formal: np.ndarray, diff: np.ndarray) -> np.ndarray:
    """The sigma a group of K parameters (formal (K,), the halves' differences (K,)) is
    reported with. Each half holds about half the data, so under the formal covariance the
    halves' difference has twice the full estimate's sigma (sqrt(2) per half) and a
    parameter's sigma as the halves show it is |d| / 2. Per parameter the larger of the
    formal sigma and |d| / 2; and when the group's q = sum (d / 2 formal)^2 exceeds the
    chi-square quantile of K degrees of freedom at SUBSET_LEVEL (the halves disagree by more
    than the formal sigmas allow, not by chance) every sigma of the group is at least the
    formal one times sqrt(q / K)."""
    f = np.maximum(np.asarray(formal, float), 1e-300)
    half = 0.5 * np.abs(np.asarray(diff, float))
    q = float(np.sum((half / f) ** 2))
    k = math.sqrt(q / len(f)) if q > chdtri(len(f), SUBSET_LEVEL) else 1.0
    return np.maximum(np.maximum(f, half), k * f)


def subset_sigmas(formal: dict, diffs: tuple, compared: np.ndarray, coupling: np.ndarray | None = None
                  ) -> tuple[dict, list]:
    """(reported sigma dict, per camera {group: reported / formal at most}) from the formal
    parameter_sigmas and the halves' differences (halves_differences), cameras `compared`
    only; other entries (biases, scale) stay formal. `coupling` (intrinsics_coupling's B):
    the intrinsics' variance beyond the formal one carried into every pose through B (a
    principal point the halves place pixels apart turns the camera's extrinsic rotation by
    about that over the focal length; the halves alone share such a bias and miss it)."""
    d_rot, d_pos, d_off, d_delay, d_intr = diffs
    out = {**formal, "pose": formal["pose"].copy(), "offset": formal["offset"].copy()}
    C = len(formal["offset"])
    factor = [{} for _ in range(C)]
    if formal.get("line_delay") is not None:
        out["line_delay"] = formal["line_delay"].copy()
    if formal.get("intrinsics") is not None:
        out["intrinsics"] = [dict(i) for i in formal["intrinsics"]]
    for c in np.flatnonzero(compared):
        groups = [("rotation", formal["pose"][c, :3], d_rot[c], lambda v: out["pose"].__setitem__((c, slice(0, 3)), v)),
                  ("position", formal["pose"][c, 3:], d_pos[c], lambda v: out["pose"].__setitem__((c, slice(3, 6)), v)),
                  ("time_offset", formal["offset"][c:c + 1], d_off[c:c + 1],
                   lambda v: out["offset"].__setitem__(c, v[0]))]
        if d_delay is not None and formal.get("line_delay") is not None:
            groups.append(("line_delay", formal["line_delay"][c:c + 1], d_delay[c:c + 1],
                           lambda v: out["line_delay"].__setitem__(c, v[0])))
        if d_intr is not None and formal.get("intrinsics") is not None:
            fi = np.array([formal["intrinsics"][c][k] for k in INTRINSIC_KEYS])
            held = fi <= 0  # a held value (the principal point of `centred`) has no sigma and no difference

            def put(v, c=c, held=held):
                for k, key in enumerate(INTRINSIC_KEYS):
                    if not held[k]:
                        out["intrinsics"][c][key] = float(v[k])
            groups.append(("intrinsics", np.where(held, 1.0, fi), np.where(held, 0.0, d_intr[c]), put))
        for name, f, d, put in groups:
            v = inflated(f, d)
            put(v)
            factor[c][name] = float(np.max(v / np.maximum(f, 1e-300)))
    if coupling is not None and out.get("intrinsics") is not None:
        excess = np.array([[max(out["intrinsics"][c][k] ** 2 - formal["intrinsics"][c][k] ** 2, 0.0)
                            for k in INTRINSIC_KEYS] for c in range(C)]).ravel()
        extra = np.einsum("pk,k,pk->p", coupling, excess, coupling).reshape(C, 6)
        if extra.any():
            pose = np.sqrt(out["pose"] ** 2 + extra)
            for c in range(C):
                for name, cols in (("rotation", slice(0, 3)), ("position", slice(3, 6))):
                    r = float(np.max(pose[c, cols] / np.maximum(formal["pose"][c, cols], 1e-300)))
                    if r > factor[c].get(name, 1.0):
                        factor[c][name] = r
            out["pose"] = pose
    return out, factor


def subset_check(res: ic.CameraImuResult, obs: ir.Corners, models: list, imu: ic.ImuInput, settings: ic.Settings,
                 formal: dict, estimate_delay: bool, coupling: np.ndarray | None = None) -> SubsetCheck | None:
    """The estimate on each half of the recording in time (its corners and IMU samples),
    each started from the whole recording's solution (state_window) and stopped early
    (SUBSET_MAX_ITER, SUBSET_COST_TOL), and the sigmas it supports (subset_sigmas). None
    when a half cannot be estimated (too short for its spline, or its LM fails)."""
    t0 = time.perf_counter()
    st = res.state
    t_c = ir.corner_times(st, obs.subset(res.corners_used))
    lo, hi = float(t_c.min()), float(t_c.max())
    mid = 0.5 * (lo + hi)
    quick = replace(settings, max_iter=SUBSET_MAX_ITER)

    def half(span):
        part = state_window(st, max(span[0], st.spline.t0), min(span[1], st.spline.t_end))
        try:
            r = ic.solve_from(part, obs, models, imu, quick, sigmas=False, cost_tol=SUBSET_COST_TOL,
                              lam0=ic.WARM_LAMBDA)
        except (CalibrationError, ValueError, np.linalg.LinAlgError):
            return None
        return r.state, np.bincount(obs.cam[r.corners_used], minlength=len(models))

    # two threads: the halves are independent and numpy / SuperLU release the GIL in their
    # heavy parts
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=2) as ex:
        halves = list(ex.map(half, ((lo - 1.0, mid), (mid, hi + 1.0))))
    if any(h is None for h in halves):
        return None
    compared = (halves[0][1] >= MIN_SUBSET_CORNERS) & (halves[1][1] >= MIN_SUBSET_CORNERS)
    if not compared.any():
        return None
    diffs = halves_differences(halves[0][0], halves[1][0], estimate_delay, settings.intrinsics)
    sigma, factor = subset_sigmas(formal, diffs, compared, coupling)
    return SubsetCheck(*diffs, compared, formal, sigma, factor, time.perf_counter() - t0, mid)


def intrinsics_warnings(check: SubsetCheck, names: list[str], prior: bool = False) -> list[str]:
    """A warning per camera whose intrinsics, estimated from this motion recording, differ
    between its halves by over INTRINSICS_SPREAD_PX or by over FORMAL_TOO_SMALL formal
    sigmas: the recording determines them poorly; the fix is a camera calibration first."""
    if check.d_intr is None:
        return []
    out = []
    for c in np.flatnonzero(check.compared):
        d = check.d_intr[c]
        f = np.array([check.formal["intrinsics"][c][k] for k in INTRINSIC_KEYS])
        est = f > 0
        worst = int(np.argmax(np.where(est, np.abs(d), -1)))
        ratio = check.factor[c].get("intrinsics", 1.0)
        if not est.any() or (abs(d[worst]) <= INTRINSICS_SPREAD_PX and ratio <= FORMAL_TOO_SMALL):
            continue
        rep = check.sigma["intrinsics"][c]
        spread = ", ".join(f"{k} {d[i]:+.1f}" for i, k in enumerate(INTRINSIC_KEYS) if est[i])
        now = ", ".join(f"{k} {rep[k]:.2f}" for k, e in zip(INTRINSIC_KEYS, est) if e)
        out.append(f"camera {names[c]}: this recording determines its intrinsics poorly: its two halves differ by "
                   f"{spread} px (reported 1-sigma now {now} px, "
                   f"{ratio:.0f}x the formal); " + (
                       "the declared calibration's prior did not hold them: --imu-intrinsics auto holds them"
                       if prior else
                       "calibrate the cameras first on a recording made for it (the board filling the corners of "
                       "each image, moved slowly) and pass that output as --rig: its intrinsics are then held here"))
    return out


def plan(rig, imus_read: dict, reference: str | None, camera_only: bool = False) -> tuple[str | None, str]:
    """(the IMU to calibrate against or None, the reference for the camera-only step and
    the output). docs/formats.md#motion-datasets: with imu/ and an IMU declared the default reference is
    `imu:<first>`; `imu:NAME` needs a declared IMU with data; `aligned` and `camera:NAME`
    still calibrate against the first IMU and place it by those cameras. camera_only
    (`--camera-only`): the IMU data are checked but not used, as for a dataset without imu/."""
    if camera_only:
        if reference is not None and reference.startswith("imu:"):
            raise InputError(f"--reference {reference} needs the camera-IMU calibration that --camera-only skips; "
                             f"use --reference aligned or camera:NAME")
        return None, reference or "aligned"
    if reference is not None and reference.startswith("imu:"):
        name = reference.split(":", 1)[1]
        if name not in [i.name for i in rig.imus]:
            have = ", ".join(i.name for i in rig.imus) or "none"
            raise InputError(f"--reference {reference}: the rig declares no IMU {name!r} (IMUs: {have})")
        if name not in imus_read:
            raise InputError(f"--reference {reference}: the dataset has no imu/{name}.csv; without IMU data use "
                             f"--reference aligned or camera:NAME")
        return name, reference
    if not imus_read:
        return None, reference or "aligned"
    first = rig.imus[0].name
    return first, reference or f"imu:{first}"

