"""Free-running cameras without an IMU: the rig's motion as a continuous-time trajectory
constrained by the views alone (docs/camera-imu-free-running.md#without-an-imu).

Cameras that do not share stems take their images at different instants; a camera-only
calibration, which treats each group of images as one instant, would carry the motion
between them as extrinsic error. Here every image is placed on a spline trajectory
T_world_body(t) (rigcal.core.spline) at its own time plus its camera's clock offset, and the
reprojection residuals are those of the camera-IMU estimator (rigcal.imucal.residuals),
with nothing but the views and a smoothness prior to shape the trajectory.

Estimated: the trajectory, every camera's T_body_cam but the reference camera's (held at
the camera-only start's: it fixes the body frame, which is then placed by the rig's
reference convention, camcal.body_frame.reference_transform), every camera's clock offset
but the reference camera's (held at 0: its clock is the time base; t_ref = t_cam +
time_offset_s), every board's pose but board 0's (the world), and the intrinsics unless
held (--fix-intrinsics, or a declared camera calibration). Estimated intrinsics have fx,
fy, cx and cy each a parameter of its own (imucal.step.free_structure), whatever the
camera-only start chose with `--intrinsics auto` (another --intrinsics is kept): the start
tests fx = fy and a held principal point on residuals that carry the motion between the
grouped images, and accepts reductions the continuous-time fit rejects. On simulated
corners whose back camera sees only a board the front cameras never see (its pose
relative to them from the rig's motion alone), the start ties the back camera's fx = fy
with the true ones 0.32 px apart; the tied fit puts the front cameras 10 mm off along L
relative to it (8 reported sigmas), with fx and fy free 1.5 mm, and freeing the tied
focal lengths lowers the cost by 68 (two parameters).

The smoothness prior: each control point's second difference over dt^2 (the knot's
acceleration, of the position and of the rotation) is taken as zero-mean with a 1-sigma of
the start trajectory's own RMS knot acceleration. That is as wide as the motion itself, so
where views are dense (every knot interval holds images of most cameras) the views decide;
where none are (the boards out of view) it makes the trajectory the smoothest through
them, so it stays defined. Knots every frame period of the slowest camera, or a half or a
third of it where that fits the corners markedly better (choose_knots).

The start: the camera-only calibration of the images grouped by time
(rigcal.data.dataset.associate_by_time): its rig poses per group placed at the group's
mean image time make the start spline, its T_body_cam and board poses the rest; clock
offsets start at the declared time_offset_s differences. Then Levenberg-Marquardt
(imucal.estimator.levenberg_marquardt), once more with the corners weighted by the noise
the first pass measured, and the sigmas from the Jacobian at the solution.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from rigcal.core import geometry as geo
from rigcal.errors import CalibrationError
from rigcal.imucal import estimator as ic
from rigcal.imucal import residuals as ir

KNOT_PERIODS = 1.0  # the coarsest knot spacing in frame periods of the slowest camera
KNOT_FRACTIONS = (1.0, 1 / 2, 1 / 3)  # of it, tried coarsest first (choose_knots)
KNOT_MIN_GAIN = 0.9  # a finer spacing is kept when it lowers the corner RMS to this fraction or below
MIN_VIEWS_PER_FINER_KNOT = 1.0  # finer spacings are tried while the views number this many per knot
KNOT_LIMITS_S = (0.01, 0.2)
MIN_VIEWS_PER_KNOT = 1.5  # images with a board per knot over the recording's span
MIN_SHARED_VIEWS = 10  # per camera: images within one knot spacing of another camera's image
MAX_OFFSET_SIGMA_KNOTS = 0.25  # an offset known to worse than this many knot spacings is not determined
SIGMA_PX = 0.5  # the first pass's corner noise; the second weighs by the measured
HELD = frozenset({"imu_rot", "imu_pos", "line_delay", "scale", "bg", "ba", "grav"})
MAX_ITER = 30


@dataclass(frozen=True, eq=False)
class VisualMotionResult:
    """The estimate, names in cal.cam_names order: T_body_cam (C, 4, 4) in the body frame
    of the reference camera's camera-only pose (before reference_transform), time_offset_s
    (C,) relative to the reference camera's clock, sigma (C, 7) (rotation rad about body
    axes, position m, offset s; zeros for the held reference camera), intrinsics (per camera
    camcal.solve.Intrinsics, or () when held) with sigma_intrinsics (C, 4) of fx fy cx cy
    (or None), the reference camera's index, knot spacing, prior sigmas, the corner noise
    measured (px), iterations and seconds."""

    T_body_cam: np.ndarray
    time_offset_s: np.ndarray
    sigma: np.ndarray
    intrinsics: tuple
    sigma_intrinsics: np.ndarray | None
    reference: int
    knot_dt: float
    prior_sigma: tuple  # (m/s^2, rad/s^2)
    corner_rms_px: float
    sigma_px: float
    iterations: int
    seconds: float
    state: ir.State
    knots_tried: tuple = ()  # ((knot spacing s, corner RMS px of a first pass), ...): choose_knots
    # the estimate repeated on each half of the recording (imucal.step.SubsetCheck): `sigma` and
    # `sigma_intrinsics` are then its reported ones (the formal ones raised where the halves
    # disagree by more), formal_sigma the Jacobian's; None when the halves were not estimated
    subsets: object = None
    formal_sigma: np.ndarray | None = None
    # every image with a board: its time on the reference camera's clock (s, the spline's
    # time base: the first image's stem + its offset) and its camera, for the report
    image_t: np.ndarray | None = None
    image_cam: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Views:
    """The corners with each image's own time: cam (M,), t (M,) seconds from the first
    image, uv, p_board, board (M,) (camera-only indices), and per image (cam, frame) its
    time (N,) and camera (N,) for the checks."""

    corners: ir.Corners
    image_t: np.ndarray
    image_cam: np.ndarray
    t_base_ns: int


def image_times(cal, image_t_ns) -> np.ndarray:
    """(C, F) each image's own time in ns: the stem of camera c's image in frame f
    (image_t_ns: camera -> frame -> stem), else the frame's name."""
    t = np.tile(np.array([int(f) for f in cal.frames], dtype=np.int64), (len(cal.cam_names), 1))
    for c, name in enumerate(cal.cam_names):
        for fi, f in enumerate(cal.frames):
            own = (image_t_ns or {}).get(name, {})
            if f in own:
                t[c, fi] = int(own[f])
    return t


def views_of(cal, image_t_ns) -> Views:
    """Every corner of the camera-only step (its outlier flags ignored: grouping images of
    different instants made them), at its image's own time."""
    o = cal.obs
    t_ns = image_times(cal, image_t_ns)
    base = int(t_ns.min())
    t = (t_ns - base) * 1e-9
    pairs = np.unique(np.stack([o.cam, o.frame], axis=1), axis=0)
    return Views(ir.Corners(o.cam.copy(), t[o.cam, o.frame], o.uv.copy(), o.p_board.copy(), o.board.copy()),
                 t[pairs[:, 0], pairs[:, 1]], pairs[:, 0], base)


def frame_period(t: np.ndarray) -> float:
    """The median interval of sorted times t (s); inf for fewer than two."""
    return float(np.median(np.diff(np.sort(t)))) if len(t) > 1 else float("inf")


def knot_spacing(views: Views, n_cams: int) -> float:
    """KNOT_PERIODS frame periods of the slowest camera (its images with a board), within
    KNOT_LIMITS_S."""
    periods = [frame_period(np.unique(views.image_t[views.image_cam == c])) for c in range(n_cams)]
    finite = [p for p in periods if np.isfinite(p)]
    if not finite:
        raise CalibrationError("free-running cameras without an IMU: no camera has two images with a board")
    return float(np.clip(KNOT_PERIODS * max(finite), *KNOT_LIMITS_S))


def check_views(views: Views, names: list[str], dt: float) -> None:
    """Refuse (CalibrationError, one line) what the views cannot model: too few images with a
    board per knot, or a camera whose images never come within a knot spacing of another
    camera's (its clock cannot be related to theirs without an IMU)."""
    span = float(views.image_t.max() - views.image_t.min())
    knots = max(span / dt, 1.0)
    per_knot = len(views.image_t) / knots
    if per_knot < MIN_VIEWS_PER_KNOT:
        raise CalibrationError(
            f"free-running cameras without an IMU: {len(views.image_t)} images with a board over {span:.2f} s are "
            f"{per_knot:.2f} per knot of the trajectory (every {1000 * dt:.0f} ms); the motion between the cameras' "
            f"instants needs at least {MIN_VIEWS_PER_KNOT:g}: record more images with the boards in view, or add "
            f"an IMU")
    for c, name in enumerate(names):
        own = np.sort(views.image_t[views.image_cam == c])
        other = np.sort(views.image_t[views.image_cam != c])
        if len(own) == 0 or len(other) == 0:
            continue
        k = np.clip(np.searchsorted(other, own), 1, len(other) - 1) if len(other) > 1 else np.zeros(len(own), int)
        near = np.minimum(np.abs(other[k] - own), np.abs(other[np.maximum(k - 1, 0)] - own))
        shared = int(np.sum(near <= dt))
        if shared < MIN_SHARED_VIEWS:
            raise CalibrationError(
                f"camera {name}: only {shared} of its {len(own)} images with a board lie within {1000 * dt:.0f} ms of "
                f"another camera's; without an IMU its clock offset and pose need at least {MIN_SHARED_VIEWS} "
                f"(the boards in view of it and another camera at the same time), or an IMU")


def start_trajectory(cal, views: Views, image_t_ns, dt: float):
    """The start spline T_world_body(t) (world: the camera-only calibration's) through the
    camera-only rig pose of each group of images at the mean time of its images with a
    board, in the output body frame of the camera-only rig (cal.T_body_solve)."""
    o = cal.obs
    t_ns = image_times(cal, image_t_ns)
    seen = np.zeros(t_ns.shape, bool)
    seen[o.cam, o.frame] = True
    frames = np.flatnonzero(seen.any(axis=0))
    t = np.array([(t_ns[seen[:, f], f].mean() - views.t_base_ns) * 1e-9 for f in frames])
    T_world_body = geo.inv_T(cal.T_body_solve[None] @ cal.state.T_body_world[frames])
    return ic.initial_spline(t, T_world_body, dt, dt)


def knot_accelerations(spline) -> tuple[np.ndarray, np.ndarray]:
    """Each inner control point's second differences over dt^2: (position (N-2, 3) m/s^2,
    rotation (N-2, 3) rad/s^2, Log(R_k^T R_k+1) - Log(R_k-1^T R_k))."""
    dt2 = spline.dt ** 2
    P, R = spline.p, spline.R
    a = (P[:-2] - 2 * P[1:-1] + P[2:]) / dt2
    phi = geo.rotvecs_from_R(np.swapaxes(R[:-1], 1, 2) @ R[1:])
    return a, (phi[1:] - phi[:-1]) / dt2


def prior_sigmas(spline) -> tuple[float, float]:
    """The smoothness prior's 1-sigma (m/s^2, rad/s^2): the RMS knot acceleration of the
    start trajectory (floored so that a rig at rest keeps a finite weight)."""
    a, al = knot_accelerations(spline)
    rms = lambda x: float(np.sqrt(np.mean(np.sum(x ** 2, axis=1)) / 3)) if len(x) else 1.0  # noqa: E731
    return max(rms(a), 1e-2), max(rms(al), 1e-2)


def smoothness_blocks(state: ir.State, lay: ir.Layout, sigma_a: float, sigma_alpha: float) -> list:
    """The prior's two blocks: position second differences (linear, exact J) and rotation
    second differences (J by central differences over the three controls' left
    perturbations), each over its 1-sigma."""
    sp_ = state.spline
    n, dt2 = len(sp_.p), sp_.dt ** 2
    k = np.arange(1, n - 1)
    a, al = knot_accelerations(sp_)
    Jp = np.zeros((n - 2, 3, 9))
    for j, w in enumerate((1.0, -2.0, 1.0)):
        Jp[:, :, 3 * j:3 * j + 3] = w * np.eye(3) / (dt2 * sigma_a)
    ctrl = (k[:, None] + np.arange(-1, 2))[:, :, None] * 3 + np.arange(3)  # (N-2, 3, 3)
    cols_p = (lay.pos + ctrl).reshape(n - 2, 9)
    cols_r = (lay.rot + ctrl).reshape(n - 2, 9)
    R3 = np.stack([sp_.R[:-2], sp_.R[1:-1], sp_.R[2:]], axis=1)

    def rot_second(R3_: np.ndarray) -> np.ndarray:
        p1 = geo.rotvecs_from_R(np.swapaxes(R3_[:, 0], 1, 2) @ R3_[:, 1])
        p2 = geo.rotvecs_from_R(np.swapaxes(R3_[:, 1], 1, 2) @ R3_[:, 2])
        return (p2 - p1) / (dt2 * sigma_alpha)

    Jr = np.zeros((n - 2, 3, 9))
    for j in range(3):
        for axis in range(3):
            d = np.zeros((n - 2, 3))
            d[:, axis] = ir.STEP
            plus, minus = R3.copy(), R3.copy()
            plus[:, j] = geo.R_from_rotvec(d) @ R3[:, j]
            minus[:, j] = geo.R_from_rotvec(-d) @ R3[:, j]
            Jr[:, :, 3 * j + axis] = (rot_second(plus) - rot_second(minus)) / (2 * ir.STEP)
    return [ir.Block(a / sigma_a, Jp, cols_p), ir.Block(al / sigma_alpha, Jr, cols_r)]


def _hold(block: ir.Block, cols: np.ndarray) -> ir.Block:
    """The block with the given global columns held (-1): the reference camera's pose and offset."""
    c = block.cols.copy()
    c[np.isin(c, cols)] = -1
    return replace(block, cols=c)


def _blocks(state, lay, obs, models, sigma_px, ref_cols, prior) -> list:
    corners = _hold(ir.reprojection_rows(state, lay, obs, models, sigma_px), ref_cols)
    return [corners, *smoothness_blocks(state, lay, *prior)]


def sigmas_of(state: ir.State, lay: ir.Layout, obs, models, sigma_px, ref_cols, prior
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """(C, 7) 1-sigma of each camera's rotation, position and offset, and (C, 4) of fx fy cx
    cy when estimated: (J^T J)^-1 at the solution (step.linear_sigmas)."""
    from rigcal.imucal.step import linear_sigmas

    J, _ = ir.assemble(ir.normal_rows(_blocks(state, lay, obs, models, sigma_px, ref_cols, prior)), lay.size)
    C = lay.n_cam
    cols = np.concatenate([lay.cam + np.arange(6 * C), lay.offset + np.arange(C)])
    rows = [np.eye(lay.size)[cols]]
    if lay.n_intr and "intrinsics" not in lay.held:
        for c, intr in enumerate(state.intrinsics):
            E = intr.basis()[:4]
            A = np.zeros((4, lay.size))
            A[:, lay.intr_start(c):lay.intr_start(c) + E.shape[1]] = E
            rows.append(A)
    sd = linear_sigmas(J, np.concatenate(rows), lay)
    pose = np.column_stack([sd[:6 * C].reshape(C, 6), sd[6 * C:7 * C]])
    intr = sd[7 * C:].reshape(C, 4) if len(sd) > 7 * C else None
    return pose, intr


def reference_camera(cal, views: Views, reference: str) -> int:
    """The camera whose pose and clock are held: the --reference camera, else the one with
    the most corners."""
    if reference.startswith("camera:"):
        return cal.cam_names.index(reference.split(":", 1)[1])
    return int(np.argmax(np.bincount(views.corners.cam, minlength=len(cal.cam_names))))


@dataclass(frozen=True, eq=False)
class _Problem:
    """What every knot spacing's estimate shares: the corners, camera models, the reference
    camera g, start poses, offsets, intrinsics and board poses, and the held groups."""

    obs: ir.Corners
    models: list
    g: int
    T_body_cam: np.ndarray
    offsets: np.ndarray
    line_delay: np.ndarray
    T_world_board: np.ndarray
    intrinsics: tuple
    held: frozenset


def _fit(pr: _Problem, spline, sigma_px: float, passes: int = 1):
    """(state, layout, blocks, iterations, sigma_px, prior, reference columns) of the
    estimate on a start spline: one pass at sigma_px, or (passes=2) a second with the
    corners weighted by the noise the first measured."""
    prior = prior_sigmas(spline)
    state = ir.State(spline=spline, T_body_imu=np.eye(4), T_body_cam=pr.T_body_cam.copy(),
                     time_offset_s=pr.offsets.copy(), line_delay_s=pr.line_delay.copy(), bias_t0=spline.t0,
                     bias_dt=spline.t_end - spline.t0, gyro_bias=np.zeros((2, 3)), accel_bias=np.zeros((2, 3)),
                     R_grav=np.eye(3), T_world_board=pr.T_world_board.copy(), intrinsics=pr.intrinsics)
    lay = ir.layout_for(state, pr.held)
    ref_cols = np.r_[lay.cam + 6 * pr.g + np.arange(6), lay.offset + pr.g]
    iters, blocks = 0, None
    for _ in range(passes):
        if blocks is not None:  # the noise the pass before measured
            sigma_px *= max(blocks[0].residual_rms, 1e-3)
        state, blocks, it = ic.levenberg_marquardt(
            state, lay, lambda s, w=sigma_px: _blocks(s, lay, pr.obs, pr.models, w, ref_cols, prior), MAX_ITER,
            ic.ESTIMATE_COST_TOL)
        iters += it
    return state, lay, blocks, iters, sigma_px, prior, ref_cols


def choose_knots(cal, views: Views, image_t_ns, pr: _Problem, base_dt: float) -> tuple[float, tuple]:
    """(knot spacing, ((dt, corner RMS px), ...) tried): base_dt (the slowest camera's
    frame period), then each finer KNOT_FRACTIONS of it while the views number at least
    MIN_VIEWS_PER_FINER_KNOT per knot, kept while it lowers the corner RMS of a first pass
    to KNOT_MIN_GAIN of the coarser one's or below. Smooth motion keeps the frame period
    (a finer spacing only frees the trajectory against the clock offsets: on a simulated
    recording a third of it left offsets 0.2 ms off, against 0.002 ms); fast hand-held
    motion does not fit it (EuRoC's stereo pair made free-running at 10 Hz each: corner
    RMS 0.46 px at 100 ms, 0.25 px at 50 ms)."""
    span = float(views.image_t.max() - views.image_t.min())
    tried, best = [], base_dt
    for frac in KNOT_FRACTIONS:
        dt = base_dt * frac
        if frac < 1.0 and (len(views.image_t) / max(span / dt, 1.0) < MIN_VIEWS_PER_FINER_KNOT
                           or dt < KNOT_LIMITS_S[0]):
            break
        blocks = _fit(pr, start_trajectory(cal, views, image_t_ns, dt), SIGMA_PX)[2]
        rms = blocks[0].residual_rms * SIGMA_PX
        if tried and rms > KNOT_MIN_GAIN * tried[-1][1]:
            tried.append((dt, rms))
            break
        tried.append((dt, rms))
        best = dt
    return best, tuple(tried)


def _formal_dict(sigma: np.ndarray, sigma_intr: np.ndarray | None) -> dict:
    """sigmas_of's arrays in imucal.step.parameter_sigmas' form (what subset_sigmas takes)."""
    from rigcal.imucal.step import INTRINSIC_KEYS

    return {"pose": sigma[:, :6].copy(), "offset": sigma[:, 6].copy(), "line_delay": None,
            "intrinsics": None if sigma_intr is None else [dict(zip(INTRINSIC_KEYS, map(float, row)))
                                                          for row in sigma_intr]}


def subset_check(state: ir.State, pr: _Problem, prior: tuple, sigma_px: float, sigma: np.ndarray,
                 sigma_intr: np.ndarray | None):
    """The camera-IMU step's check of its formal sigmas (imucal.step.subset_check), on this
    estimate: the estimate repeated on each half of the recording in time (its corners, the
    trajectory windowed to them, imucal.step.state_window), each from the whole recording's
    solution and stopped early (step.SUBSET_MAX_ITER, SUBSET_COST_TOL), and the sigmas the
    halves' differences support (step.subset_sigmas: the larger of the formal one and
    |difference| / 2, a group scaled where the halves disagree beyond its formal sigmas).
    Cameras seen by fewer than step.MIN_SUBSET_CORNERS corners in a half, and the reference
    camera (held), are not compared. Returns a step.SubsetCheck, or None when a half cannot
    be estimated."""
    from concurrent.futures import ThreadPoolExecutor

    from rigcal.imucal import step

    t0 = time.perf_counter()
    C = len(pr.models)
    t = ir.corner_times(state, pr.obs)
    lo, hi = float(t.min()), float(t.max())
    mid = 0.5 * (lo + hi)
    dt = state.spline.dt

    def half(span):
        keep = np.flatnonzero((t >= span[0]) & (t < span[1]))
        obs = pr.obs.subset(keep)
        part = step.state_window(state, max(span[0] - dt, state.spline.t0), min(span[1] + dt, state.spline.t_end))
        lay = ir.layout_for(part, pr.held)
        ref = np.r_[lay.cam + 6 * pr.g + np.arange(6), lay.offset + pr.g]
        try:
            st, _, _ = ic.levenberg_marquardt(
                part, lay, lambda s: _blocks(s, lay, obs, pr.models, sigma_px, ref, prior), step.SUBSET_MAX_ITER,
                step.SUBSET_COST_TOL, lam0=ic.WARM_LAMBDA)
        except (CalibrationError, ValueError, np.linalg.LinAlgError):
            return None
        return st, np.bincount(obs.cam, minlength=C)

    with ThreadPoolExecutor(max_workers=2) as ex:
        halves = list(ex.map(half, ((lo - 1.0, mid), (mid, hi + 1.0))))
    if any(h is None for h in halves):
        return None
    compared = (halves[0][1] >= step.MIN_SUBSET_CORNERS) & (halves[1][1] >= step.MIN_SUBSET_CORNERS)
    compared[pr.g] = False
    if not compared.any():
        return None
    formal = _formal_dict(sigma, sigma_intr)
    diffs = step.halves_differences(halves[0][0], halves[1][0], False, sigma_intr is not None)
    reported, factor = step.subset_sigmas(formal, diffs, compared)
    return step.SubsetCheck(*diffs, compared, formal, reported, factor, time.perf_counter() - t0, mid)


def calibrate_visual_motion(cal, image_t_ns, reference: str = "aligned", hold_intrinsics: bool = False,
                            offsets_declared: dict | None = None, subsets: bool = True,
                            free_intrinsics_structure: bool = True) -> VisualMotionResult:
    """The continuous-time estimate after the camera-only calibration `cal` of time-grouped
    images (image_t_ns: camera -> frame -> the image's own stem, ns), its formal sigmas
    checked on the recording's halves (subset_check; `subsets` False: formal only). Estimated
    intrinsics have fx, fy, cx, cy free (free_intrinsics_structure; False keeps the start's
    structure: a --intrinsics the user chose). Raises CalibrationError with one line where
    the views cannot model the motion."""
    from rigcal.imucal.step import free_structure

    t0 = time.perf_counter()
    names = list(cal.cam_names)
    views = views_of(cal, image_t_ns)
    base = knot_spacing(views, len(names))
    check_views(views, names, base)
    g = reference_camera(cal, views, reference)
    declared = offsets_declared or {}
    pr = _Problem(views.corners, [cal.rig.camera(n).intrinsics for n in names], g,
                  np.stack([cal.rig.camera(n).T_body_cam for n in names]),
                  np.array([declared.get(n, 0.0) - declared.get(names[g], 0.0) for n in names]),
                  np.array([cal.rig.camera(n).line_delay_s or 0.0 for n in names]), cal.state.T_world_board.copy(),
                  tuple(cal.state.intrinsics) if hold_intrinsics or not free_intrinsics_structure
                  else free_structure(cal.state.intrinsics),
                  HELD | ({"intrinsics"} if hold_intrinsics else set()))
    dt, tried = choose_knots(cal, views, image_t_ns, pr, base)
    state, lay, blocks, iters, sigma_px, prior, ref_cols = _fit(pr, start_trajectory(cal, views, image_t_ns, dt),
                                                                SIGMA_PX, passes=2)
    sigma, sigma_intr = sigmas_of(state, lay, pr.obs, pr.models, sigma_px, ref_cols, prior)
    bad = [n for c, n in enumerate(names) if c != g and not sigma[c, 6] <= MAX_OFFSET_SIGMA_KNOTS * dt]
    if bad:
        raise CalibrationError(
            f"camera {bad[0]}: its clock offset to {names[g]} is not determined by the views (1-sigma "
            f"{1000 * sigma[names.index(bad[0]), 6]:.1f} ms, more than {MAX_OFFSET_SIGMA_KNOTS:g} of the "
            f"{1000 * dt:.0f} ms knot spacing): without an IMU the rig must move while both cameras see the boards")
    rms_px = blocks[0].residual_rms * sigma_px
    sigma_intr = None if hold_intrinsics else sigma_intr
    formal = sigma
    check = subset_check(state, pr, prior, sigma_px, sigma, sigma_intr) if subsets else None
    if check is not None:
        from rigcal.imucal.step import INTRINSIC_KEYS

        sigma = np.column_stack([check.sigma["pose"], check.sigma["offset"]])
        if sigma_intr is not None:
            sigma_intr = np.array([[i[k] for k in INTRINSIC_KEYS] for i in check.sigma["intrinsics"]])
    return VisualMotionResult(state.T_body_cam.copy(), state.time_offset_s.copy(), sigma,
                              () if hold_intrinsics else tuple(state.intrinsics), sigma_intr, g, dt, prior,
                              float(rms_px), sigma_px, iters, time.perf_counter() - t0, state, tried, check, formal,
                              views.image_t + state.time_offset_s[views.image_cam], views.image_cam.copy())
