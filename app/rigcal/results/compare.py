"""`rigcal compare CALIBRATED TRUTH`: errors of a calibrated rig against truth.

Per camera: intrinsics errors, the projection difference over the whole image (the
same rays through both models), and pose errors in the body frame. Per camera
pair: relative rotation (deg) and translation (mm) errors, which do not depend on
how either file chose its body frame. Per stereo pair: baseline error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.console import Group
from rich.table import Table

from rigcal.core import geometry as geo
from rigcal.errors import InputError, RigFileError
from rigcal.core.rig import Rig, load_rig, load_yaml, rig_file
from rigcal.core.validate import read_text
from rigcal.data.truth import load_truth


def projection_difference_px(est, true, n: int = 25) -> tuple[float, float]:
    """RMS and max pixel distance between two camera models over the image: pixels of a
    grid unprojected through the true model, reprojected through the estimate."""
    u = np.linspace(0, true.width - 1, n)
    v = np.linspace(0, true.height - 1, n)
    uv = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    rays = true.unproject(uv)
    ok = np.all(np.isfinite(rays), axis=1)
    uv2, valid = est.project(rays[ok])
    d = np.linalg.norm(uv2[valid] - uv[ok][valid], axis=1)
    if len(d) == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def compare_rigs(est: Rig, truth: Rig) -> dict:
    """Errors per camera, per camera pair and per stereo pair (plain numbers for tests/bench)."""
    names = [n for n in est.names if n in truth.names]
    cams = {}
    for n in names:
        a, b = est.camera(n), truth.camera(n)
        ma, mb = a.intrinsics, b.intrinsics
        e = {"fx": ma.fx - mb.fx, "fy": ma.fy - mb.fy, "cx": ma.cx - mb.cx, "cy": ma.cy - mb.cy,
             "focal_rel_pct": 100 * 0.5 * ((ma.fx - mb.fx) / mb.fx + (ma.fy - mb.fy) / mb.fy)}
        e["proj_rms_px"], e["proj_max_px"] = projection_difference_px(ma, mb)
        if a.T_body_cam is not None and b.T_body_cam is not None:
            e["rot_deg"] = geo.rotation_angle_deg(a.T_body_cam[:3, :3] @ b.T_body_cam[:3, :3].T)
            e["pos_mm"] = 1000 * float(np.linalg.norm(a.T_body_cam[:3, 3] - b.T_body_cam[:3, 3]))
        cams[n] = e
    # Body frames are a choice (aligned to a declared rig, or one camera); after the best
    # rigid fit of the estimate onto the truth, what is left is the rig's own error.
    posed = [n for n in names if est.camera(n).T_body_cam is not None and truth.camera(n).T_body_cam is not None]
    if posed:
        T_fit = geo.fit_rigid_to(np.array([est.camera(n).T_body_cam for n in posed]),
                             np.array([truth.camera(n).T_body_cam for n in posed]))
        for n in posed:
            Ta = T_fit @ est.camera(n).T_body_cam
            Tb = truth.camera(n).T_body_cam
            cams[n]["rot_fit_deg"] = geo.rotation_angle_deg(Ta[:3, :3] @ Tb[:3, :3].T)
            cams[n]["pos_fit_mm"] = 1000 * float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
    pairs = {}
    for i, p in enumerate(names):
        for q in names[i + 1:]:
            Ta = [est.camera(x).T_body_cam for x in (p, q)]
            Tb = [truth.camera(x).T_body_cam for x in (p, q)]
            if any(T is None for T in Ta + Tb):
                continue
            rel_a = geo.inv_T(Ta[0]) @ Ta[1]
            rel_b = geo.inv_T(Tb[0]) @ Tb[1]
            pairs[(p, q)] = {
                "rot_deg": geo.rotation_angle_deg(rel_a[:3, :3] @ rel_b[:3, :3].T),
                "trans_mm": 1000 * float(np.linalg.norm(rel_a[:3, 3] - rel_b[:3, 3])),
                "distance_m": float(np.linalg.norm(rel_b[:3, 3])),
            }
    stereo = {}
    for sp in est.stereo_pairs:
        k = (sp.left, sp.right)
        if k in pairs or (sp.right, sp.left) in pairs:
            ba = np.linalg.norm(est.camera(sp.left).T_body_cam[:3, 3] - est.camera(sp.right).T_body_cam[:3, 3])
            bb = np.linalg.norm(truth.camera(sp.left).T_body_cam[:3, 3] - truth.camera(sp.right).T_body_cam[:3, 3])
            stereo[k] = {"baseline_m": float(ba), "true_baseline_m": float(bb), "error_mm": 1000 * float(ba - bb)}
    return {"cameras": cams, "pairs": pairs, "stereo": stereo}


def run(calibrated: Path, truth_path: Path):
    est = load_rig(calibrated)
    truth_path = rig_file(truth_path)  # a shipped rig's name gives its file
    truth = load_truth(truth_path).rig
    missing = [n for n in est.names if n not in truth.names]
    if missing:
        raise RigFileError(f"{truth_path}: cameras: {', '.join(missing)} not found (has {', '.join(truth.names)})")
    res = compare_rigs(est, truth)
    t1 = Table(title=f"cameras: {calibrated} vs {truth_path}")
    for col in ("camera", "fx err", "fy err", "cx err", "cy err", "focal %", "proj rms px", "proj max px",
                "rot err deg", "pos err mm", "rot err deg (fit)", "pos err mm (fit)"):
        t1.add_column(col, justify="left" if col == "camera" else "right")
    nan = float("nan")
    for n, e in res["cameras"].items():
        t1.add_row(n, *(f"{e[k]:+.3f}" for k in ("fx", "fy", "cx", "cy")), f"{e['focal_rel_pct']:+.4f}",
                   f"{e['proj_rms_px']:.3f}", f"{e['proj_max_px']:.3f}",
                   f"{e.get('rot_deg', nan):.4f}", f"{e.get('pos_mm', nan):.3f}",
                   f"{e.get('rot_fit_deg', nan):.4f}", f"{e.get('pos_fit_mm', nan):.3f}")
    t1.caption = ("pose errors in each file's own body frame, and after the best rigid fit of the calibrated "
                  "rig onto the truth (what is left is the rig's error, not the body-frame choice)")
    t2 = Table(title="camera pairs (independent of the body frame)")
    for col in ("pair", "distance m", "rel. rotation err deg", "rel. translation err mm"):
        t2.add_column(col, justify="left" if col == "pair" else "right")
    for (p, q), e in res["pairs"].items():
        t2.add_row(f"{p}/{q}", f"{e['distance_m']:.4f}", f"{e['rot_deg']:.4f}", f"{e['trans_mm']:.3f}")
    parts = [t1, t2]
    if res["stereo"]:
        t3 = Table(title="stereo baselines")
        for col in ("pair", "calibrated mm", "true mm", "error mm"):
            t3.add_column(col, justify="left" if col == "pair" else "right")
        for (l, r), e in res["stereo"].items():
            t3.add_row(f"{l}/{r}", f"{1000 * e['baseline_m']:.3f}", f"{1000 * e['true_baseline_m']:.3f}",
                       f"{e['error_mm']:+.3f}")
        parts.append(t3)
    if est.imus and truth.imus:
        from rigcal.results.imu_outputs import compare_imu, compare_tables

        doc = load_yaml(read_text(truth_path, InputError), str(truth_path), InputError)
        parts += compare_tables(compare_imu(est, truth, doc if isinstance(doc, dict) else None, str(truth_path)))
    return Group(*parts)
