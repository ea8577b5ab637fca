"""What a camera-IMU calibration writes and prints (docs/formats.md#motion-datasets): the calibrated
rig (every T_body_cam relative to the reference IMU, time_offset_s, line_delay_s, the IMU's
calibration block), the console tables, and `rigcal compare`'s camera-IMU errors.

Units in files: seconds for time_offset_s / line_delay_s, their sigma in ms / us; biases in
rad/s and m/s^2; residual RMS in the same units beside what the declared density predicts
(density * sqrt(update_rate), Kalibr's discrete noise).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from rich.table import Table

from rigcal.core import geometry as geo
from rigcal.imucal import residuals as ir
from rigcal.imucal.step import SCALE_PARAMETERS, ImuCalibration
from rigcal.errors import InputError
from rigcal.core.rig import Rig


def rounded(x: float, nd: int) -> float:
    return float(np.round(float(x), nd))


def body_from_imu(reference: str, imu_name: str, T_imu_cam: np.ndarray, declared: Rig) -> np.ndarray:
    """T_body_imu of the calibrated IMU under the chosen reference: `imu:NAME` keeps the
    declared pose; `camera:NAME` puts that camera at its declared pose; `aligned` fits every
    camera to its declared pose (geometry.fit_rigid_to)."""
    if reference == f"imu:{imu_name}":
        return declared.imu(imu_name).T_body_imu
    names = declared.names
    if reference.startswith("camera:"):
        c = reference.split(":", 1)[1]
        return declared.camera(c).T_body_cam @ geo.inv_T(T_imu_cam[names.index(c)])
    posed = [k for k, c in enumerate(declared.cameras) if c.T_body_cam is not None]
    return geo.fit_rigid_to(T_imu_cam[posed], np.stack([declared.cameras[k].T_body_cam for k in posed]))


def _camera_block(old: dict | None, k: int, res: ImuCalibration, held_sigma: dict | None = None) -> dict:
    block = dict(old or {})
    sig = dict(block.get("sigma", {}))
    pose = res.sigma["pose"][k]
    sig["position_mm"] = [rounded(1000 * x, 4) for x in pose[3:]]
    sig["rotation_deg"] = [rounded(np.degrees(x), 5) for x in pose[:3]]
    sig["time_offset_ms"] = rounded(1000 * res.sigma["offset"][k], 5)
    if res.sigma["line_delay"] is not None:
        sig["line_delay_us"] = rounded(1e6 * res.sigma["line_delay"][k], 5)
    if res.sigma.get("intrinsics") is not None:  # estimated with the rest: their sigma replaces the camera-only one
        sig["intrinsics"] = {key: rounded(res.sigma["intrinsics"][k][key], 4) for key in ("fx", "fy", "cx", "cy")}
    elif held_sigma:  # held at the declared camera calibration: its uncertainty is still theirs
        sig["intrinsics"] = dict(held_sigma)
    block["sigma"] = sig
    # formal: from the solution covariance; subsets: raised to what the recording's halves show
    block["sigma_source"] = res.subsets.source(k) if res.subsets is not None and res.subsets.compared[k] else "formal"
    return block


SCALE_KEYS = ("gyroscope_scale_misalignment", "accelerometer_scale_misalignment")


def _rows(M: np.ndarray, nd: int) -> list:
    return [[rounded(x, nd) for x in row] for row in M]


def model_selection_entry(res: ImuCalibration) -> dict:
    """`imu_model_selection`: the test behind `imu_model` (statistic and threshold), or
    that it was forced."""
    t = res.model_test
    if t is None:
        return {"test": f"none (--imu-model {res.imu_model})"}
    return {"test": "likelihood ratio", "statistic": rounded(t.statistic, 2), "imu_statistic": rounded(t.imu_statistic, 2),
            "threshold": rounded(t.threshold, 2), "parameters": SCALE_PARAMETERS, "level": float(t.level)}


def _model_entries(res: ImuCalibration, block: dict) -> None:
    """The additions to the rig format (docs/formats.md): `imu_model`, `imu_model_selection` and, for the
    scale-misalignment model, M of each sensor (3x3 rows, sensor reads M @ ideal + bias)
    with its 1-sigma (the upper triangle is held at 0)."""
    block["imu_model"] = res.imu_model
    block["imu_model_selection"] = model_selection_entry(res)
    if res.imu_model != "scale-misalignment":
        return
    st = res.result.state
    for k, (key, M) in enumerate(zip(SCALE_KEYS, (st.M_gyro, st.M_accel))):
        block[key] = _rows(M, 7)
        block["sigma"][key] = _rows(ir.lower(res.sigma["scale"][6 * k:6 * k + 6]), 7)


def imu_block(res: ImuCalibration, placed: bool) -> dict:
    """The IMU's `calibration` block (docs/formats.md#motion-datasets, plus the IMU model: _model_entries); `placed`:
    its pose comes from the cameras (it is not the reference), so its sigma is given."""
    n = int(len(res.result.state.gyro_bias))
    block = {
        "gyroscope_bias": [rounded(x, 9) for x in res.gyro_bias],
        "accelerometer_bias": [rounded(x, 7) for x in res.accel_bias],
        "gyroscope_residual_rms": rounded(res.gyro_rms, 9),
        "gyroscope_residual_rms_declared": rounded(res.gyro_predicted, 9),
        "accelerometer_residual_rms": rounded(res.accel_rms, 7),
        "accelerometer_residual_rms_declared": rounded(res.accel_predicted, 7),
        "bias_knots": n,
        "sigma": {"gyroscope_bias": [rounded(x, 9) for x in res.sigma["gyro_bias"]],
                  "accelerometer_bias": [rounded(x, 7) for x in res.sigma["accel_bias"]]},
    }
    if placed:
        # the IMU moves with the chosen body frame: its pose is known as well as the cameras'
        # relative to it, taken here from the reference (or best) camera
        pose = res.sigma["pose"].min(axis=0)
        block["sigma"]["position_mm"] = [rounded(1000 * x, 4) for x in pose[3:]]
        block["sigma"]["rotation_deg"] = [rounded(np.degrees(x), 5) for x in pose[:3]]
    _model_entries(res, block)
    return block


def calibrated_imu_rig(out_rig: Rig, declared: Rig, res: ImuCalibration, reference: str) -> Rig:
    """The camera-only calibrated rig with every T_body_cam from the camera-IMU estimate,
    time offsets (and line delays when estimated), the intrinsics when estimated with them,
    the IMU's calibration block, the stereo baselines from the new poses, and the reference."""
    est = res.result
    T_body_imu = body_from_imu(reference, res.imu.name, est.T_imu_cam, declared)
    names = list(out_rig.names)
    cams = []
    for c in out_rig.cameras:
        k = names.index(c.name)
        delay = float(est.state.line_delay_s[k]) if res.sigma["line_delay"] is not None else c.line_delay_s
        lens = c.intrinsics.with_values(res.intrinsics[k].values) if res.intrinsics else c.intrinsics
        cams.append(replace(c, T_body_cam=T_body_imu @ est.T_imu_cam[k], time_offset_s=float(est.time_offset_s[k]),
                            line_delay_s=delay, intrinsics=lens,
                            calibration=_camera_block(c.calibration, k, res, _declared_sigma(declared, c.name, res))))
    imus = tuple(replace(i, T_body_imu=T_body_imu, calibration=imu_block(res, reference != f"imu:{res.imu.name}"))
                 if i.name == res.imu.name
                 else i for i in out_rig.imus)
    by_name = {c.name: c for c in cams}
    pairs = tuple(replace(p, baseline_m=rounded(np.linalg.norm(by_name[p.left].T_body_cam[:3, 3]
                                                          - by_name[p.right].T_body_cam[:3, 3]), 7))
                  if p.baseline_m is not None else p for p in out_rig.stereo_pairs)
    top = dict(out_rig.calibration or {})
    top["reference"] = reference
    top["camera_imu"] = {"imu": res.imu.name, "corner_rms_px": rounded(res.corner_rms_px, 4),
                         "gravity_m_s2": rounded(est.state.gravity, 5), "passes": res.passes,
                         "iterations": int(est.iterations), "seconds": rounded(res.seconds, 2),
                         "knot_spacing_s": rounded(res.knot_dt, 6),
                         "knot_spacing_from": "imu" if res.knot is not None else "--knot-spacing",
                         "intrinsics": res.intrinsics_source}
    if res.subsets is not None:
        top["camera_imu"]["sigma_check"] = halves_entry(res.subsets, names)
    return replace(out_rig, cameras=tuple(cams), imus=imus, stereo_pairs=pairs, calibration=top)


def halves_entry(check, names: list[str]) -> dict:
    """`sigma_check`: where the recording was split, and per camera compared the halves'
    differences (first minus second) in the sigmas' units: rotation about body F, L, U
    (deg), position (mm), time offset (ms), line delay (us), intrinsics (px), and its
    formal sigmas in the same units (`formal_sigma`)."""
    cams, formal = {}, {}
    for k in np.flatnonzero(check.compared):
        e = {"rotation_deg": [rounded(np.degrees(x), 5) for x in check.d_rot[k]],
             "position_mm": [rounded(1000 * x, 4) for x in check.d_pos[k]],
             "time_offset_ms": rounded(1000 * check.d_offset[k], 5)}
        if check.d_delay is not None:
            e["line_delay_us"] = rounded(1e6 * check.d_delay[k], 5)
        if check.d_intr is not None:
            e["intrinsics"] = {key: rounded(x, 4) for key, x in zip(("fx", "fy", "cx", "cy"), check.d_intr[k])}
        cams[names[k]] = e
        # the formal sigmas beside the reported: what the halves changed, and coverage
        # benchmarks can score both
        f = check.formal
        formal[names[k]] = g = {"rotation_deg": [rounded(np.degrees(x), 5) for x in f["pose"][k, :3]],
                                "position_mm": [rounded(1000 * x, 4) for x in f["pose"][k, 3:]],
                                "time_offset_ms": rounded(1000 * f["offset"][k], 5)}
        if f.get("line_delay") is not None:
            g["line_delay_us"] = rounded(1e6 * f["line_delay"][k], 5)
        if f.get("intrinsics") is not None:
            g["intrinsics"] = {key: rounded(f["intrinsics"][k][key], 4)
                               for key in ("fx", "fy", "cx", "cy")}
    return {"method": "halves", "split_s": rounded(check.split_s, 3), "seconds": rounded(check.seconds, 2),
            "halves_difference": cams, "formal_sigma": formal}


def _declared_sigma(declared: Rig, name: str, res: ImuCalibration) -> dict | None:
    """The declared camera calibration's sigma.intrinsics when its intrinsics were held."""
    if res.intrinsics_source != "declared" or name not in declared.names:
        return None
    sig = ((declared.camera(name).calibration or {}).get("sigma") or {}).get("intrinsics")
    return dict(sig) if isinstance(sig, dict) else None


def console_tables(rig: Rig, res: ImuCalibration) -> list:
    """The per-IMU table (residual RMS against the declared noise, biases) and the cameras'
    time offsets, line delays and pose sigmas relative to the IMU."""
    b = rig.imu(res.imu.name).calibration
    t = Table(title=f"IMU {res.imu.name}")
    for col in ("", "residual RMS", "declared noise predicts", "ratio", "mean bias (x y z)", "1-sigma (x y z)"):
        t.add_column(col, justify="left" if col == "" else "right")
    t.add_row("gyroscope (rad/s)", f"{res.gyro_rms:.3g}", f"{res.gyro_predicted:.3g}",
              f"{res.gyro_rms / res.gyro_predicted:.2f}", " ".join(f"{x:+.2e}" for x in b["gyroscope_bias"]),
              " ".join(f"{x:.1e}" for x in b["sigma"]["gyroscope_bias"]))
    t.add_row("accelerometer (m/s^2)", f"{res.accel_rms:.3g}", f"{res.accel_predicted:.3g}",
              f"{res.accel_rms / res.accel_predicted:.2f}", " ".join(f"{x:+.2e}" for x in b["accelerometer_bias"]),
              " ".join(f"{x:.1e}" for x in b["sigma"]["accelerometer_bias"]))
    sel = b["imu_model_selection"]
    t.caption = f"IMU model: {b['imu_model']} (" + (
        f"likelihood ratio {sel['statistic']:.1f}, {sel['imu_statistic']:.1f} of it in the IMU's residuals, on "
        f"{sel['parameters']} parameters; both need {sel['threshold']:.1f})"
        if "statistic" in sel else sel["test"] + ")")
    parts = [t]
    if b["imu_model"] == "scale-misalignment":
        parts.append(scale_table(res.imu.name, b))
    c = Table(title=f"cameras relative to {res.imu.name} (clocks: t_imu = t_cam + offset)")
    cols = ["camera", "time offset ms", "1-sigma ms", "line delay us/row", "1-sigma us", "sigma pos mm (F L U)",
            "sigma rot deg (F L U)", "sigmas from"]
    for col in cols:
        c.add_column(col, justify="left" if col == "camera" else "right")
    for cam in rig.cameras:
        s = cam.calibration["sigma"]
        c.add_row(cam.name, f"{1000 * cam.time_offset_s:+.3f}", f"{s['time_offset_ms']:.4f}",
                  f"{1e6 * cam.line_delay_s:.3f}" if cam.line_delay_s is not None else "-",
                  f"{s['line_delay_us']:.3f}" if "line_delay_us" in s else "-",
                  " ".join(f"{x:.3f}" for x in s["position_mm"]), " ".join(f"{x:.4f}" for x in s["rotation_deg"]),
                  cam.calibration.get("sigma_source", "formal"))
    return parts + [c]


def scale_table(name: str, b: dict) -> Table:
    """M - I of each sensor: scale factors (diagonal) and misalignments (below it), with 1-sigma."""
    t = Table(title=f"IMU {name} scale and misalignment (reads M @ ideal + bias)")
    for col in ("", "scale - 1 (x y z), ppm", "1-sigma ppm", "misalignment (yx zx zy), mrad", "1-sigma mrad"):
        t.add_column(col, justify="left" if col == "" else "right")
    low = (ir.SCALE_ROWS[3:], ir.SCALE_COLS[3:])
    for label, key in zip(("gyroscope", "accelerometer"), SCALE_KEYS):
        M, S = np.array(b[key]), np.array(b["sigma"][key])
        t.add_row(label, " ".join(f"{1e6 * (x - 1):+.0f}" for x in np.diag(M)),
                  " ".join(f"{1e6 * x:.0f}" for x in np.diag(S)), " ".join(f"{1e3 * x:+.3f}" for x in M[low]),
                  " ".join(f"{1e3 * x:.3f}" for x in S[low]))
    return t


# ----------------------------------------------------------------------------- compare


def _mean_bias(doc: dict, imu: str, key: str, label: str) -> np.ndarray | None:
    try:
        v = np.asarray(doc["imus"][imu][key]["values"], dtype=float)
    except (KeyError, TypeError):
        return None
    if v.ndim != 2 or v.shape[1] != 3 or not len(v):
        raise InputError(f"{label}: imus.{imu}.{key}.values: expected rows of 3 numbers")
    return v.mean(axis=0)


def _scale_truth(doc: dict, imu: str, key: str, label: str) -> np.ndarray | None:
    try:
        v = doc["imus"][imu][key]
    except (KeyError, TypeError):
        return None
    try:
        M = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        M = None
    if M is None or M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise InputError(f"{label}: imus.{imu}.{key}: expected 3 rows of 3 numbers")
    return M


def compare_imu(est: Rig, truth: Rig, truth_doc: dict | None, label: str = "<truth>") -> dict:
    """Per camera the error of T_imu_cam (rotation deg, translation mm) for every IMU both
    rigs have, of time_offset_s (ms) and line_delay_s (us/row); per IMU the error of the
    mean biases against truth.yaml's sampled ones (when given) and, when truth.yaml gives
    them, of the scale-misalignment matrices (3x3; a calibrated IMU counts as M = I)."""
    out = {"cameras": {}, "imus": {}}
    imus = [i.name for i in est.imus if i.name in {j.name for j in truth.imus}]
    for n in est.names:
        if n not in truth.names:
            continue
        a, b = est.camera(n), truth.camera(n)
        e = {}
        if a.time_offset_s is not None:
            e["offset_ms"] = 1000 * (a.time_offset_s - (b.time_offset_s or 0.0))
        if a.line_delay_s is not None:
            e["line_delay_us"] = 1e6 * (a.line_delay_s - (b.line_delay_s or 0.0))
        for i in imus:
            Ta = geo.inv_T(est.imu(i).T_body_imu) @ a.T_body_cam
            Tb = geo.inv_T(truth.imu(i).T_body_imu) @ b.T_body_cam
            e[f"{i}_rot_deg"] = geo.rotation_angle_deg(Ta[:3, :3] @ Tb[:3, :3].T)
            e[f"{i}_pos_mm"] = 1000 * float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
        out["cameras"][n] = e
    for i in imus:
        cal = est.imu(i).calibration or {}
        e = {}
        for key in ("gyroscope_bias", "accelerometer_bias"):
            true = _mean_bias(truth_doc or {}, i, key, label)
            if key in cal and true is not None:
                e[key] = np.asarray(cal[key], float) - true
        for key in SCALE_KEYS:  # compared only when the truth has them (the simulator writes none)
            true = _scale_truth(truth_doc or {}, i, key, label)
            if true is not None:
                e[key] = np.asarray(cal.get(key, np.eye(3)), float) - true
        out["imus"][i] = e
    return out


def compare_tables(res: dict) -> list:
    if not any(res["cameras"].values()):
        return []
    keys = sorted({k for e in res["cameras"].values() for k in e})
    t = Table(title="camera-IMU (T_imu_cam, clocks)")
    t.add_column("camera")
    for k in keys:
        t.add_column(k.replace("_", " ").replace(" deg", " err deg").replace(" mm", " err mm")
                     .replace("offset ms", "offset err ms").replace("line delay us", "line delay err us"),
                     justify="right")
    for n, e in res["cameras"].items():
        t.add_row(n, *(f"{e[k]:+.4f}" if k in e else "-" for k in keys))
    parts = [t]
    every = [(i, k, v) for i, e in res["imus"].items() for k, v in e.items()]
    rows = [r for r in every if r[1] not in SCALE_KEYS]
    if rows:
        b = Table(title="IMU biases (calibrated mean - true mean)")
        for col in ("imu", "bias", "error x", "error y", "error z"):
            b.add_column(col, justify="left" if col in ("imu", "bias") else "right")
        for i, k, v in rows:
            b.add_row(i, k + (" rad/s" if k.startswith("gyro") else " m/s^2"), *(f"{x:+.2e}" for x in v))
        parts.append(b)
    rows = [r for r in every if r[1] in SCALE_KEYS]
    if rows:
        m = Table(title="IMU scale-misalignment (calibrated M - true M)")
        for col in ("imu", "matrix", "largest error", "scale errors (x y z)"):
            m.add_column(col, justify="left" if col in ("imu", "matrix") else "right")
        for i, k, v in rows:
            m.add_row(i, k, f"{np.abs(v).max():.2e}", " ".join(f"{x:+.2e}" for x in np.diag(v)))
        parts.append(m)
    return parts
