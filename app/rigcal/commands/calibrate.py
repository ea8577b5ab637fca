"""`rigcal calibrate`: dataset folder in, calibrated rig YAML (and optional HTML report) out.

The command: reads and checks the dataset, detects the boards (detect.py), runs the
calibration pipeline (pipeline.calibrate_views) and writes what outputs.py and report.py make.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

from rich.console import Console, Group

from rigcal.errors import CalibrationError, DatasetError, InputError, OutputError, TargetFileError
from rigcal.core.io import atomic_write_texts, output_target
from rigcal.core.observations import BoardView
from rigcal.core.rig import Rig, dump_rig, load_rig

if TYPE_CHECKING:  # annotations only: detection, the camera pipeline (cv2), the camera-IMU step (scipy.stats)
    # and the dataset readers load when run() needs them, so an imu/ + mag/ dataset never imports them
    from rigcal.imucal.step import Options
    from rigcal.data.dataset import DatasetImages
    from rigcal.detect.detect import DetectionResult
    from rigcal.data.imu_csv import MotionCheck
    from rigcal.core.target import Target


def _err() -> Console:
    return Console(stderr=True, highlight=False, soft_wrap=True)


def check_output_path(path: Path) -> None:
    """Fail before the long work when the output can never be written."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; expected a file path for the calibrated rig YAML")
    path = output_target(path)
    parent = path.parent if str(path.parent) else Path(".")
    probe = parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{path}: cannot write here ({probe} is a file, not a directory)")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: cannot write here (directory {probe} is not writable)")


def _diagnosis(paths: list[Path], target) -> str:
    """': <why no board shows>' from the first few of these images (detect_diagnose.diagnose_no_detection), or ''."""
    from rigcal.detect.diagnose import diagnose_no_detection

    hint = diagnose_no_detection(paths[:4], target) if paths else ""
    return f": {hint}" if hint else ""


def _corner_views(images, target, console, renamed=None) -> tuple[list[BoardView], object]:
    """Views of the cameras given as corners/<camera>.csv, and the dataset's images without
    those cameras' (the corners are used instead, and calibrate says so). renamed: camera ->
    csv frame -> frame, where free-running cameras' frames were grouped by time."""
    from types import MappingProxyType

    from rigcal.data.corners import read_corners

    views = []
    for cam, path in images.corners.items():
        got = read_corners(path, target)
        names = (renamed or {}).get(cam, {})
        views += [BoardView(cam, names.get(frame, frame), board, ids, uv, False, None) for frame, board, ids, uv in got]
        both = f"; its {len(images.frames[cam])} images in images/{cam}/ are not used" if images.frames[cam] else ""
        console.print(f"{cam}: {len(got)} board views from {path} (corners detected elsewhere){both}")
    if not images.corners:
        return views, images
    frames = {c: (MappingProxyType({}) if c in images.corners else f) for c, f in images.frames.items()}
    return views, replace(images, frames=MappingProxyType(frames))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


@dataclass(frozen=True)
class CalibrateOptions:
    """Every option of `rigcal calibrate`, each named as its command-line flag
    (--fix-intrinsics -> fix_intrinsics); the defaults are the command's."""

    # inputs and outputs
    rig: Path | None = None  # the declared rig (default DATASET/rig.yaml)
    target: Path | None = None  # the target (default DATASET/target.yaml)
    report: Path | None = None  # the HTML report to write
    # the camera model
    reference: str | None = None  # aligned | camera:NAME | imu:NAME (None: imucal.step.plan's default)
    distortion: str = "auto"
    intrinsics: str = "auto"
    fix_intrinsics: bool = False
    allow_resize: bool = False
    # detection and execution
    guided: str = "auto"
    jobs: int | None = None
    scheduler: str | None = None
    # the camera-IMU step
    camera_only: bool = False
    gravity: float | None = None
    offset_window: float | None = None
    rolling_shutter: bool = False
    knot_spacing: float | None = None
    imu_model: str = "auto"
    imu_intrinsics: str = "auto"

    def imu_step(self, imu: str, intrinsics_from_rig: bool = False) -> Options:
        """The camera-IMU step's options against `imu` (--fix-intrinsics holds the declared
        intrinsics there too)."""
        from rigcal.imucal.step import Options

        return Options(imu, gravity=self.gravity, offset_window=self.offset_window,
                       rolling_shutter=True if self.rolling_shutter else None, knot_spacing=self.knot_spacing,
                       imu_model=self.imu_model, imu_intrinsics="held" if self.fix_intrinsics else self.imu_intrinsics,
                       intrinsics_from_rig=intrinsics_from_rig)


def run(dataset: Path, out_path: Path, options: CalibrateOptions = CalibrateOptions()):
    """`rigcal calibrate`: check the arguments, read and detect the dataset, calibrate
    (pipeline.calibrate_views, then the camera-IMU step on a motion dataset with an IMU
    unless camera_only), write the rig (and report) atomically, print warnings and notes;
    returns the console summary."""
    t0 = time.perf_counter()
    dataset, o = Path(dataset), options
    from rigcal.commands import calibrate_mag

    if calibrate_mag.mag_only_dataset(dataset):  # imu/ + mag/, no images: magnetometers only
        _check_arguments(dataset, out_path, o.report, o.jobs)
        return calibrate_mag.run_mag_only(dataset, out_path, o.rig, o.report, _err(), check_output_path)
    from rigcal.camcal.pipeline import calibrate_views
    from rigcal.results.outputs import calibrated_rig, console_summary, warnings_for

    imu_options = o.imu_step("")  # the IMU options' values checked before any work
    # --camera-only does not use the IMU: its overlap with the images is not checked
    inp = _read_inputs(dataset, out_path, o.report, o.rig, o.target, o.jobs, None if o.camera_only else imu_options)
    imu_name, reference, plan_notes = _imu_plan(inp, o.reference, o.camera_only)
    # free-running cameras and no IMU used: the camera-only answer would carry the motion between
    # the cameras' instants; the views alone shape a continuous-time trajectory (imucal.visual_motion)
    free_running = imu_name is None and inp.motion.frame_t_ns is not None
    fix_intrinsics = o.fix_intrinsics
    if free_running:
        from rigcal.imucal.step import resolve_intrinsics

        fix_intrinsics = fix_intrinsics or resolve_intrinsics("auto", inp.rig)[1]
    if imu_name is not None:  # --imu-intrinsics auto: a declared camera calibration's intrinsics are held
        from rigcal.imucal.step import resolve_intrinsics

        choice, from_rig = resolve_intrinsics(imu_options.imu_intrinsics, inp.rig)
        imu_options = replace(imu_options, imu=imu_name, imu_intrinsics=choice, intrinsics_from_rig=from_rig)
        if from_rig:
            fix_intrinsics = True  # the camera-only step keeps the declared calibration's intrinsics
            plan_notes.append("the declared rig is a camera calibration (its cameras carry calibration sigmas): its "
                              "intrinsics and distortion are " + (
                                  "held in both steps (--imu-intrinsics joint re-estimates them from this recording)"
                                  if choice == "held" else "held in the camera-only step and the camera-IMU step's "
                                                           "prior"))
    console = _err()
    found = _detect_views(inp, o.jobs, o.scheduler, o.allow_resize, fix_intrinsics, console)
    console.print(f"calibrating {len(found.rig.names)} cameras from {len(found.views)} board views ...")
    from rigcal.detect.guided import guided_cameras, rerefiner

    rerefine = rerefiner(found.images, found.rig, inp.target, jobs=o.jobs or os.cpu_count() or 1, mode=o.guided,
                         scheduler=o.scheduler)
    for cam in guided_cameras(found.rig, o.guided):
        if cam in found.images.corners:
            console.print(f"note: {cam}: the guided pass needs images; its corners from "
                          f"{found.images.corners[cam]} stand")
    cal = calibrate_views(found.views, found.rig, {b.name: b.corners for b in inp.target.boards},
                          distortion=o.distortion, fix_intrinsics=fix_intrinsics,
                          reference="aligned" if reference.startswith("imu:") else reference, rerefine=rerefine,
                          intrinsics=o.intrinsics, faces={b.name: b.print_face for b in inp.target.boards},
                          # the camera-IMU step re-estimates the intrinsics: these are its start only
                          imu_start=imu_name is not None and imu_options.imu_intrinsics in ("joint", "prior"))
    from rigcal.camcal.stereo_checks import stereo_checks

    pairs = stereo_checks(cal, dataset_truth=dataset / "truth.yaml")
    out_rig = calibrated_rig(cal, pairs, dataset=str(dataset))
    imu_res = None
    if free_running:
        from rigcal.imucal.visual_motion import calibrate_visual_motion
        from rigcal.results.visual_outputs import subsets_note, summary_note, visual_motion_rig

        vm = calibrate_visual_motion(cal, inp.motion.frame_t_ns, cal.reference, fix_intrinsics,
                                     {c.name: c.time_offset_s or 0.0 for c in inp.rig.cameras},
                                     free_intrinsics_structure=o.intrinsics == "auto")
        out_rig = visual_motion_rig(out_rig, cal, vm)
        plan_notes += [summary_note(list(cal.cam_names), vm), subsets_note(list(cal.cam_names), vm)]
    if imu_name is not None:
        from rigcal.commands.calibrate_imu import calibrate_with_imu

        imu_res, out_rig = calibrate_with_imu(cal, out_rig, inp.motion, reference, inp.target, imu_options)
    before_mag = out_rig
    out_rig, mag_tables, mag_step = calibrate_mag.with_magnetometers(out_rig, dataset, inp.motion.imus, console)
    timings = dict(cal.timings, detection_s=found.det.seconds, total_s=time.perf_counter() - t0)
    _write_outputs(out_path, o.report, out_rig, cal, found.det, pairs, timings,
                   imu=None if imu_res is None else (imu_res, inp.motion.imus[imu_name]),
                   mag=None if mag_step is None or not mag_step.results else (mag_step, before_mag),
                   visual=(vm, list(cal.cam_names)) if free_running else None)
    start_warnings = warnings_for(cal)
    if free_running:  # the written poses' sigmas are the continuous-time estimate's, not the start's
        from rigcal.results.visual_outputs import is_start_pose_warning, pose_warnings

        start_warnings = ([w for w in start_warnings if not is_start_pose_warning(w)]
                          + pose_warnings(list(cal.cam_names), vm))
    imu_warnings, imu_notes = (list(imu_res.warnings), list(imu_res.notes)) if imu_res else ([], [])
    for w in found.warnings + start_warnings + imu_warnings:
        console.print(f"warning: {w}")
    for n in list(cal.notes) + list(inp.motion_notes) + plan_notes + imu_notes:
        console.print(f"note: {n}")
    summary = console_summary(cal, out_rig, found.det, timings, out_path, o.report)
    if free_running:
        from rigcal.results.visual_outputs import console_table

        summary = Group(summary, console_table(out_rig, vm, list(cal.cam_names)))
    if imu_res is None:
        return Group(summary, *mag_tables) if mag_tables else summary
    from rigcal.results.imu_outputs import console_tables

    return Group(summary, *console_tables(out_rig, imu_res), *mag_tables)


@dataclass(frozen=True)
class _Inputs:
    """What `rigcal calibrate` reads and checks before detection: the declared rig, the
    target and its file, the dataset's images (dataset.list_dataset) and the motion check
    (motion.check_motion_dataset, its IMU samples) with what to tell the user about it."""

    rig: Rig
    target: Target
    target_file: Path
    images: DatasetImages
    motion: MotionCheck
    motion_notes: tuple[str, ...]
    # corners/<camera>.csv cameras grouped by time with the others: camera -> csv frame -> frame
    corner_frames: Mapping[str, Mapping[str, str]] | None = None


def _read_inputs(dataset: Path, out_path: Path, report_path: Path | None, rig_path: Path | None,
                 target_path: Path | None, jobs: int | None, imu_options: Options | None = None) -> _Inputs:
    """The arguments checked, then the rig, target, images and IMU files read and checked
    (one clear error on bad input, before any detection). A motion dataset's cameras that
    do not share stems (free-running, mixed rates) get their images grouped by time into
    shared frames for the camera-only start (dataset.associate_by_time); the motion check
    then carries every image's own time (MotionCheck.frame_t_ns) to the camera-IMU step."""
    from rigcal.data.dataset import (associate_by_time, check_shared_stems, dataset_rig_path, dataset_target_path,
                                     list_dataset)
    from rigcal.core.target import load_target

    _check_arguments(dataset, out_path, report_path, jobs)
    rig = load_rig(dataset_rig_path(dataset, rig_path))
    target_file = dataset_target_path(dataset, target_path)
    for written in (out_path, report_path):
        if written is not None and _same_file(written, target_file):
            raise OutputError(f"{written}: is the target file this calibration reads; write the output elsewhere")
    target = load_target(target_file)
    _refuse_square_chessboard(target, rig, target_file)
    images = list_dataset(dataset, rig)
    motion_notes, motion = _motion_notes(dataset, rig, images, _min_overlap_s(imu_options))
    corner_stems = _corner_stems(images)
    if not motion.imus:
        try:
            check_shared_stems(images)
            if not _integer_stems(images, corner_stems) or not _lone(images, corner_stems):
                return _Inputs(rig, target, target_file, images, motion, tuple(motion_notes))
        except DatasetError:
            if not _integer_stems(images, corner_stems):
                raise  # files named per camera, not free-running cameras
    assoc = associate_by_time(images, corner_stems=corner_stems)
    check_shared_stems(assoc.images, assoc.tolerance_ns)
    if assoc.renamed:
        n = sum(len(f) for f in assoc.images.frames.values()) + sum(len(f) for f in assoc.corner_frames.values())
        motion_notes.append(f"the cameras do not share stems (free-running or mixed rates): for the camera-only start "
                            f"their {n} images are grouped into {assoc.shared_frames} frames shared by two cameras or "
                            f"more (taken within {assoc.tolerance_ns * 1e-6:.1f} ms); the "
                            f"{'camera-IMU' if imu_options is not None and motion.imus else 'continuous-time'} step "
                            f"places every image at its own time")
        motion = replace(motion, frame_t_ns=assoc.image_t_ns)
        images = assoc.images
        return _Inputs(rig, target, target_file, images, motion, tuple(motion_notes), assoc.corner_frames)
    return _Inputs(rig, target, target_file, images, motion, tuple(motion_notes))


def _corner_stems(images) -> dict[str, list[str]]:
    """The frames of each camera given as corners/<camera>.csv (their first column)."""
    from rigcal.data.imu_csv import corner_frame_stems

    return {c: list(corner_frame_stems(p)) for c, p in images.corners.items()}


def _lone(images, corner_stems: dict[str, list[str]]) -> bool:
    """Whether a camera given as a corners file shares no frame with any other camera (the
    image cameras' stems are check_shared_stems')."""
    stems = {c: set(f) for c, f in images.frames.items() if c not in images.corners}
    stems.update({c: set(f) for c, f in corner_stems.items()})
    return any(not any(stems[c] & stems[o] for o in stems if o != c) for c in corner_stems) and len(stems) > 1


def _integer_stems(images, corner_stems: dict[str, list[str]] | None = None) -> bool:
    """Every image's stem (and every corners file's frame) an integer (a capture time in ns)
    and every camera's images within another camera's span: cameras that share no stem are
    then free-running, their images grouped by time (dataset.associate_by_time); otherwise
    check_shared_stems' naming hint stands."""
    frames = {c: f for c, f in images.frames.items() if c not in images.corners and f}
    frames.update({c: f for c, f in (corner_stems or {}).items() if f})
    if not all(s.lstrip("-").isdigit() for f in frames.values() for s in f):
        return False
    span = {c: (min(int(s) for s in f), max(int(s) for s in f)) for c, f in frames.items()}
    return all(any(span[c][0] < span[o][1] and span[o][0] < span[c][1] for o in span if o != c) for c in span)


def _min_overlap_s(imu_options: Options | None) -> float:
    """How long every camera's images must overlap the IMU samples: the camera-IMU step's
    MIN_KNOTS knot spacings (--knot-spacing, else the coarsest spacing it may choose, the
    estimator's default); 0 when the IMU is not used (None)."""
    if imu_options is None:
        return 0.0
    from rigcal.imucal.estimator import Settings
    from rigcal.imucal.step import MIN_KNOTS

    return MIN_KNOTS * (imu_options.knot_spacing or Settings().knot_dt)


def _imu_plan(inp: _Inputs, reference: str | None, camera_only: bool) -> tuple[str | None, str, list[str]]:
    """(the IMU to calibrate against or None, the output reference, notes): calibrate_imu.plan
    with what it means for the user."""
    from rigcal.imucal.step import plan

    imu_name, reference = plan(inp.rig, dict(inp.motion.imus), reference, camera_only)
    notes = []
    if camera_only and inp.motion.imus:
        notes.append("--camera-only: the IMU data are not used; the IMU blocks are carried through "
                     f"unchanged and the reference is `{reference}`")
    if imu_name is not None:
        notes.append(f"camera-IMU calibration against {imu_name} after the camera-only one; reference {reference}")
    return imu_name, reference, notes


@dataclass(frozen=True)
class _Detected:
    """Every board view of the dataset (detected, then those of corners/<camera>.csv), the
    detection's record, the rig with its image sizes applied (--allow-resize), the images
    detection read, and warnings for boards never seen or of a spacing too narrow."""

    views: list[BoardView]
    det: DetectionResult
    rig: Rig
    images: DatasetImages
    warnings: list[str]


def _detect_views(inp: _Inputs, jobs: int | None, scheduler: str | None, allow_resize: bool, fix_intrinsics: bool,
                  console: Console) -> _Detected:
    """Detection over the dataset's images (detect.detect_dataset), plus the cameras given as
    corner files; refuses cameras with (almost) no board (_check_detections)."""
    from rigcal.detect.detect import detect_dataset

    given, images = _corner_views(inp.images, inp.target, console, inp.corner_frames)
    det = detect_dataset(images, inp.target, rig=inp.rig, jobs=jobs, progress=True, scheduler=scheduler)
    for path, reason in det.unreadable:
        console.print(f"warning: {path}: skipped ({reason})")
    rig = _apply_image_sizes(inp.rig, det, allow_resize)
    views = list(det.views) + given
    unseen = _check_detections(rig, det, views, images, inp.target, inp.target_file, fix_intrinsics)
    from rigcal.detect.april import spacing_warnings

    return _Detected(views, det, rig, images, spacing_warnings(inp.target.boards) + unseen)


def _write_outputs(out_path: Path, report_path: Path | None, out_rig: Rig, cal, det, pairs: dict,
                   timings: dict, imu: tuple | None = None, mag: tuple | None = None, visual: tuple | None = None
                   ) -> None:
    """The calibrated rig YAML and the HTML report (when asked for), written together or not
    at all. `imu`: (camera-IMU result, its IMU's samples) for the report's IMU part; `mag`:
    (the magnetometer step, the rig it was given) for its magnetometer part; `visual`: (the
    free-running cameras' continuous-time estimate, camera names) for its part."""
    text = dump_rig(out_rig)
    report_html = None
    if report_path is not None:
        from rigcal.results.report import build_report

        report_html = build_report(cal, out_rig, det, pairs, timings)
        if imu is not None:
            from rigcal.results.report_imu import with_imu_section

            report_html = with_imu_section(report_html, out_rig, *imu)
        if visual is not None:
            from rigcal.results.report_visual import with_visual_section

            report_html = with_visual_section(report_html, out_rig, *visual)
        if mag is not None:
            from rigcal.results.report_mag import with_mag_section

            step, declared = mag
            report_html = with_mag_section(report_html, out_rig, declared, dict(step.results),
                                           {k: v.m for k, v in step.inputs.items()})
    atomic_write_texts([(out_path, text)] + ([(report_path, report_html)] if report_html is not None else []))


def _check_arguments(dataset: Path, out_path: Path, report_path: Path | None, jobs: int | None) -> None:
    """Refuse, before any work, what can never run or be written."""
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs: expected a positive number of processes, got {jobs}")
    if not dataset.is_dir():
        raise DatasetError(f"{dataset}: not a dataset folder (expected rig.yaml, target.yaml, images/<camera>/)")
    check_output_path(out_path)
    if report_path is not None:
        check_output_path(report_path)
        if _same_file(report_path, out_path):
            raise OutputError(f"{report_path}: --report and --out name the same file; give the report its own path")


def _check_detections(rig: Rig, det, views: list[BoardView], images, target, target_file, fix_intrinsics: bool
                      ) -> list[str]:
    """CalibrationError when a camera's images show (almost) no board, with a diagnosis of
    target.yaml; else the warnings for boards of a multi-board target never detected."""
    from rigcal.camcal.pipeline import MIN_FRAMES

    for cam in rig.names:
        n_img = det.n_images.get(cam, 0)
        seen = {v.frame for v in views if v.camera == cam}
        # the images without a board, where the diagnosis looks for what target.yaml got wrong
        blank = [p for f, p in images.frames[cam].items() if f not in seen]
        if n_img and not seen:
            raise CalibrationError(
                f"no board detected in any of {n_img} images of camera {cam}; check target.yaml "
                f"(dictionary, squares, legacy_pattern)" + _diagnosis(blank, target))
        if n_img and len(seen) < MIN_FRAMES and not fix_intrinsics and det.no_board.get(cam, 0) > n_img // 2:
            # mostly nothing found: more often a target.yaml off by one than too few photos
            raise CalibrationError(
                f"{cam}: boards detected in only {len(seen)} frame(s) of {n_img} images; at least {MIN_FRAMES} "
                f"are needed to calibrate its intrinsics; check target.yaml (dictionary, squares, "
                f"inner_corners, legacy_pattern)" + _diagnosis(blank, target)
                + " (or use --fix-intrinsics to keep the declared ones)")
    # With several boards, one that is never found (its ids, squares or layout misdeclared)
    # would just drop out of the room: say so.
    found = {v.board for v in det.views}
    missing = [b.name for b in target.boards if len(target.boards) > 1 and b.name not in found]
    n_img = sum(det.n_images.values())
    if not n_img:
        # corners/<camera>.csv only: nothing was detected here, so the board's declaration is
        # not what to check
        return [f"board {name}: no corners of it in the corners files; declared in {target_file} "
                f"but not seen by any camera" for name in missing]
    return [f"board {name}: never detected in {n_img} images; check its dictionary, "
            f"first_marker_id, squares and legacy_pattern in {target_file}" for name in missing]


def _motion_notes(dataset: Path, rig: Rig, images, min_overlap_s: float = 0.0):
    """the motion-dataset format's checks of a motion dataset (DatasetError on bad input): (notes for the
    user, the MotionCheck with the IMU samples read)."""
    from rigcal.data.imu_csv import check_motion_dataset

    motion = check_motion_dataset(dataset, rig, images, min_overlap_s)
    notes = list(motion.notes)
    if motion.imus:
        n = ", ".join(f"{k} ({len(s.t_ns)} samples)" for k, s in motion.imus.items())
        notes.append(f"imu/ checked: {n}")
    return notes, motion


def _refuse_square_chessboard(target, rig: Rig, target_file) -> None:
    """A chessboard with as many inner corners along x as along y looks the same turned
    by 90 degrees: its corner order could differ between the cameras of one frame by a
    quarter turn, which the 180-degree resolution cannot undo. One camera does not care
    (any order is just another board pose); a rig is refused, as docs/formats.md#dataset allows."""
    if len(rig.cameras) < 2:
        return
    for k, b in enumerate(target.boards):
        if b.type == "chessboard" and b.inner_corners[0] == b.inner_corners[1]:
            nx, ny = b.inner_corners
            raise TargetFileError(
                f"{target_file}: boards[{k}].inner_corners: [{nx}, {ny}] is square, so the board looks the same "
                f"turned by 90 degrees and its corner order cannot be matched between cameras; a rig of "
                f"{len(rig.cameras)} cameras needs a chessboard with different counts along x and y")


def _apply_image_sizes(rig: Rig, det, allow_resize: bool) -> Rig:
    """Refuse images whose size differs from the rig's resolution, or (--allow-resize)
    scale that camera's declared intrinsics to the images."""
    if not det.size_mismatch:
        return rig
    for cam, path, got, expected in det.size_mismatch:
        if tuple(got) == tuple(expected)[::-1]:
            # not a resize: scaling the intrinsics by w and h apart would be nonsense
            raise DatasetError(f"{path}: camera {cam}: image is {got[0]}x{got[1]}, the rig's {expected[0]}x"
                               f"{expected[1]} turned by 90 degrees; rigcal reads the pixels as stored (an EXIF "
                               f"orientation tag is not applied), so declare the resolution as stored")
    if not allow_resize:
        cam, path, got, expected = det.size_mismatch[0]
        more = f" (and {len(det.size_mismatch) - 1} more)" if len(det.size_mismatch) > 1 else ""
        raise DatasetError(f"{path}: camera {cam}: image is {got[0]}x{got[1]} but the rig says "
                           f"{expected[0]}x{expected[1]}{more}; fix resolution in rig.yaml or pass --allow-resize")
    cams = []
    sizes = {}
    for cam, path, got, expected in det.size_mismatch:
        prev = sizes.setdefault(cam, got)
        if prev != got:
            raise DatasetError(f"{path}: camera {cam}: images of two sizes ({prev[0]}x{prev[1]} and {got[0]}x{got[1]})")
    for cam, got in sizes.items():
        # some images at the rig's size and some not: scaling the intrinsics would fit neither
        n_read = det.n_images.get(cam, 0) - det.unreadable_by_camera.get(cam, 0)
        odd = [(path, expected) for c, path, _, expected in det.size_mismatch if c == cam]
        if len(odd) < n_read:
            path, expected = odd[0]
            raise DatasetError(f"{path}: camera {cam}: images of two sizes ({expected[0]}x{expected[1]} as the rig "
                               f"says, and {got[0]}x{got[1]} in {len(odd)} of {n_read}); --allow-resize needs one size")
    for c in rig.cameras:
        if c.name in sizes:
            w, h = sizes[c.name]
            m = c.intrinsics
            sx, sy = w / m.width, h / m.height
            m = m.with_(width=w, height=h, fx=m.fx * sx, fy=m.fy * sy, cx=(m.cx + 0.5) * sx - 0.5,
                        cy=(m.cy + 0.5) * sy - 0.5)
            c = replace(c, intrinsics=m)
        cams.append(c)
    return rig.with_cameras(cams)
