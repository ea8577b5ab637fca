"""What a calibration hands back: the calibrated rig in the rig file's schema, warnings, console tables.

Used by `rigcal calibrate` (calibrate.py) and its HTML report (report.py): both read a
pipeline.Calibration and neither imports the other.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from rich.console import Group
from rich.table import Table

from rigcal import __version__
from rigcal.camcal.pipeline import Calibration
from rigcal.core.rig import Rig, StereoPair

SIGMA_WARN_MM = 2.0
SIGMA_WARN_DEG = 0.1
SIGMA_WARN_FOCAL = 0.01  # relative 1-sigma of fx, fy
# 1-sigma of cx, cy as the camera rotation it is (sigma / f): a principal point off by
# sigma turns every ray, and the camera's T_body_cam with it, by that angle. Eight well
# moved views of one board at f = 300 px give 0.13 deg (tests/commands/test_faults.py, degenerate
# motion); caliscope's webcams 0.15-0.44 deg, where the set's principal points and
# caliscope's differ by 10-30 px (docs/accuracy.md, Real image sets).
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


def calibrated_rig(cal: Calibration, pairs: dict, dataset: str) -> Rig:
    """The calibrated rig in the schema of docs/formats.md#rig-yaml, with per camera and rig statistics."""
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
    from rigcal.core import geometry as geo

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
    """The console's closing tables (cameras, stereo pairs) and lines (RMS, time, files written)."""
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
