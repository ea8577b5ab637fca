"""`rigcal calibrate`: dataset folder in, calibrated rig YAML (and optional HTML report) out."""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from rich.console import Console, Group
from rich.table import Table

from . import __version__
from .core import MIN_FRAMES, Calibration, ViewIn, calibrate_views
from .errors import CalibrationError, DatasetError, InputError, OutputError, TargetFileError
from .rig import Rig, StereoPair, dump_rig, load_rig
from .io import atomic_write_texts, output_target

SIGMA_WARN_MM = 2.0
SIGMA_WARN_DEG = 0.1
SIGMA_WARN_FOCAL = 0.01  # relative 1-sigma of fx, fy
# 1-sigma of cx, cy as the camera rotation it is (sigma / f): a principal point off by
# sigma turns every ray, and the camera's T_body_cam with it, by that angle. Eight well
# moved views of one board at f = 300 px give 0.13 deg (tests/test_faults.py, degenerate
# motion); caliscope's webcams 0.15-0.44 deg, where the set's principal points and
# caliscope's differ by 10-30 px (README, Real image sets).
SIGMA_WARN_PP_DEG = 0.25
# a board must tilt this much (deg, from facing the camera) for its perspective to
# separate the focal length and principal point from the board's distance and position
GOOD_TILT_DEG = 30.0
REGIONS = ("top left", "top", "top right", "left", "centre", "right", "bottom left", "bottom", "bottom right")
AXES = ("F", "L", "U")
MOTION_HINT = {
    "F": "move the rig (or board) towards and away from the cameras, and tilt the board",
    "L": "move sideways and rotate about the vertical (yaw) more",
    "U": "move up and down and pitch the rig more",
}


# declared vs calibrated rig (declared_disagreements): nominal poses are a few degrees and
# millimetres off; beyond these the declaration (or the target's scale) is wrong
DECLARED_WARN_DEG = 15.0
DECLARED_SCALE_WARN = 1.5  # calibrated / declared camera distances, either way
DECLARED_MIN_DISTANCE_M = 0.01  # pairs closer than this do not measure scale or direction
DECLARED_DIRECTION_WARN_DEG = 60.0  # one camera seen from another (left/right folders swapped: 180)


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
    from .detect_diagnose import diagnose_no_detection

    hint = diagnose_no_detection(paths[:4], target) if paths else ""
    return f": {hint}" if hint else ""


def _corner_views(images, target, console) -> tuple[list[ViewIn], object]:
    """Views of the cameras given as corners/<camera>.csv, and the dataset's images without
    those cameras' (the corners are used instead, and calibrate says so)."""
    from types import MappingProxyType

    from .corners import read_corners

    views = []
    for cam, path in images.corners.items():
        got = read_corners(path, target)
        views += [ViewIn(cam, frame, board, ids, uv, False, None) for frame, board, ids, uv in got]
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


def run(dataset: Path, out_path: Path, rig_path: Path | None = None, target_path: Path | None = None,
        report_path: Path | None = None, jobs: int | None = None, reference: str | None = None,
        distortion: str = "auto", fix_intrinsics: bool = False, allow_resize: bool = False, guided: str = "auto",
        intrinsics: str = "auto", scheduler: str | None = None, imu_options: dict | None = None):
    from .dataset import check_shared_stems, dataset_rig_path, dataset_target_path, list_dataset
    from .detect import detect_dataset
    from .target import load_target

    t0 = time.perf_counter()
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs: expected a positive number of processes, got {jobs}")
    dataset = Path(dataset)
    if not dataset.is_dir():
        raise DatasetError(f"{dataset}: not a dataset folder (expected rig.yaml, target.yaml, images/<camera>/)")
    check_output_path(out_path)
    if report_path is not None:
        check_output_path(report_path)
        if _same_file(report_path, out_path):
            raise OutputError(f"{report_path}: --report and --out name the same file; give the report its own path")
    rig = load_rig(dataset_rig_path(dataset, rig_path))
    target_file = dataset_target_path(dataset, target_path)
    for written in (out_path, report_path):
        if written is not None and _same_file(written, target_file):
            raise OutputError(f"{written}: is the target file this calibration reads; write the output elsewhere")
    target = load_target(target_file)
    _refuse_square_chessboard(target, rig, target_file)
    images = list_dataset(dataset, rig)
    check_shared_stems(images)
    motion_notes, motion = _motion_notes(dataset, rig, images)
    from .calibrate_imu import plan

    imu_name, reference = plan(rig, dict(motion.imus), reference)
    cam_reference = "aligned" if reference.startswith("imu:") else reference
    if imu_name is not None:
        motion_notes.append(f"camera-IMU calibration against {imu_name} after the camera-only one; reference "
                            f"{reference}")
    console = _err()
    given, images = _corner_views(images, target, console)
    det = detect_dataset(images, target, rig=rig, jobs=jobs, progress=True, scheduler=scheduler)
    for path, reason in det.unreadable:
        console.print(f"warning: {path}: skipped ({reason})")
    rig = _apply_image_sizes(rig, det, allow_resize)
    views = [ViewIn(v.camera, v.frame, v.board, np.asarray(v.ids), np.asarray(v.uv, float), v.ambiguous, v.sigma)
             for v in det.views] + given
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
    unseen = [f"board {b.name}: never detected in {sum(det.n_images.values())} images; check its dictionary, "
              f"first_marker_id, squares and legacy_pattern in {target_file}"
              for b in target.boards if len(target.boards) > 1 and b.name not in found]
    corners = {b.name: b.corners for b in target.boards}
    console.print(f"calibrating {len(rig.names)} cameras from {len(views)} board views ...")
    from .guided import guided_cameras, rerefiner

    rerefine = rerefiner(images, rig, target, jobs=jobs or os.cpu_count() or 1, mode=guided, scheduler=scheduler)
    for cam in guided_cameras(rig, guided):
        if cam in images.corners:
            console.print(f"note: {cam}: the guided pass needs images; its corners from {images.corners[cam]} stand")
    cal = calibrate_views(views, rig, corners, distortion=distortion, fix_intrinsics=fix_intrinsics,
                          reference=cam_reference, rerefine=rerefine, intrinsics=intrinsics,
                          faces={b.name: b.print_face for b in target.boards})
    from .checks import stereo_checks

    pairs = stereo_checks(cal, dataset_truth=dataset / "truth.yaml")
    out_rig = calibrated_rig(cal, pairs, dataset=str(dataset))
    imu_res = None
    if imu_name is not None:
        from .imu_outputs import calibrate_with_imu

        imu_res, out_rig = calibrate_with_imu(cal, out_rig, motion, imu_name, reference, target, imu_options or {})
    timings = dict(cal.timings, detection_s=det.seconds, total_s=time.perf_counter() - t0)
    text = dump_rig(out_rig)
    report_html = None
    if report_path is not None:
        from .report import build_report

        report_html = build_report(cal, out_rig, det, pairs, timings)
        if imu_res is not None:
            from .report_imu import with_imu_section

            report_html = with_imu_section(report_html, out_rig, imu_res, motion.imus[imu_name])
    # the rig and its report land together or not at all
    atomic_write_texts([(out_path, text)] + ([(report_path, report_html)] if report_html is not None else []))
    imu_warnings, imu_notes = (list(imu_res.warnings), list(imu_res.notes)) if imu_res else ([], [])
    for w in unseen + warnings_for(cal) + imu_warnings:
        console.print(f"warning: {w}")
    for n in list(cal.notes) + motion_notes + imu_notes:
        console.print(f"note: {n}")
    summary = console_summary(cal, out_rig, det, timings, out_path, report_path)
    if imu_res is None:
        return summary
    from .imu_outputs import console_tables

    return Group(summary, *console_tables(out_rig, imu_res))


def _motion_notes(dataset: Path, rig: Rig, images):
    """imu.md's checks of a motion dataset (DatasetError on bad input): (notes for the
    user, the MotionCheck with the IMU samples read)."""
    from .motion import check_motion_dataset

    motion = check_motion_dataset(dataset, rig, images)
    notes = list(motion.notes)
    if motion.imus:
        n = ", ".join(f"{k} ({len(s.t_ns)} samples)" for k, s in motion.imus.items())
        notes.append(f"imu/ checked: {n}")
    return notes, motion


def _refuse_square_chessboard(target, rig: Rig, target_file) -> None:
    """A chessboard with as many inner corners along x as along y looks the same turned
    by 90 degrees: its corner order could differ between the cameras of one frame by a
    quarter turn, which the 180-degree resolution cannot undo. One camera does not care
    (any order is just another board pose); a rig is refused, as dataset.md allows."""
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


def calibrated_rig(cal: Calibration, pairs: dict, dataset: str) -> Rig:
    """The calibrated rig in the schema of rig-yaml.md, with per camera and rig statistics."""
    cams = []
    for c in cal.rig.cameras:
        st = cal.stats[c.name]
        block = {
            "reprojection_rms_px": _r(st.rms_px, 4),
            "observations": st.observations,
            "frames": st.frames,
            "outliers": st.outliers,
        }
        if st.intrinsics_model is not None:
            block["intrinsics_model"] = dict(st.intrinsics_model)
        if st.sigma_position_mm is not None:
            sig = {"position_mm": [_r(x, 4) for x in st.sigma_position_mm],
                   "rotation_deg": [_r(x, 5) for x in st.sigma_rotation_deg]}
            if st.sigma_intrinsics is not None:
                sig["intrinsics"] = {k: _r(st.sigma_intrinsics[k], 4) for k in ("fx", "fy", "cx", "cy")}
            block["sigma"] = sig
        cams.append(replace(c, calibration=block))
    ref = "aligned-to-declared" if cal.reference == "aligned" else cal.reference
    if cal.reference == "aligned" and not any(c.T_body_cam is not None for c in cal.declared.cameras):
        ref = f"camera:{cal.rig.cameras[0].name}"
    top = {"tool": f"rigcal {__version__}", "dataset": dataset, "reference": ref,
           "reprojection_rms_px": _r(cal.rms_px, 4)}
    stereo = []
    for p in cal.rig.stereo_pairs:
        chk = pairs.get((p.left, p.right))
        if chk is None:
            stereo.append(StereoPair(p.left, p.right))
            continue
        stereo.append(StereoPair(p.left, p.right, baseline_m=_r(chk["baseline_m"], 7),
                                 depth_check=chk.get("depth_check"), sanity_10m=chk.get("sanity_10m")))
    return replace(cal.rig, cameras=tuple(cams), stereo_pairs=tuple(stereo), calibration=top)


def _r(x: float, nd: int) -> float:
    return float(np.round(float(x), nd)) if np.isfinite(x) else float("nan")


def declared_disagreements(cal: Calibration) -> list[str]:
    """Where the calibrated rig contradicts the declared poses beyond nominal error: a
    camera pair whose relative orientation differs by more than DECLARED_WARN_DEG (a
    camera mounted upside down but declared upright), and camera distances scaled by more
    than DECLARED_SCALE_WARN (a wrong square_length). Both otherwise pass silently: the
    aligned body frame is a best fit to the declared poses and spreads the contradiction
    over every camera. Compares camera pairs, so the body-frame choice does not enter."""
    from . import geometry as geo

    declared = getattr(cal, "declared", None)
    if declared is None:
        return []
    posed = [c for c in declared.cameras if c.T_body_cam is not None]
    out, ratios = [], []
    for i, a in enumerate(posed):
        for b in posed[i + 1:]:
            Ta, Tb = cal.rig.camera(a.name).T_body_cam, cal.rig.camera(b.name).T_body_cam
            # calibrated b in declared b's frame, both taken relative to camera a
            R_rel = (a.T_body_cam[:3, :3].T @ b.T_body_cam[:3, :3]).T @ (Ta[:3, :3].T @ Tb[:3, :3])
            r = geo.rotvec_from_R(R_rel)
            angle = float(np.degrees(np.linalg.norm(r)))
            turned = angle > DECLARED_WARN_DEG
            if turned:
                hint = ""
                if angle > 150 and abs(r[2]) > 0.9 * np.linalg.norm(r):
                    hint = (" (about the optical axis: is one of them mounted upside down? Declare it so, e.g. "
                            "look: forward becomes axes: [L, U, F])")
                out.append(f"{a.name}/{b.name}: the calibrated relative orientation is {angle:.0f} deg from the "
                           f"declared one{hint}; the body frame is fitted to the declared poses, so every "
                           f"T_body_cam is off: fix rig.yaml or use --reference camera:NAME")
            d_decl = float(np.linalg.norm(a.T_body_cam[:3, 3] - b.T_body_cam[:3, 3]))
            if d_decl >= DECLARED_MIN_DISTANCE_M:
                ratios.append((float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3])) / d_decl, a.name, b.name, d_decl))
                # where b sits seen from a, in a's camera frame: declared vs calibrated
                t_decl = a.T_body_cam[:3, :3].T @ (b.T_body_cam[:3, 3] - a.T_body_cam[:3, 3])
                t_cal = Ta[:3, :3].T @ (Tb[:3, 3] - Ta[:3, 3])
                cos = float(t_decl @ t_cal) / (np.linalg.norm(t_decl) * np.linalg.norm(t_cal) + 1e-300)
                turn = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
                if turn > DECLARED_DIRECTION_WARN_DEG and not turned:  # a turned camera is named above
                    out.append(f"{a.name}/{b.name}: seen from {a.name}, {b.name} is calibrated {turn:.0f} deg away "
                               f"from where the rig declares it (are the image folders images/{a.name}/ and "
                               f"images/{b.name}/ swapped, or the declared positions?)")
    if ratios:
        k = int(np.argsort([q[0] for q in ratios])[len(ratios) // 2])
        ratio, na, nb, d_decl = ratios[k]
        if not 1 / DECLARED_SCALE_WARN <= ratio <= DECLARED_SCALE_WARN:
            times = f"{ratio:.0f}" if ratio >= 10 else f"{ratio:.2g}"
            out.append(f"the calibrated rig is {times}x the size of the declared one ({na}/{nb}: "
                       f"{ratio * d_decl:.4g} m calibrated, {d_decl:.4g} m declared); check square_length in "
                       f"target.yaml (metres) and the declared positions")
    return out


def warnings_for(cal: Calibration) -> list[str]:
    """Poorly constrained intrinsics and extrinsics: name the parameter or axis and the
    motion that would fix it; and contradictions of the declared rig (declared_disagreements)."""
    out = declared_disagreements(cal)
    for c, (n, st) in enumerate(cal.stats.items()):
        out.extend(intrinsics_warnings(cal, c, n))
        if st.sigma_position_mm is None:
            continue
        for i, s in enumerate(st.sigma_position_mm):
            if s > SIGMA_WARN_MM:
                out.append(f"{n}: position along body {AXES[i]} is poorly constrained (1-sigma {s:.2f} mm > "
                           f"{SIGMA_WARN_MM} mm); {MOTION_HINT[AXES[i]]}")
        for i, s in enumerate(st.sigma_rotation_deg):
            if s > SIGMA_WARN_DEG:
                out.append(f"{n}: rotation about body {AXES[i]} is poorly constrained (1-sigma {s:.3f} deg > "
                           f"{SIGMA_WARN_DEG} deg); rotate the rig about more than one axis and tilt the board")
    return out


def view_coverage(cal: Calibration, c: int) -> tuple[int, int, list[str]]:
    """(how many of camera c's board views tilt GOOD_TILT_DEG or more from facing it, how
    many views it has, the REGIONS of a 3x3 split of its image where none of its inlier
    corners lies): what its views lack."""
    m = cal.inliers & (cal.obs.cam == c)
    if not m.any():
        return 0, 0, list(REGIONS)
    st = cal.state
    fb = np.unique(np.stack([cal.obs.frame[m], cal.obs.board[m]], axis=1), axis=0)
    R = st.T_cam_body[c, :3, :3] @ st.T_body_world[fb[:, 0], :3, :3] @ st.T_world_board[fb[:, 1], :3, :3]
    tilt = np.degrees(np.arccos(np.clip(np.abs(R[:, 2, 2]), 0.0, 1.0)))  # board normal vs optical axis
    cam = cal.rig.camera(cal.cam_names[c]).intrinsics
    uv = cal.obs.uv[m]
    col = np.clip((3 * (uv[:, 0] + 0.5) / cam.width).astype(int), 0, 2)
    row = np.clip((3 * (uv[:, 1] + 0.5) / cam.height).astype(int), 0, 2)
    seen = np.bincount(3 * row + col, minlength=9) > 0
    return int(np.sum(tilt >= GOOD_TILT_DEG)), len(fb), [r for r, s in zip(REGIONS, seen) if not s]


def intrinsics_warnings(cal: Calibration, c: int, name: str) -> list[str]:
    """Camera c's focal length or principal point still poorly determined after the
    structure was chosen (SIGMA_WARN_FOCAL, SIGMA_WARN_PP_DEG): the parameter, its 1-sigma
    and the views that would pin it. A held principal point is judged by its sigma when it
    was free: held because the data could not place it, it may be off by that much."""
    st = cal.stats[name]
    sig = st.sigma_intrinsics or {}
    m = cal.rig.camera(name).intrinsics
    model = st.intrinsics_model or {}
    weak = []  # (kind, line head)
    tied = model.get("focal") == "fx=fy"
    for k in (("fx",) if tied else ("fx", "fy")):
        if k in sig and sig[k] > SIGMA_WARN_FOCAL * m.fx:
            weak.append(("focal", f"focal length {k} is poorly constrained ({'fx = fy tied, ' if tied else ''}"
                                  f"1-sigma {sig[k]:.2f} px = {100 * sig[k] / m.fx:.1f} % > "
                                  f"{100 * SIGMA_WARN_FOCAL:g} %)"))
    held = model.get("principal_point") == "held"
    sig_c = st.sigma_intrinsics_free if held else sig
    if sig_c and "cx" in sig_c:
        deg = float(np.degrees(max(sig_c["cx"], sig_c["cy"]) / m.fx))
        if deg > SIGMA_WARN_PP_DEG:
            what = ("held at the declared centre because the data cannot place it; free, its 1-sigma is" if held
                    else "1-sigma")
            weak.append(("centre", f"principal point is poorly constrained ({what} cx {sig_c['cx']:.1f}, cy "
                                   f"{sig_c['cy']:.1f} px, i.e. {deg:.2f} deg of camera rotation > "
                                   f"{SIGMA_WARN_PP_DEG:g} deg)"))
    if not weak:
        return []
    tilted, views, empty = view_coverage(cal, c)
    out = []
    for kind, head in weak:
        fix = []
        if tilted < max(3, views / 2):
            fix.append(f"the board tilted {GOOD_TILT_DEG:.0f}-50 deg from facing the camera, about both image axes "
                       f"(only {tilted} of its {views} views tilt {GOOD_TILT_DEG:.0f} deg or more)")
        if kind == "focal":
            fix.append("the board at several distances")
        if kind == "centre" and empty:
            fix.append(f"corners in every part of the image (none seen in: {', '.join(empty)})")
        if not fix:
            fix.append("the board tilted and near the image corners")
        out.append(f"{name}: {head}; add views with {'; '.join(fix)}")
    return out


def console_summary(cal: Calibration, out_rig: Rig, det, timings: dict, out_path, report_path):
    cams = Table(title="cameras", show_lines=False)
    for col in ("camera", "model", "intrinsics", "rms px", "obs", "frames", "outliers", "sigma pos mm (F L U)",
                "sigma rot deg (F L U)"):
        cams.add_column(col, justify="right" if col not in ("camera", "model", "intrinsics") else "left")
    for c in out_rig.cameras:
        st = cal.stats[c.name]
        sp = " ".join(f"{x:.3f}" for x in st.sigma_position_mm) if st.sigma_position_mm is not None else "-"
        sr = " ".join(f"{x:.4f}" for x in st.sigma_rotation_deg) if st.sigma_rotation_deg is not None else "-"
        cams.add_row(c.name, st.distortion_model, structure_text(st.intrinsics_model), f"{st.rms_px:.3f}",
                     str(st.observations), str(st.frames), str(st.outliers), sp, sr)
    parts = [det.summary() if hasattr(det, "summary") else "", cams]
    if out_rig.stereo_pairs:
        pt = Table(title="stereo pairs")
        for col in ("pair", "baseline mm", "vert. disparity rms px", "depth err median %", "depth err p95 %",
                    "10 m: disparity px"):
            pt.add_column(col, justify="right" if col != "pair" else "left")
        for p in out_rig.stereo_pairs:
            dc = p.depth_check or {}
            overall = dc.get("overall", {})
            s10 = p.sanity_10m or {}
            pt.add_row(f"{p.left}/{p.right}", f"{1000 * p.baseline_m:.3f}" if p.baseline_m else "-",
                       _fmt(dc.get("vertical_disparity_rms_px"), 4), _fmt(overall.get("median_rel_error_pct"), 3),
                       _fmt(overall.get("p95_rel_error_pct"), 3), _fmt(s10.get("disparity_px"), 3))
        parts.append(pt)
    parts.append(f"reprojection RMS {cal.rms_px:.3f} px over {int(cal.inliers.sum())} corners "
                 f"({int((~cal.inliers).sum())} outliers rejected); reference {out_rig.calibration['reference']}")
    parts.append(f"time: detection {timings.get('detection_s', 0):.1f} s, intrinsics {timings['intrinsics_s']:.1f} s, "
                 f"solve {timings['solve_s']:.1f} s, "
                 + (f"guided pass {timings['guided_s']:.1f} s, " if "guided_s" in timings else "")
                 + f"total {timings['total_s']:.1f} s")
    parts.append(f"wrote {out_path}" + (f" and {report_path}" if report_path else ""))
    return Group(*[p for p in parts if p != ""])


def structure_text(model: dict | None) -> str:
    """'fx=fy, cx,cy held' for the console table (calibration.intrinsics_model)."""
    if not model:
        return "-"
    if model["focal"] == "declared":
        return "declared, held"
    return f"{model['focal']}; cx,cy {model['principal_point']}"


def _fmt(x, nd) -> str:
    return "-" if x is None else f"{x:.{nd}f}"
