"""Benchmark: the camera-IMU estimator (rigcal.imucal.estimator) on EuRoC's real calibration
recording `imu_april` (../shared/data/real/euroc_imu_april: 72 s, stereo MT9V034 at 20 Hz,
yac's AprilGrid corners, ADIS16448 at 200 Hz), against EuRoC's published T_BS (Kalibr's
result, not ground truth).

As Kalibr does: the intrinsics come from a camera-only calibration of the same corners
(rigcal's calibrate_views, held), the static AprilGrid is the world frame, gravity's
direction is estimated (|g| = 9.81007, EuRoC's site), the IMU defines the body frame.
The run is repeated with EuRoC's own intrinsics held, and on each half of the recording,
to tell rigcal's differences from the reference's.

The recording is also calibrated end to end by `rigcal calibrate` (`--calibrate`): a
motion dataset of dataset.md's `corners/` input (the camera-only set of bench.real) plus
imu/imu0.csv and the IMU declared in rig.yaml, with EuRoC's gravity and Kalibr's knot spacing.

`--defaults` runs `rigcal calibrate DATASET --out X` as a user would, nothing else given
(the knot spacing chosen from the IMU, the sigmas checked on the recording's halves), twice:
on the dataset as above (the intrinsics estimated from this recording) and with a declared
rig that is a camera calibration (EuRoC's published intrinsics and distortion, standing in
for a calibration of EuRoC's separate camera-calibration recording, with a calibration block
whose sigma.intrinsics are 0.5 px: EuRoC publishes none), as in the two-recording workflow.
Each against the accuracy band (0.35 deg, 8 mm from T_BS, baseline within 0.3 mm of
110.07 mm, offsets within 1 ms), and every reported parameter's halves difference in units
of its reported sigma.

    python -m bench.imu_euroc [--no-halves] [--no-euroc-intrinsics] [--huber K] [--calibrate | --calibrate-only]
    python -m bench.imu_euroc --defaults
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace

import numpy as np

from rigcal.core import geometry as geo
from rigcal.imucal import estimator as ic
from rigcal.imucal import residuals as ir

from .common import OUT, Timer, md_table, say, write_json
from .real import SHARED, linked

GRAVITY_EUROC = 9.81007  # m/s^2 at ETH Zurich (imu.md)
# Kalibr's 100 knots/s: at the prototype's 0.05 s the hand-waved motion left gyro and accel
# residuals at 9x and 7.5x EuRoC's noise (0.02 s: 2.4x / 3.0x; 0.01 s: 0.8x / 1.25x, first 15 s)
KNOT_DT = 0.01
CAMERAS = ("cam0", "cam1")
BASELINE_MM = 110.07


@dataclass(frozen=True)
class EurocData:
    """The corners as estimator inputs (before any camera model): per camera frame times (s
    since the first IMU sample), per frame (ids, uv), the board's corner positions."""

    frames: dict  # camera -> list of (t_s, ids, uv)
    board_corners: np.ndarray
    imu: ic.ImuInput
    reference: dict
    views: list  # BoardViews for the camera-only calibration
    rig: object
    target: object
    read_s: float


def load(log=say) -> EurocData | None:
    import yaml

    import rigcal
    from rigcal.core.observations import BoardView
    from rigcal.data.corners import read_corners
    from rigcal.data.imu_csv import read_imu_csv
    from rigcal.core.target import load_target

    d = linked("euroc", log)
    if d is None:
        return None
    with Timer() as t:
        rig = rigcal.load_rig(d / "rig.yaml")
        target = load_target(d / "target.yaml")
        ref = yaml.safe_load((SHARED / "euroc_imu_april" / "reference.yaml").read_text())
        samples = read_imu_csv(SHARED / "euroc_imu_april" / "imu0.csv")
        t_base = int(samples.t_ns[0])
        frames, views = {}, []
        for cam in CAMERAS:
            rows = read_corners(d / "corners" / f"{cam}.csv", target)
            frames[cam] = [((int(f) - t_base) * 1e-9, ids, uv) for f, _, ids, uv in rows]
            views += [BoardView(cam, f, b, ids, uv) for f, b, ids, uv in rows]
        n = ref["imu0"]
        imu = ic.ImuInput((samples.t_ns - t_base) * 1e-9, samples.gyro, samples.accel, float(n["rate_hz"]),
                          n["gyroscope_noise_density"], n["gyroscope_random_walk"],
                          n["accelerometer_noise_density"], n["accelerometer_random_walk"], np.eye(4))
    return EurocData(frames, target.boards[0].corners, imu, ref, views, rig, target, t.wall)


def camera_only(data: EurocData):
    """rigcal's camera-only calibration of the corners: (models by camera, RMS px, seconds)."""
    from rigcal.camcal.pipeline import calibrate_views

    b = data.target.boards[0]
    with Timer() as t:
        cal = calibrate_views(data.views, data.rig, {b.name: b.corners}, faces={b.name: b.print_face})
    return {c.name: c.intrinsics for c in cal.rig.cameras}, float(cal.rms_px), t.wall


def euroc_models(data: EurocData, like: dict) -> dict:
    """EuRoC's published intrinsics (radtan k1 k2 p1 p2, k3 = 0) as CameraModels."""
    out = {}
    for cam in CAMERAS:
        fx, fy, cx, cy = data.reference[cam]["intrinsics"]
        out[cam] = replace(like[cam], fx=fx, fy=fy, cx=cx, cy=cy, dist=(*data.reference[cam]["distortion"], 0.0))
    return out


def inputs(data: EurocData, models: dict, t_lo: float = -np.inf, t_hi: float = np.inf):
    """(cameras, corners, imu) for calibrate_camera_imu: PnP per frame with `models`, every
    corner of the frames whose time lies in [t_lo, t_hi), the IMU samples over that span."""
    from rigcal.camcal.initialise import pnp_views

    board = data.board_corners
    cams, parts = [], []
    for ci, cam in enumerate(CAMERAS):
        fr = [f for f in data.frames[cam] if t_lo <= f[0] < t_hi]
        m = models[cam]
        fits = pnp_views([board[ids] for _, ids, _ in fr], [uv for *_, uv in fr],
                         np.array([m.fx, m.fy, m.cx, m.cy, *m.dist]), m.model, [data.target.boards[0].print_face] * len(fr))
        ok = [j for j, f in enumerate(fits) if f is not None]
        T_wc = np.stack([geo.inv_T(fits[j][0]) for j in ok])
        cams.append(ic.CameraInput(m, np.eye(4), np.array([fr[j][0] for j in ok]), T_wc))
        for t, ids, uv in fr:
            parts.append((np.full(len(ids), ci), np.full(len(ids), t), uv, board[ids]))
    obs = ir.Corners(*(np.concatenate(x) for x in zip(*parts)))
    imu = data.imu
    keep = (imu.t >= t_lo - 1.0) & (imu.t < t_hi + 1.0)
    imu = replace(imu, t=imu.t[keep], gyro=imu.gyro[keep], accel=imu.accel[keep])
    return cams, obs, imu


def against_reference(T_imu_cam: np.ndarray, offsets_s, sigma: np.ndarray, ref: dict) -> dict:
    """Per camera (T_imu_cam (2, 4, 4), offsets (2,) s, sigma (2, 7): rotation rad, position m,
    offset s): rotation (deg) and translation (mm) differences from EuRoC's T_BS, as vectors in
    IMU axes too, offset (ms), 1-sigmas; the baseline (mm)."""
    out = {"rot_deg": [], "pos_mm": [], "offset_ms": [], "sigma_rot_deg": [], "sigma_pos_mm": [], "sigma_offset_ms": [],
           "rot_vec_deg": [], "pos_vec_mm": []}
    for ci, cam in enumerate(CAMERAS):
        T_ref = np.array(ref[cam]["T_BS"], dtype=float)
        T = T_imu_cam[ci]
        dR = T[:3, :3] @ T_ref[:3, :3].T
        out["rot_deg"].append(geo.rotation_angle_deg(dR))
        out["rot_vec_deg"].append(np.degrees(geo.rotvecs_from_R(dR[None])[0]).tolist())
        out["pos_vec_mm"].append((1000 * (T[:3, 3] - T_ref[:3, 3])).tolist())
        out["pos_mm"].append(1000 * float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3])))
        out["offset_ms"].append(1000 * float(offsets_s[ci]))
        out["sigma_rot_deg"].append(np.degrees(sigma[ci, :3]).tolist())
        out["sigma_pos_mm"].append((1000 * sigma[ci, 3:6]).tolist())
        out["sigma_offset_ms"].append(1000 * float(sigma[ci, 6]))
    out["baseline_mm"] = 1000 * float(np.linalg.norm(T_imu_cam[0, :3, 3] - T_imu_cam[1, :3, 3]))
    return out


def compare(res: ic.CameraImuResult, ref: dict) -> dict:
    """against_reference for the estimator's result, with its residuals, iterations, time."""
    return {**against_reference(res.T_imu_cam, res.time_offset_s, res.sigma, ref),
            "normalised_rms": res.normalised_rms, "iterations": res.iterations, "solve_s": res.seconds}


def corner_spread(res: ic.CameraImuResult, obs: ir.Corners, models: list) -> dict:
    """The corners' residual norms (px) at the estimate: RMS, 99th percentile, share beyond
    1 and 2 px (outliers would show here)."""
    k = res.corners_used
    obs = obs.subset(k)
    b = ir.reprojection_block(res.state, ir.layout_for(res.state), obs, models, 1.0)
    e = np.linalg.norm(b.r, axis=1)
    return {"rms_px": float(np.sqrt(np.mean(e ** 2))), "p99_px": float(np.percentile(e, 99)),
            "over_1px": float(np.mean(e > 1)), "over_2px": float(np.mean(e > 2))}


def run_one(data: EurocData, models: dict, sigma_px: float, label: str, log=say, huber: float | None = None,
            **span) -> dict:
    with Timer() as t:
        cams, obs, imu = inputs(data, models, **span)
    res = ic.calibrate_camera_imu(cams, obs, imu, ic.Settings(sigma_px=sigma_px, gravity=GRAVITY_EUROC, knot_dt=KNOT_DT,
                                                              huber=huber))
    row = {"label": label, "corners": len(obs.cam), "imu_samples": len(imu.t), "inputs_s": t.wall,
           "corner_residuals": corner_spread(res, obs, [c.model for c in cams]), **compare(res, data.reference)}
    log(f"  {label}: rot {row['rot_deg'][0]:.3f}/{row['rot_deg'][1]:.3f} deg, pos {row['pos_mm'][0]:.2f}/"
        f"{row['pos_mm'][1]:.2f} mm, baseline {row['baseline_mm']:.2f} mm, offset {row['offset_ms'][0]:+.3f}/"
        f"{row['offset_ms'][1]:+.3f} ms, rms {row['normalised_rms']}, {res.seconds:.1f} s")
    return row


def run(halves: bool = True, euroc_intrinsics: bool = True, huber: float | None = None, log=say,
        calibrate: bool = False) -> dict | None:
    data = load(log)
    if data is None:
        return None
    t0 = time.perf_counter()
    models, rms_px, cam_s = camera_only(data)
    log(f"  camera-only: {cam_s:.1f} s, {rms_px:.3f} px RMS")
    out = {"read_s": data.read_s, "camera_only_s": cam_s, "camera_only_rms_px": rms_px,
           "intrinsics": {c: [m.fx, m.fy, m.cx, m.cy, *m.dist] for c, m in models.items()}, "runs": []}
    # rigcal's RMS is of the residual norm; the estimator's sigma_px is per coordinate
    sigma = rms_px / np.sqrt(2.0)
    out["sigma_px"] = sigma
    out["runs"].append(run_one(data, models, sigma, "rigcal intrinsics", log, huber))
    out["start_to_result_s"] = time.perf_counter() - t0 + data.read_s
    if euroc_intrinsics:
        out["runs"].append(run_one(data, euroc_models(data, models), sigma, "EuRoC intrinsics", log, huber))
    if halves:
        mid = 0.5 * (data.imu.t[0] + data.imu.t[-1])
        out["runs"].append(run_one(data, models, sigma, "first half", log, huber, t_hi=mid))
        out["runs"].append(run_one(data, models, sigma, "second half", log, huber, t_lo=mid))
    if calibrate:
        out["calibrate"] = via_calibrate(log)
        out["runs"].append(out["calibrate"])
    return out


def tables(res: dict | None) -> str:
    if not res:
        return ""
    rows = []
    for r in res["runs"]:
        rows.append([r["label"], *(f"{r['rot_deg'][i]:.3f} ({np.linalg.norm(r['sigma_rot_deg'][i]):.3f})" for i in (0, 1)),
                     *(f"{r['pos_mm'][i]:.2f} ({np.linalg.norm(r['sigma_pos_mm'][i]):.2f})" for i in (0, 1)),
                     f"{r['baseline_mm']:.2f}",
                     *(f"{r['offset_ms'][i]:+.3f} ({r['sigma_offset_ms'][i]:.3f})" for i in (0, 1)),
                     " / ".join(f"{r['normalised_rms'][k]:.2f}" for k in ("corners", "gyro", "accel")),
                     f"{r['solve_s']:.0f}"])
    return md_table(["run", "cam0 rot deg (1-sigma)", "cam1 rot deg", "cam0 pos mm", "cam1 pos mm", "baseline mm",
                     "cam0 offset ms", "cam1 offset ms", "RMS / declared: corners / gyro / accel", "solve s"], rows)


# EuRoC's ADIS16448 is mounted x up, y to the right, z forward (its T_BS against the cameras'):
# declared roughly, as a user would before calibrating; the noise figures are EuRoC's imu0 sensor.yaml
IMU_BLOCK = """
imus:
  imu0:
    position: [0.0, 0.0, 0.0]
    axes: [U, -L, F]
    update_rate: 200.0
    gyroscope_noise_density: {gyroscope_noise_density}
    gyroscope_random_walk: {gyroscope_random_walk}
    accelerometer_noise_density: {accelerometer_noise_density}
    accelerometer_random_walk: {accelerometer_random_walk}
"""


def build_dataset(dst, log=say):
    """The EuRoC motion dataset for `rigcal calibrate`: bench.real's corners-only set (its
    corners/, target.yaml and declared camera rig) plus imu/imu0.csv (EuRoC's file as is) and
    the IMU in rig.yaml. None when the shared data is absent."""
    import shutil

    import yaml

    src = linked("euroc", log)
    if src is None:
        return None
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src / "corners", dst / "corners")
    shutil.copy(src / "target.yaml", dst / "target.yaml")
    (dst / "imu").mkdir()
    shutil.copy(SHARED / "euroc_imu_april" / "imu0.csv", dst / "imu" / "imu0.csv")
    noise = yaml.safe_load((SHARED / "euroc_imu_april" / "reference.yaml").read_text())["imu0"]
    (dst / "rig.yaml").write_text((src / "rig.yaml").read_text() + IMU_BLOCK.format(**noise))
    return dst


def via_calibrate(log=say) -> dict | None:
    """`rigcal calibrate` on the EuRoC motion dataset (a subprocess, timed start to YAML),
    its T_imu_cam against EuRoC's T_BS."""
    import subprocess
    import sys

    d = build_dataset(OUT / "euroc_imu_dataset", log)
    if d is None:
        return None
    out_yaml = OUT / "euroc_imu_calibrated.yaml"
    cmd = [sys.executable, "-m", "rigcal", "calibrate", str(d), "--out", str(out_yaml), "--gravity",
           str(GRAVITY_EUROC), "--knot-spacing", str(KNOT_DT), "--jobs", "2"]
    with Timer() as t:
        run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"rigcal calibrate failed ({run.returncode}): {run.stderr.strip()[-2000:]}")
    return score(out_yaml, t.wall, run.stdout, log)


def score(out_yaml, wall_s: float, console: str, log=say) -> dict:
    """A calibrated EuRoC rig (`rigcal calibrate`'s YAML) against EuRoC's T_BS."""
    import yaml

    import rigcal

    rig = rigcal.load_rig(out_yaml)
    ref = yaml.safe_load((SHARED / "euroc_imu_april" / "reference.yaml").read_text())
    doc = yaml.safe_load(out_yaml.read_text())
    T_bi = rig.imu("imu0").T_body_imu
    T = np.stack([geo.inv_T(T_bi) @ rig.camera(cam).T_body_cam for cam in CAMERAS])
    sig = [rig.camera(cam).calibration["sigma"] for cam in CAMERAS]
    sigma = np.array([[*np.radians(s["rotation_deg"]), *(1e-3 * np.array(s["position_mm"])), 1e-3 * s["time_offset_ms"]]
                      for s in sig])
    row = {"label": "rigcal calibrate", "seconds": wall_s, "console": console[-6000:],
           "camera_imu": doc["calibration"].get("camera_imu"), "imu0": doc["imus"]["imu0"].get("calibration"),
           "intrinsics": {cam: [m.fx, m.fy, m.cx, m.cy, *m.dist] for cam in CAMERAS
                          for m in [rig.camera(cam).intrinsics]},
           **against_reference(T, [rig.camera(cam).time_offset_s for cam in CAMERAS], sigma, ref)}
    cal = row["imu0"]
    row["normalised_rms"] = {"corners": float("nan"),
                             "gyro": cal["gyroscope_residual_rms"] / cal["gyroscope_residual_rms_declared"],
                             "accel": cal["accelerometer_residual_rms"] / cal["accelerometer_residual_rms_declared"]}
    row["solve_s"] = float(row["camera_imu"]["seconds"])
    log(f"  rigcal calibrate: rot {row['rot_deg'][0]:.3f}/{row['rot_deg'][1]:.3f} deg, pos {row['pos_mm'][0]:.2f}/"
        f"{row['pos_mm'][1]:.2f} mm, baseline {row['baseline_mm']:.2f} mm, offset {row['offset_ms'][0]:+.3f}/"
        f"{row['offset_ms'][1]:+.3f} ms, gyro/accel RMS {row['normalised_rms']['gyro']:.2f}/"
        f"{row['normalised_rms']['accel']:.2f} x declared, whole calibrate {wall_s:.1f} s")
    return row


BAND = {"rot_deg": 0.35, "pos_mm": 8.0, "baseline_mm": 0.3, "offset_ms": 1.0}
STANDIN_SIGMA_PX = 0.5  # sigma.intrinsics of the stand-in camera calibration (EuRoC publishes none)


def camera_calibration_rig(src_rig: str, reference: dict) -> str:
    """The declared rig text with EuRoC's intrinsics and distortion per camera and a
    calibration block (sigma.intrinsics): a camera calibration, as `rigcal calibrate`
    writes one."""
    import yaml

    doc = yaml.safe_load(src_rig)
    for cam in CAMERAS:
        fx, fy, cx, cy = reference[cam]["intrinsics"]
        c = doc["cameras"][cam]
        c["intrinsics"] = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
        c["distortion"] = list(reference[cam]["distortion"])
        c["calibration"] = {"sigma": {"intrinsics": {k: STANDIN_SIGMA_PX for k in ("fx", "fy", "cx", "cy")}}}
    return yaml.safe_dump(doc, sort_keys=False)


def halves_in_sigmas(out_yaml) -> dict:
    """Per camera and reported parameter |halves difference| / reported 1-sigma (from the
    output's camera_imu.sigma_check), and the largest."""
    import yaml

    doc = yaml.safe_load(out_yaml.read_text())
    chk = (doc["calibration"].get("camera_imu") or {}).get("sigma_check")
    if not chk:
        return {}
    out = {}
    for cam, d in chk["halves_difference"].items():
        sig = doc["cameras"][cam]["calibration"]["sigma"]
        r = {}
        for key in ("rotation_deg", "position_mm"):
            r[key] = [abs(a) / b for a, b in zip(d[key], sig[key])]
        r["time_offset_ms"] = [abs(d["time_offset_ms"]) / sig["time_offset_ms"]]
        if "intrinsics" in d:
            r["intrinsics"] = [abs(d["intrinsics"][k]) / sig["intrinsics"][k] for k in ("fx", "fy", "cx", "cy")
                               if sig["intrinsics"].get(k)]
        out[cam] = {"ratios": r, "max": max(max(v) for v in r.values()),
                    "sigma_source": doc["cameras"][cam]["calibration"].get("sigma_source")}
    return out


def in_band(row: dict) -> dict:
    """Which of the band's figures the row meets."""
    return {"rot_deg": max(row["rot_deg"]) <= BAND["rot_deg"], "pos_mm": max(row["pos_mm"]) <= BAND["pos_mm"],
            "baseline_mm": abs(row["baseline_mm"] - BASELINE_MM) <= BAND["baseline_mm"],
            "offset_ms": max(abs(x) for x in row["offset_ms"]) <= BAND["offset_ms"]}


def band_distance_in_sigmas(row: dict) -> dict:
    """Per camera how far the result lies outside the band (0 inside), in units of its
    reported 1-sigma (the norm over the three axes): rotation and position."""
    out = {}
    for i, cam in enumerate(CAMERAS):
        rot = max(row["rot_deg"][i] - BAND["rot_deg"], 0.0) / np.linalg.norm(row["sigma_rot_deg"][i])
        pos = max(row["pos_mm"][i] - BAND["pos_mm"], 0.0) / np.linalg.norm(row["sigma_pos_mm"][i])
        out[cam] = {"rot": float(rot), "pos": float(pos)}
    return out


def defaults_runs(log=say) -> dict | None:
    """`rigcal calibrate DATASET --out X` with nothing else (but --jobs 2), without and with
    a camera calibration as the declared rig (camera_calibration_rig)."""
    import resource
    import subprocess
    import sys

    import yaml

    d = build_dataset(OUT / "euroc_imu_dataset", log)
    if d is None:
        return None
    ref = yaml.safe_load((SHARED / "euroc_imu_april" / "reference.yaml").read_text())
    cal_rig = OUT / "euroc_camera_calibration.yaml"
    cal_rig.write_text(camera_calibration_rig((d / "rig.yaml").read_text(), ref))
    out = {}
    for label, extra in (("defaults, intrinsics from this recording", []),
                         ("defaults, camera calibration as --rig (EuRoC's intrinsics)", ["--rig", str(cal_rig)])):
        out_yaml = OUT / f"euroc_defaults_{len(out)}.yaml"
        cmd = [sys.executable, "-m", "rigcal", "calibrate", str(d), "--out", str(out_yaml), "--jobs", "2", *extra]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        with Timer() as t:
            run = subprocess.run(cmd, capture_output=True, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if run.returncode != 0:
            raise RuntimeError(f"rigcal calibrate failed ({run.returncode}): {run.stderr.strip()[-2000:]}")
        row = score(out_yaml, t.wall, run.stderr + run.stdout, log)
        row["label"] = label
        row["cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        row["halves"] = halves_in_sigmas(out_yaml)
        row["band"] = in_band(row)
        row["outside_band_in_sigmas"] = band_distance_in_sigmas(row)
        row["warnings"] = [ln for ln in run.stderr.splitlines() if ln.startswith("warning:")]
        row["knot_spacing_s"] = row["camera_imu"]["knot_spacing_s"]
        log(f"  {label}: knot {row['knot_spacing_s']} s, band {row['band']}, halves max "
            f"{ {c: round(h['max'], 2) for c, h in row['halves'].items()} } sigma, wall {t.wall:.1f} s, "
            f"cpu {row['cpu_s']:.1f} s; warnings: {row['warnings']}")
        out[label] = row
    return out


def defaults_tables(rows: dict | None) -> str:
    """The two default runs: accuracy against T_BS (tables()), then per run the knot
    spacing, the band, the halves' largest difference in reported sigmas, the distance
    outside the band in sigmas, the warnings and the time."""
    if not rows:
        return ""
    lines = [tables({"runs": list(rows.values())}), ""]
    for label, r in rows.items():
        out = {c: {k: round(v, 2) for k, v in x.items()} for c, x in r["outside_band_in_sigmas"].items()}
        lines.append(f"- {label}: knot {r['knot_spacing_s']} s; in band {r['band']}; halves / reported sigma at most "
                     f"{ {c: round(h['max'], 2) for c, h in r['halves'].items()} }; outside the band in sigmas "
                     f"{out}; "
                     f"{len(r['warnings'])} warning(s); start to YAML {r['seconds']:.1f} s (cpu {r['cpu_s']:.1f} s)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-halves", action="store_true")
    ap.add_argument("--no-euroc-intrinsics", action="store_true")
    ap.add_argument("--huber", type=float, default=None, help="Huber loss on the corners beyond this many sigma")
    ap.add_argument("--calibrate", action="store_true", help="also run `rigcal calibrate` on the recording")
    ap.add_argument("--calibrate-only", action="store_true", help="only `rigcal calibrate` on the recording")
    ap.add_argument("--defaults", action="store_true",
                    help="only `rigcal calibrate` with its defaults, without and with a camera calibration as --rig")
    a = ap.parse_args(argv)
    if a.defaults:
        rows = defaults_runs()
        if rows is None:
            say("imu_euroc: ../shared/data/real/euroc_imu_april not found; skipped")
            return 0
        write_json("imu_euroc_defaults", rows)
        print(defaults_tables(rows))
        return 0
    if a.calibrate_only:
        row = via_calibrate()
        res = None if row is None else {"calibrate": row, "runs": [row]}
    else:
        res = run(not a.no_halves, not a.no_euroc_intrinsics, a.huber, calibrate=a.calibrate)
    if res is None:
        say("imu_euroc: ../shared/data/real/euroc_imu_april not found; skipped")
        return 0
    write_json("imu_euroc", res)
    print(tables(res))
    if "start_to_result_s" in res:
        print(f"start to result (read, camera-only, camera-IMU): {res['start_to_result_s']:.1f} s")
    if "calibrate" in res:
        print(f"rigcal calibrate, start to YAML: {res['calibrate']['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
