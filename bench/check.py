"""`rigcal check` on simulated recordings: false alarms on an unchanged rig, and detection of
one camera turned, shifted, its focal length or its principal point changed.

Per seed: the true rig (drone-stereo-back with simulate's mount and lens errors, drawn once)
is calibrated from its own 30-frame room recording (seed-dependent, so the rig's own error
varies across seeds as it does across real calibrations); then new `frames`-frame
recordings of the true rig (unchanged) and of changed copies (CASES, camera CHANGED) are
checked against that calibration at level 0.01. Per case: the share of seeds in which the
changed camera is flagged with the right status, in which another camera is flagged, and
in which the reported size is within 2 sigma of the true change; the check's time over
its detection time.

The camera-IMU part (--imu N): per seed, the camera-IMU rig (drone-stereo-back-imu with
simulate's mount, lens and clock errors) calibrated from its own 10 s motion recording (camera-only,
then camera-IMU), then 6 s recordings (20 Hz) of it unchanged, with front_right turned 0.2 deg
about body U relative to the IMU, and with its clock offset changed by 2 ms, checked at level
0.01 (tests/support/imu_check_cases: projected corners with 0.3 px noise, not rendered).

    python -m bench.check [--seeds N] [--frames F] [--first SEED] [--indie N] [--imu N]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.check.run import run as run_check
from rigcal.commands.calibrate import CalibrateOptions, run as calibrate
from tests.support.check_cases import calibrated_rig, changed_rig, record, true_rig

from .common import say, write_json

CHANGED = "front_right"
LEVEL = 0.01
# name -> (changed_rig keyword arguments, expected status, how to read the size and its sigma, true size)
CASES = {
    "unchanged": ({}, "ok", None, 0.0),
    "turned 0.2 deg about U": ({"rotate_deg": 0.2, "axis": "U"}, "moved", ("pose", "rotation_deg", 2), 0.2),
    "moved 2 mm along L": ({"shift_mm": 2.0, "shift_axis": "L"}, "moved", ("pose", "translation_mm", 1), 2.0),
    "focal +0.3 %": ({"focal_rel": 0.003}, "intrinsics changed", ("intrinsics", "fx", None), None),
    "principal point +2 px in x": ({"pp_px": (2.0, 0.0)}, "intrinsics changed", ("intrinsics", "cx", None), 2.0),
}


def size_and_sigma(cam: dict, how: tuple) -> tuple[float, float]:
    part, key, axis = how
    if part == "pose":
        p = cam["pose"]
        sig_key = key.replace("_deg", "_sigma_deg").replace("_mm", "_sigma_mm")
        return p[key][axis], p[sig_key][axis]
    i = cam["intrinsics"]
    return i["change_px"][key], i["sigma_px"][key]


def one_seed(seed: int, frames: int, work: Path, truth) -> dict:
    """Every case for one seed: the rig calibrated from its own recording, then each case checked."""
    cal = calibrated_rig(truth, work, 30, 1000 + seed)
    out = {}
    for name, (kw, expected, how, size) in CASES.items():
        true_rig = changed_rig(truth, CHANGED, **kw)
        if name.startswith("focal"):
            size = true_rig.camera(CHANGED).intrinsics.fx - truth.camera(CHANGED).intrinsics.fx
        rec = record(true_rig, work / "new", frames, 2000 + seed)
        t0 = time.perf_counter()
        text, code = run_check(cal, rec, as_json=True, jobs=1)
        wall = time.perf_counter() - t0
        d = json.loads(text)
        cams = d["cameras"]
        others = [n for n, c in cams.items() if n != CHANGED and c["status"] != "ok"]
        row = {"exit": code, "status": cams[CHANGED]["status"], "others_flagged": others,
               "right": cams[CHANGED]["status"] == expected, "seconds": wall,
               "detection_s": d["seconds"]["detection_s"]}
        if name == "unchanged":  # every test's p-value: uniform on [0, 1] when the sigmas are honest
            row["p_values"] = [c[k]["p_value"] for c in cams.values() for k in ("pose", "intrinsics") if k in c]
        if how is not None and cams[CHANGED]["status"] != "undetermined":
            got, sig = size_and_sigma(cams[CHANGED], how)
            row.update(size=got, sigma=sig, true=size, within_2_sigma=bool(abs(got - size) <= 2 * sig))
        out[name] = row
    return out


def indie_seed(seed: int, frames: int, work: Path) -> dict:
    """The independent renderer (tests/support/indie_render.py: a pinhole pair and a fisheye
    looking back, in a room of ChArUco boards): a rig calibrated from its own 30 frames,
    then checked unchanged and with front_right turned 0.2 deg about body U."""
    from dataclasses import replace

    from rigcal.core import geometry as geo
    from tests.support import indie_render as ir

    png = ((".png", False),)
    base = ir.room_scene(n_frames=30, seed=100 + seed)
    shutil.rmtree(work / "ibase", ignore_errors=True)
    ir.write_dataset(base, work / "ibase", seed=seed, drop=0, corrupt=False, formats=png)
    cal = work / "icalibrated.yaml"
    calibrate(work / "ibase", cal, CalibrateOptions(jobs=1))
    out = {}
    for name, turn in (("unchanged", 0.0), ("turned 0.2 deg about U", 0.2)):
        cams = []
        for c in base.cameras:
            if c.name == CHANGED and turn:
                T = c.T_body_cam.copy()
                T[:3, :3] = geo.R_from_rotvec([0.0, 0.0, np.radians(turn)]) @ T[:3, :3]
                c = replace(c, T_body_cam=T)
            cams.append(c)
        scene = replace(ir.room_scene(n_frames=frames, seed=200 + seed), cameras=tuple(cams))
        shutil.rmtree(work / "inew", ignore_errors=True)
        ir.write_dataset(scene, work / "inew", seed=seed, drop=0, corrupt=False, formats=png)
        text, code = run_check(cal, work / "inew", as_json=True, jobs=1)
        d = json.loads(text)
        out[name] = {"exit": code, "statuses": {n: c["status"] for n, c in d["cameras"].items()},
                     "rotation_deg": d["cameras"][CHANGED].get("pose", {}).get("rotation_deg"),
                     "rotation_sigma_deg": d["cameras"][CHANGED].get("pose", {}).get("rotation_sigma_deg")}
    return out


# name -> (imu_check_cases.changed_imu_rig keyword arguments, expected status, size key, true size)
IMU_CASES = {
    "unchanged": ({}, "ok", None, 0.0),
    "turned 0.2 deg about U relative to the IMU": ({"rotate_deg": 0.2, "axis": "U"}, "moved", "rotation", 0.2),
    "clock offset +2 ms": ({"offset_ms": 2.0}, "clock changed", "clock", 2.0),
}


def imu_seed(seed: int, work: Path) -> dict:
    """Every camera-IMU case for one seed (module text)."""
    from tests.support import imu_check_cases as ic

    truth = ic.true_rig(1)
    cal = ic.calibrated_rig(truth, work, duration=10.0, seed=1000 + seed, camera_rate=20.0)
    out = {}
    for name, (kw, expected, what, size) in IMU_CASES.items():
        rec = ic.record(ic.changed_imu_rig(truth, CHANGED, **kw), work / "new", 6.0, 20.0, 2000 + seed)
        t0 = time.perf_counter()
        text, code = run_check(cal, rec, as_json=True, jobs=1)
        d = json.loads(text)
        cams = d["cameras"]
        row = {"exit": code, "status": cams[CHANGED]["status"], "right": cams[CHANGED]["status"] == expected,
               "others_flagged": [n for n, c in cams.items() if n != CHANGED and c["status"] != "ok"],
               "seconds": time.perf_counter() - t0, "camera_imu_s": d["seconds"].get("camera_imu_s"),
               "p_values": [p for c in cams.values() if "imu" in c
                            for p in (c["imu"]["p_value"], c["imu"]["clock"]["p_value"])]}
        imu = cams[CHANGED].get("imu")
        if what is not None and imu is not None:
            got, sig = ((imu["rotation_deg"][2], imu["rotation_sigma_deg"][2]) if what == "rotation"
                        else (imu["clock"]["offset_change_ms"], imu["clock"]["sigma_ms"]))
            row.update(size=got, sigma=sig, true=size, within_2_sigma=bool(abs(got - size) <= 2 * sig))
        out[name] = row
    return out


def run_imu(seeds: int, first: int = 0) -> dict:
    per_seed = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-check-imu-") as tmp:
        for s in range(first, first + seeds):
            per_seed.append(imu_seed(s, Path(tmp)))
            say(f"check --imu: seed {s} ({len(per_seed)}/{seeds}) done ({time.perf_counter() - t0:.0f} s)")
    summary = {}
    for name in IMU_CASES:
        rows = [p[name] for p in per_seed]
        n = len(rows)
        summary[name] = {"seeds": n, "flagged_right": sum(r["right"] for r in rows) / n,
                         "any_flagged": sum(r["exit"] == 1 for r in rows) / n,
                         "other_camera_flagged": sum(bool(r["others_flagged"]) for r in rows) / n,
                         "within_2_sigma": (sum(r.get("within_2_sigma", False) for r in rows) / n
                                            if "size" in rows[0] else None),
                         "check_s": float(np.median([r["seconds"] for r in rows]))}
    p = np.concatenate([r["unchanged"]["p_values"] for r in per_seed])
    summary["unchanged"]["p_below"] = {str(a): float(np.mean(p < a)) for a in (0.01, 0.05, 0.2, 0.5)}
    return {"seeds": seeds, "first_seed": first, "level": LEVEL, "changed_camera": CHANGED, "summary": summary,
            "per_seed": per_seed, "seconds": time.perf_counter() - t0}


def imu_tables(r: dict) -> str:
    lines = [f"### rigcal check, camera-IMU: {r['seeds']} seeds, drone-stereo-back-imu, 6 s at 20 Hz, level "
             f"{r['level']}, changed camera {r['changed_camera']}", "",
             "| case | right status | exit 1 | another camera flagged | size within 2 sigma | check s (median) |",
             "|---|---|---|---|---|---|"]
    for name, s in r["summary"].items():
        w = "-" if s["within_2_sigma"] is None else f"{100 * s['within_2_sigma']:.0f} %"
        lines.append(f"| {name} | {100 * s['flagged_right']:.0f} % | {100 * s['any_flagged']:.0f} % | "
                     f"{100 * s['other_camera_flagged']:.0f} % | {w} | {s['check_s']:.1f} |")
    pb = r["summary"]["unchanged"]["p_below"]
    lines += ["", "Unchanged rig, every single test's p-value: " + ", ".join(
        f"{100 * v:.0f} % below {k}" for k, v in pb.items())]
    return "\n".join(lines)


def sigma_seed(seed: int, frames: int, work: Path, truth) -> dict:
    """Where the p-value tail comes from: per camera, the intrinsics error against the truth
    over its 1-sigma, of the rig (its calibration.sigma.intrinsics) and of the new estimate
    (estimate_rig's covariance) of an unchanged recording, each alone. Honest sigmas give
    z-scores of unit RMS."""
    from rigcal.check import inputs
    from rigcal.check.estimate import determined, estimate_rig, with_subset

    cal = calibrated_rig(truth, work, 30, 1000 + seed)
    rec_path = record(truth, work / "new", frames, 2000 + seed)
    rig = inputs.load_calibrated_rig(cal)
    rec = inputs.read_recording(rec_path, rig, cal, 1)
    names, _ = determined(rec.views, rig)
    est = estimate_rig(rec.views, with_subset(rig, names), rec.corners, rec.faces)
    keys = ("fx", "fy", "cx", "cy")
    out = {"z_rig": [], "z_new": [], "sigma_px_new": est.sigma_px}
    for c, n in enumerate(est.names):
        true = truth.camera(n).intrinsics
        t = np.array([true.fx, true.fy, true.cx, true.cy])
        m = rig.camera(n).intrinsics
        s_rig = rig.camera(n).calibration["sigma"].get("intrinsics", {})
        new = est.state.intrinsics[c].values[:4]
        s_new = np.sqrt(np.clip(np.diag(est.cov_intrinsics[c])[:4], 0, None))
        for j, k in enumerate(keys):
            if float(s_rig.get(k, 0.0)) > 0:
                out["z_rig"].append(float(([m.fx, m.fy, m.cx, m.cy][j] - t[j]) / float(s_rig[k])))
            if s_new[j] > 0:
                out["z_new"].append(float((new[j] - t[j]) / s_new[j]))
    # the pose tests, leave one out: the rig's error alone (rig vs truth, the rig's variances
    # only), the new estimate's alone (new vs truth, its covariance only) and the check's
    # (new vs rig, both), each with the rig's variances as reported (independent) and with
    # the independent errors behind them (decide.gauge_free_variances): chi-square(6) each
    from rigcal.check import decide
    from rigcal.check.verdict import pose_variances, relative_pose_variances

    T_rig = np.array([rig.camera(n).T_body_cam for n in est.names])
    T_true = np.array([truth.camera(n).T_body_cam for n in est.names])
    variances = {"reported": pose_variances(rig, list(est.names)),
                 "gauge_free": relative_pose_variances(rig, list(est.names))}
    zero_new = np.zeros_like(est.cov_poses)
    C = len(est.names)
    for i in range(C):
        others = [j for j in range(C) if j != i]
        d_new = decide.aligned_delta(est.T_body_cam, T_true, i, others)
        cov_new = decide.delta_covariance(est.state.T_cam_body, est.cov_poses, T_true, np.zeros((C, 6)), i, others)
        out.setdefault("stat_new_alone", []).append(decide.chi2_test(d_new, cov_new)[0])
        for key, var in variances.items():
            d_rig = decide.aligned_delta(T_rig, T_true, i, others)
            cov_rig = decide.delta_covariance(est.state.T_cam_body, zero_new, T_true, var, i, others)
            out.setdefault(f"stat_rig_alone_{key}", []).append(decide.chi2_test(d_rig, cov_rig)[0])
            d = decide.aligned_delta(est.T_body_cam, T_rig, i, others)
            cov = decide.delta_covariance(est.state.T_cam_body, est.cov_poses, T_rig, var, i, others)
            out.setdefault(f"stat_check_{key}", []).append(decide.chi2_test(d, cov)[0])
    return out


def run_sigmas(seeds: int, frames: int, first: int = 0) -> dict:
    truth = true_rig(1)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-check-sigmas-") as tmp:
        for s in range(first, first + seeds):
            rows.append(sigma_seed(s, frames, Path(tmp), truth))
            say(f"check --sigmas: seed {s}: {json.dumps(rows[-1])}")
    summary = {}
    for key in ("z_rig", "z_new"):
        z = np.concatenate([r[key] for r in rows])
        summary[key] = {"n": int(len(z)), "rms": float(np.sqrt(np.mean(z ** 2))),
                        "beyond_2": float(np.mean(np.abs(z) > 2)), "beyond_3": float(np.mean(np.abs(z) > 3))}
    from scipy import stats

    for key in [k for k in rows[0] if k.startswith("stat_")]:
        x = np.concatenate([r[key] for r in rows])
        p = stats.chi2.sf(x, 6)
        summary[key] = {"n": int(len(x)), "mean_over_dof": float(np.mean(x) / 6),
                        **{f"p_below_{a}": float(np.mean(p < a)) for a in (0.01, 0.05, 0.2, 0.5)}}
    return {"seeds": seeds, "first_seed": first, "frames": frames, "summary": summary, "per_seed": rows}


def run(seeds: int = 10, frames: int = 20, first: int = 0) -> dict:
    truth = true_rig(1)
    per_seed = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-check-") as tmp:
        for s in range(first, first + seeds):
            per_seed.append(one_seed(s, frames, Path(tmp), truth))
            say(f"check: seed {s} ({len(per_seed)}/{seeds}) done ({time.perf_counter() - t0:.0f} s)")
    return summarise(per_seed, frames, time.perf_counter() - t0, first)


def summarise(per_seed: list[dict], frames: int, seconds: float, first: int = 0) -> dict:
    """The rates over seeds (per_seed: one_seed's answers), as run() returns them."""
    seeds = len(per_seed)
    summary = {}
    for name in CASES:
        rows = [p[name] for p in per_seed]
        n = len(rows)
        summary[name] = {
            "seeds": n,
            "flagged_right": sum(r["right"] for r in rows) / n,
            "any_flagged": sum(r["exit"] == 1 for r in rows) / n,
            "changed_camera_flagged": sum(r["status"] != "ok" for r in rows) / n,
            "other_camera_flagged": sum(bool(r["others_flagged"]) for r in rows) / n,
            "within_2_sigma": (sum(r.get("within_2_sigma", False) for r in rows) / n) if "size" in rows[0] else None,
            "time_over_detection": float(np.median([r["seconds"] / r["detection_s"] for r in rows])),
        }
    p = np.concatenate([r["unchanged"]["p_values"] for r in per_seed])
    summary["unchanged"]["p_below"] = {str(a): float(np.mean(p < a)) for a in (0.01, 0.05, 0.2, 0.5)}
    return {"seeds": seeds, "first_seed": first, "frames": frames, "level": LEVEL, "changed_camera": CHANGED,
            "summary": summary, "per_seed": per_seed, "seconds": seconds}


def tables(r: dict) -> str:
    lines = [f"### rigcal check: {r['seeds']} seeds x {r['frames']} frames, drone-stereo-back, level {r['level']}, "
             f"changed camera {r['changed_camera']}", "",
             "| case | right status | exit 1 (any camera flagged) | changed camera flagged | another camera flagged | "
             "size within 2 sigma | check time / detection time (median) |", "|---|---|---|---|---|---|---|"]
    for name, s in r["summary"].items():
        if name == "unchanged":
            pb = s["p_below"]
            tail = ", ".join(f"{100 * v:.0f} % below {k}" for k, v in pb.items())
            lines_p = f"Unchanged rig, every single test's p-value (uniform when the sigmas are honest): {tail}"
        w = "-" if s["within_2_sigma"] is None else f"{100 * s['within_2_sigma']:.0f} %"
        lines.append(f"| {name} | {100 * s['flagged_right']:.0f} % | {100 * s['any_flagged']:.0f} % | "
                     f"{100 * s['changed_camera_flagged']:.0f} % | "
                     f"{100 * s['other_camera_flagged']:.0f} % | {w} | {s['time_over_detection']:.2f} |")
    return "\n".join(lines + ["", lines_p])


def residual_png(rig_path: Path, dataset: Path, out: Path, scale: float = 20.0) -> None:
    """docs/check_residuals.png: per camera (side by side) the new views' corners and, drawn
    `scale` times longer, where the rig's calibration misses them (report.residual_figure's
    content, drawn with OpenCV)."""
    import cv2

    from rigcal.check import inputs
    from rigcal.check.estimate import determined, estimate_rig, with_subset
    from rigcal.check.run import old_residuals
    from rigcal.check.verdict import verdicts
    from rigcal.check.estimate import structure

    rig = inputs.load_calibrated_rig(rig_path)
    rec = inputs.read_recording(dataset, rig, rig_path, 1)
    names, missing = determined(rec.views, rig)
    est = estimate_rig(rec.views, with_subset(rig, names), rec.corners, rec.faces)
    vs, _, _, keep = verdicts(rig, est, {n: structure(rig.camera(n).calibration) for n in names}, missing, LEVEL)
    r = old_residuals(rig, est, keep)
    panels = []
    for c, name in enumerate(est.names):
        m = rig.camera(name).intrinsics
        img = np.full((m.height + 40, m.width, 3), 255, np.uint8)
        sel = est.obs.cam == c
        uv, e = est.obs.uv[sel], r[sel]
        for (u, v), (du, dv) in zip(uv, e):
            p0 = (int(round(u - scale * du)), int(round(v - scale * dv + 40)))
            cv2.arrowedLine(img, p0, (int(round(u)), int(round(v + 40))), (60, 60, 200), 1, cv2.LINE_AA,
                            tipLength=0.25)
            cv2.circle(img, (int(round(u)), int(round(v + 40))), 1, (0, 0, 0), -1)
        cv2.rectangle(img, (0, 40), (m.width - 1, m.height + 39), (0, 0, 0), 1)
        rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
        status = next(v.status for v in vs if v.name == name)
        cv2.putText(img, f"{name}: {status}, RMS {rms:.3f} px (arrows x{scale:g})", (8, 26),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        panels.append(img)
    cv2.imwrite(str(out), np.hstack(panels))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--first", type=int, default=0, help="the first seed (runs first .. first + seeds - 1)")
    ap.add_argument("--indie", type=int, default=0, help="also this many seeds of the independent renderer")
    ap.add_argument("--sigmas", type=int, default=0,
                    help="the intrinsics' errors over their sigmas, the rig's and the new estimate's, for this many "
                         "seeds (and stop)")
    ap.add_argument("--imu", type=int, default=0, help="the camera-IMU cases for this many seeds (and stop)")
    ap.add_argument("--figure", nargs=3, metavar=("RIG", "DATASET", "PNG"),
                    help="draw the residual maps of one check (docs/check_residuals.png) and stop")
    a = ap.parse_args(argv)
    if a.figure:
        residual_png(Path(a.figure[0]), Path(a.figure[1]), Path(a.figure[2]))
        return
    if a.sigmas:
        r = run_sigmas(a.sigmas, a.frames, a.first)
        write_json("check_sigmas", r)
        say(json.dumps(r["summary"], indent=1))
        return
    if a.imu:
        r = run_imu(a.imu, a.first)
        write_json("check_imu" if a.first == 0 else f"check_imu_from_{a.first}", r)
        say(imu_tables(r))
        return
    if a.indie:
        with tempfile.TemporaryDirectory(prefix="rigcal-bench-check-indie-") as tmp:
            rows = []
            for s in range(a.indie):
                rows.append(indie_seed(s, a.frames, Path(tmp)))
                say(f"check --indie: seed {s}: {json.dumps(rows[-1])}")
        write_json("check_indie", {"seeds": a.indie, "frames": a.frames, "per_seed": rows})
        say(json.dumps(rows, indent=1))
        return
    r = run(a.seeds, a.frames, a.first)
    write_json("check" if a.first == 0 else f"check_from_{a.first}", r)
    say(tables(r))


if __name__ == "__main__":
    main()
