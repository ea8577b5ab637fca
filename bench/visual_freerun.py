"""Benchmark: free-running cameras without an IMU (rigcal.imucal.visual_motion) against a
synchronised camera-only recording of the same length.

Per seed, two recordings of drone-stereo-back-imu's three cameras (at 480x360 for render
time), the images only (no imu/, the rig without its IMU):

  synchronised   `simulate --scene imu --time-offset-ms 0`: every camera at 20 Hz on one stem
                 grid and one clock, so equal stems are one instant: the camera-only
                 calibration is exact there (the reference)
  free-running   `simulate --scene imu --free-running`: own phase, period error, jitter,
                 start and stop per camera, clocks offset by up to +-10 ms
  mixed-rate     (--cases; not run by default) free-running with front_left at 20 Hz,
                 front_right at 30 Hz and back at 15 Hz

then `rigcal calibrate` with its defaults, and every camera's pose relative to the
reference camera (the free-running estimate's clock camera; its pose put on the true one)
against truth.yaml: rotation (deg) and position (mm) errors; for free-running also the
camera-camera clock offsets (ms) and each component's error over its reported 1-sigma.
Target: relative extrinsics no worse than 2x the synchronised recording's; offsets
<= 0.1 ms.

    python -m bench.visual_freerun [--seeds N] [--duration S] [--cases NAME ...] [--reuse]
    python -m bench.visual_freerun --euroc SECONDS   (real motion: euroc())
    python -m bench.visual_freerun --corners SEEDS   (projected corners, a camera sharing no board)
    python -m bench.visual_freerun --limits SEED [--draws N] [--duration S] [--motion-scale X]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import os
import shutil
import subprocess
import sys

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig
from rigcal.data.truth import load_truth

from .common import JOBS, OUT, RIGS, Timer, md_table, say, write_json

RIG = RIGS / "drone-stereo-back-imu.yaml"
CASES = {"synchronised": ("--time-offset-ms", "0"), "free-running": ("--free-running",),
         "mixed-rate": ("--free-running", "--camera-rate", "front_left=20", "--camera-rate", "front_right=30",
                        "--camera-rate", "back=15")}
DEFAULT_CASES = ("free-running", "synchronised")
WORK = OUT / "visual_freerun"


def _rigcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rigcal", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "250"})


def _small_rig() -> str:
    """drone-stereo-back-imu at 480x360 (renders about 2x faster than 640x480)."""
    return RIG.read_text().replace("[640, 480]", "[480, 360]").replace(
        "{fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}", "{fx: 225.0, fy: 225.0, cx: 240.0, cy: 180.0}")


def _without_imu(text: str) -> str:
    return text[:text.index("imus:")] + text[text.index("cameras:"):]


def relative_errors(est, truth, ref: str) -> dict:
    """Per camera but `ref`: (rotation error deg (3,) about body axes, position error mm (3,),
    clock offset error ms) relative to camera `ref`, the estimate's `ref` put on the true one."""
    A = truth.camera(ref).T_body_cam @ geo.inv_T(est.camera(ref).T_body_cam)
    out = {}
    for c in est.cameras:
        if c.name == ref:
            continue
        T, Tt = A @ c.T_body_cam, truth.camera(c.name).T_body_cam
        true_off = truth.camera(c.name).time_offset_s - truth.camera(ref).time_offset_s
        out[c.name] = (np.degrees(geo.rotvec_from_R(T[:3, :3] @ Tt[:3, :3].T)), 1000 * (T[:3, 3] - Tt[:3, 3]),
                       1000 * ((c.time_offset_s or 0.0) - true_off))
    return out


def one(case: str, seed: int, duration: float, log=say, reuse: bool = False) -> dict:
    """One case and seed: simulate (kept), strip the IMU, calibrate, score."""
    tag = f"{case}_{duration:g}s_seed{seed}"
    kept = WORK / f"scores_{tag}.json"
    if reuse and kept.is_file():
        return json.loads(kept.read_text())
    sim, d = WORK / f"sim_{tag}", WORK / tag
    WORK.mkdir(parents=True, exist_ok=True)
    rig = WORK / "rig.yaml"
    rig.write_text(_small_rig())
    if not (sim / "truth.yaml").is_file():
        with Timer() as t:
            r = _rigcal("simulate", str(rig), "--out", str(sim), "--scene", "imu", "--duration", f"{duration:g}",
                        "--seed", str(seed), "--jobs", str(JOBS), "--force", *CASES[case])
        if r.returncode != 0:
            raise RuntimeError(f"rigcal simulate failed: {r.stderr.strip()[-2000:]}")
        log(f"  {case} seed {seed}: simulated in {t.wall:.0f} s")
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    shutil.copytree(sim / "images", d / "images")
    shutil.copy(sim / "target.yaml", d / "target.yaml")
    (d / "rig.yaml").write_text(_without_imu((sim / "rig.yaml").read_text()))
    out = WORK / f"calibrated_{tag}.yaml"
    with Timer() as t:
        r = _rigcal("calibrate", str(d), "--out", str(out), "--jobs", str(JOBS))
    if r.returncode != 0:
        raise RuntimeError(f"rigcal calibrate failed ({r.returncode}): {r.stderr.strip()[-2000:]}")
    est, truth = load_rig(out), load_truth(sim / "truth.yaml").rig
    fr = (est.calibration or {}).get("free_running")
    ref = fr["clock"].split(":", 1)[1] if fr else _reference_of(case, seed, duration)
    errs = relative_errors(est, truth, ref)
    res = {"case": case, "seed": seed, "wall_s": t.wall, "reference": ref, "cameras": {}}
    for name, (dr, dp, do) in errs.items():
        e = {"rot_deg": float(np.linalg.norm(dr)), "pos_mm": float(np.linalg.norm(dp)), "offset_ms": float(do)}
        if fr:
            s = est.camera(name).calibration["sigma"]
            e["z"] = [*(dr / np.array(s["rotation_deg"])).tolist(), *(dp / np.array(s["position_mm"])).tolist(),
                      do / s["time_offset_ms"]]
        res["cameras"][name] = e
    kept.write_text(json.dumps(res))
    log(f"  {case} seed {seed}: calibrate {t.wall:.0f} s; relative to {ref}: "
        + "; ".join(f"{n} {e['rot_deg']:.4f} deg {e['pos_mm']:.3f} mm"
                    + (f" {e['offset_ms']:+.4f} ms" if fr else "") for n, e in res["cameras"].items()))
    return res


def _reference_of(case: str, seed: int, duration: float) -> str:
    """The synchronised case scores relative to the free-running run's reference camera of
    the same seed (run first), else the first camera."""
    p = WORK / f"scores_free-running_{duration:g}s_seed{seed}.json"
    return json.loads(p.read_text())["reference"] if p.is_file() else "front_left"


def run(seeds: int = 3, duration: float = 10.0, log=say, reuse: bool = False, cases=DEFAULT_CASES) -> dict:
    # free-running first: the synchronised case scores relative to its reference camera
    cases = sorted(cases, key=lambda c: c == "synchronised")
    return {"duration_s": duration, "seeds": seeds,
            "runs": [one(c, s, duration, log, reuse) for s in range(seeds) for c in cases]}


def summary(res: dict) -> dict:
    out = {}
    for case in [c for c in ("synchronised", *CASES) if any(r["case"] == c for r in res["runs"])]:
        if case in out:
            continue
        e = [c for r in res["runs"] if r["case"] == case for c in r["cameras"].values()]
        row = {"cameras": len(e), "rot_deg_rms": float(np.sqrt(np.mean([x["rot_deg"] ** 2 for x in e]))),
               "rot_deg_max": max(x["rot_deg"] for x in e),
               "pos_mm_rms": float(np.sqrt(np.mean([x["pos_mm"] ** 2 for x in e]))),
               "pos_mm_max": max(x["pos_mm"] for x in e)}
        if case != "synchronised":
            z = np.abs(np.concatenate([x["z"] for x in e]))
            row.update(offset_ms_max=max(abs(x["offset_ms"]) for x in e), within_2_sigma=float(np.mean(z <= 2)),
                       components=int(z.size))
        out[case] = row
    return out


def tables(res: dict) -> str:
    s = summary(res)
    rows = [[case, r["cameras"], f"{r['rot_deg_rms']:.4f} / {r['rot_deg_max']:.4f}",
             f"{r['pos_mm_rms']:.3f} / {r['pos_mm_max']:.3f}",
             f"{r['offset_ms_max']:.4f}" if "offset_ms_max" in r else "-",
             f"{100 * r['within_2_sigma']:.0f} % of {r['components']}" if "components" in r else "-"]
            for case, r in s.items()]
    base = s.get("synchronised")
    ratios = "; ".join(f"{case} / synchronised RMS: rotation {r['rot_deg_rms'] / base['rot_deg_rms']:.2f}x, "
                       f"position {r['pos_mm_rms'] / base['pos_mm_rms']:.2f}x"
                       for case, r in s.items() if case != "synchronised" and base)
    return md_table(["case", "camera-seeds", "relative rot deg (RMS / max)", "relative pos mm (RMS / max)",
                     "|clock offset| ms max", "within 2 sigma"], rows,
                    title=f"`rigcal calibrate` without an IMU on {res['duration_s']:g} s rendered recordings of "
                          f"drone-stereo-back-imu's cameras, {res['seeds']} seeds: poses relative to the reference "
                          f"camera against truth.yaml ({ratios}; target <= 2x, offsets <= 0.1 ms)")


def euroc(seconds: float = 30.0, log=say) -> dict | None:
    """Real motion: EuRoC imu_april's stereo corners (hardware-synchronised, 20 Hz) made
    free-running by keeping cam0's even frames and cam1's odd ones (10 Hz each, 50 ms
    apart; the cameras' true clock offset is 0), the first `seconds`: the camera-only
    calibration of all frames (synchronised), of the images grouped by time (the start),
    and the continuous-time estimate, each camera pair against EuRoC's published cam0-cam1
    pose (Kalibr's; baseline 110.07 mm). None when the shared data are absent."""
    from rigcal.camcal.pipeline import calibrate_views
    from rigcal.core.observations import BoardView
    from rigcal.imucal.visual_motion import calibrate_visual_motion

    from .imu_euroc import load

    data = load(log)
    if data is None:
        return None
    b = data.target.boards[0]
    T_BS = {c: np.array(data.reference[c]["T_BS"], float).reshape(4, 4) for c in ("cam0", "cam1")}
    ref = geo.inv_T(T_BS["cam0"]) @ T_BS["cam1"]
    frames = sorted({v.frame for v in data.views}, key=int)
    frames = [f for f in frames if (int(f) - int(frames[0])) * 1e-9 < seconds]
    index = {f: i for i, f in enumerate(frames)}
    sync = [v for v in data.views if v.frame in index]
    free, own = [], {"cam0": {}, "cam1": {}}
    for v in sync:
        i = index[v.frame]
        if v.camera == "cam0" and i % 2 == 0:
            free.append(v)
            own["cam0"][v.frame] = int(v.frame)
        elif v.camera == "cam1" and i % 2 == 1:  # grouped with cam0's image 50 ms before
            free.append(BoardView(v.camera, frames[i - 1], v.board, v.ids, v.uv))
            own["cam1"][frames[i - 1]] = int(v.frame)

    def score(T0, T1) -> dict:
        T = geo.inv_T(T0) @ T1
        return {"rot_deg": float(np.degrees(np.linalg.norm(geo.rotvec_from_R(T[:3, :3] @ ref[:3, :3].T)))),
                "pos_mm": float(1000 * np.linalg.norm(T[:3, 3] - ref[:3, 3])),
                "baseline_mm": float(1000 * np.linalg.norm(T[:3, 3]))}

    out = {"seconds": seconds}
    corners = {b.name: b.corners}
    with Timer() as t:
        cal_s = calibrate_views(sync, data.rig, corners, faces={b.name: b.print_face})
    out["synchronised"] = {**score(*(cal_s.rig.camera(c).T_body_cam for c in ("cam0", "cam1"))), "wall_s": t.wall,
                           "views": len(sync)}
    with Timer() as t:
        cal = calibrate_views(free, data.rig, corners, faces={b.name: b.print_face})
    out["grouped start"] = {**score(*(cal.rig.camera(c).T_body_cam for c in ("cam0", "cam1"))), "wall_s": t.wall,
                            "views": len(free)}
    with Timer() as t:
        vm = calibrate_visual_motion(cal, own)
    k = 1 - vm.reference
    T_sync = np.stack([cal_s.rig.camera(c).T_body_cam for c in ("cam0", "cam1")])
    T_eur = np.stack([T_BS["cam0"], T_BS["cam1"]])

    def in_sigmas(vm_, refs) -> dict:
        """Each component's error over its reported (and formal) 1-sigma against each reference."""
        z_ = {}
        for name, T_ref in refs:
            d_rot, d_pos = component_errors(vm_.T_body_cam, T_ref, vm_.reference, k)
            d = np.r_[d_rot, d_pos, vm_.time_offset_s[k]]  # the true clock offset is 0
            z_[name] = {"reported": (d / vm_.sigma[k]).tolist(), "formal": (d / vm_.formal_sigma[k]).tolist()}
        return z_

    z = in_sigmas(vm, (("EuRoC T_BS", T_eur), ("synchronised", T_sync)))
    # EuRoC's published intrinsics held (the camera calibration the Kalibr and basalt workflows start from)
    from dataclasses import replace

    held_rig = data.rig.with_cameras([replace(c, intrinsics=c.intrinsics.with_(
        **dict(zip(("fx", "fy", "cx", "cy"), data.reference[c.name]["intrinsics"])),
        dist=tuple(data.reference[c.name]["distortion"]) + (0.0,) * (len(c.intrinsics.dist) - 4)))
        for c in data.rig.cameras])
    cal_sh = calibrate_views(sync, held_rig, corners, faces={b.name: b.print_face}, fix_intrinsics=True)
    cal_h = calibrate_views(free, held_rig, corners, faces={b.name: b.print_face}, fix_intrinsics=True)
    with Timer() as t_h:
        vm_h = calibrate_visual_motion(cal_h, own, hold_intrinsics=True)
    z_held = in_sigmas(vm_h, (("EuRoC T_BS", T_eur),
                              ("synchronised", np.stack([cal_sh.rig.camera(c).T_body_cam for c in ("cam0", "cam1")]))))
    out["free-running"] = {**score(*vm.T_body_cam), "wall_s": t.wall, "views": len(free),
                           "offset_ms": float(1000 * vm.time_offset_s[k]),
                           "offset_sigma_ms": float(1000 * vm.sigma[k, 6]),
                           "knot_spacing_s": vm.knot_dt, "knots_tried": [list(x) for x in vm.knots_tried],
                           "corner_rms_px": vm.corner_rms_px,
                           "sigma_rot_deg": np.degrees(vm.sigma[k, :3]).tolist(),
                           "sigma_pos_mm": (1000 * vm.sigma[k, 3:6]).tolist(),
                           "formal_sigma_rot_deg": np.degrees(vm.formal_sigma[k, :3]).tolist(),
                           "formal_sigma_pos_mm": (1000 * vm.formal_sigma[k, 3:6]).tolist(),
                           "sigma_source": "formal" if vm.subsets is None or not vm.subsets.compared[k]
                           else vm.subsets.source(k),
                           "subsets_line": None if vm.subsets is None else vm.subsets.line(["cam0", "cam1"]),
                           "z": z}
    out["free-running, EuRoC intrinsics held"] = {
        **score(*vm_h.T_body_cam), "wall_s": t_h.wall, "views": len(free),
        "offset_ms": float(1000 * vm_h.time_offset_s[k]), "offset_sigma_ms": float(1000 * vm_h.sigma[k, 6]),
        "sigma_source": "formal" if vm_h.subsets is None or not vm_h.subsets.compared[k] else vm_h.subsets.source(k),
        "subsets_line": None if vm_h.subsets is None else vm_h.subsets.line(["cam0", "cam1"]), "z": z_held}
    log(f"  euroc {seconds:g} s: " + "; ".join(f"{n} {r['rot_deg']:.3f} deg {r['pos_mm']:.2f} mm"
                                               for n, r in out.items() if n != "seconds"))
    return out


def component_errors(T_est: np.ndarray, T_ref: np.ndarray, g: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(rotation rad (3,) about body axes, position m (3,)) of camera k's estimated pose
    against T_ref's, the estimate's reference camera g put on T_ref's (its pose is held)."""
    A = T_ref[g] @ geo.inv_T(T_est[g])
    T = A @ T_est[k]
    return geo.rotvec_from_R(T[:3, :3] @ T_ref[k][:3, :3].T), T[:3, 3] - T_ref[k][:3, 3]


def z_table(res: dict) -> str:
    """The free-running estimate's errors (rotation about F L U, position along F L U, clock
    offset) over its reported and its formal 1-sigma, against EuRoC's T_BS and against the
    synchronised calibration of all frames."""
    rows = [[case, ref, which, " ".join(f"{x:+.1f}" for x in v[which][:3]),
             " ".join(f"{x:+.1f}" for x in v[which][3:6]), f"{v[which][6]:+.1f}",
             f"{100 * np.mean(np.abs(v[which]) <= 2):.0f} %"]
            for case, fr in res.items() if isinstance(fr, dict) and "z" in fr
            for ref, v in fr["z"].items() for which in ("reported", "formal")]
    lines = "; ".join(f"{case}: {fr['subsets_line']}" for case, fr in res.items() if isinstance(fr, dict) and "z" in fr)
    return md_table(["case", "against", "sigma", "rotation F L U", "position F L U", "clock offset (truth 0)",
                     "within 2 sigma"], rows, title=f"cam1's errors over its 1-sigma ({lines})")


def corners_case(seeds: int = 10, duration: float = 10.0, log=say) -> dict:
    """Projected corners (tests/support/imu_check_cases: 0.3 px noise, not rendered) of
    drone-stereo-back-imu's cameras, free-running at 20 Hz (simulate's schedule), no IMU, given
    as corners/<camera>.csv; `rigcal calibrate`'s run with its defaults; per seed a new true
    rig (mount, lens and clock errors drawn) and motion. Each non-reference camera's
    rotation, position and clock offset error relative to the reference camera over its
    reported and formal 1-sigma."""
    from rigcal.commands.calibrate import CalibrateOptions
    from rigcal.commands.calibrate import run as calibrate
    from tests.support.imu_check_cases import record, true_rig

    from rigcal.imucal import visual_motion

    real, made = visual_motion.calibrate_visual_motion, []

    def keep(*args, **kwargs):  # the estimate calibrate makes, for its formal sigmas
        made.append(real(*args, **kwargs))
        return made[-1]

    runs = []
    for seed in range(seeds):
        truth = true_rig(100 + seed, 3.0)
        d = WORK / f"corners_{duration:g}s_seed{seed}"
        record(truth, d, duration, 20.0, seed=seed, free_running=True, with_imu=False)
        out = WORK / f"corners_{duration:g}s_seed{seed}.yaml"
        visual_motion.calibrate_visual_motion = keep
        try:
            with Timer() as t:
                calibrate(d, out, CalibrateOptions(jobs=1))
        finally:
            visual_motion.calibrate_visual_motion = real
        vm = made[-1]
        est = load_rig(out)
        fr = est.calibration["free_running"]
        ref = fr["clock"].split(":", 1)[1]
        for name, (dr, dp, do) in relative_errors(est, truth, ref).items():
            c = est.camera(name)
            s = c.calibration["sigma"]
            rep = np.r_[s["rotation_deg"], s["position_mm"], s["time_offset_ms"]]
            f = vm.formal_sigma[[c_.name for c_ in est.cameras].index(name)]
            formal = np.r_[np.degrees(f[:3]), 1000 * f[3:6], 1000 * f[6]]
            runs.append({"seed": seed, "camera": name, "error": np.r_[dr, dp, do].tolist(), "sigma": rep.tolist(),
                         "formal": formal.tolist(), "source": c.calibration["sigma_source"], "wall_s": t.wall})
        log(f"  corners seed {seed}: {t.wall:.0f} s; " + "; ".join(
            f"{r['camera']} z {' '.join(f'{e / s:+.1f}' for e, s in zip(r['error'], r['sigma']))} ({r['source']})"
            for r in runs if r["seed"] == seed))
    z = np.abs(np.array([np.array(r["error"]) / np.array(r["sigma"]) for r in runs]))
    zf = np.abs(np.array([np.array(r["error"]) / np.array(r["formal"]) for r in runs]))
    return {"seeds": seeds, "duration_s": duration, "runs": runs, "within_2_sigma": float(np.mean(z <= 2)),
            "within_3_sigma": float(np.mean(z <= 3)), "components": int(z.size),
            "formal_within_2_sigma": float(np.mean(zf <= 2)), "formal_within_3_sigma": float(np.mean(zf <= 3)),
            "offset_ms_max": float(max(abs(r["error"][6]) for r in runs)),
            "subsets": sum(r["source"] == "subsets" for r in runs)}


def corners_limits(seed: int = 0, draws: int = 30, duration: float = 10.0, motion_scale: float = 1.0,
                   log=say) -> dict:
    """What limits corners_case's estimate on one seed's geometry: the same true rig, motion
    (its amplitudes x motion_scale) and views with the corners exact (no noise), `rigcal
    calibrate` on them, then `draws` re-estimates (from that solution) with 0.3 px of noise
    added to the exact corners, at the frame period's knot spacing (what calibrate chooses
    on the noisy corners of every corners_case seed). Per non-reference camera and component (rotation about and
    position along body F L U, clock offset), relative to the reference camera: the
    noise-free error, the draws' mean error and spread, and the formal 1-sigma at 0.3 px; and
    each clock offset's formal 1-sigma with parts of the problem held known (the Cramer-Rao
    bound with those parameters given): the trajectory, the boards' poses, the intrinsics,
    the camera's own pose."""
    from rigcal.commands.calibrate import CalibrateOptions
    from rigcal.commands.calibrate import run as calibrate
    from rigcal.imucal import estimator as ic
    from rigcal.imucal import residuals as ir
    from rigcal.imucal import visual_motion
    from tests.support.imu_check_cases import record, true_rig

    sigma_px = 0.3
    truth = true_rig(100 + seed, 3.0)
    d = WORK / f"limits_{duration:g}s_seed{seed}_x{motion_scale:g}"
    record(truth, d, duration, 20.0, seed=seed, free_running=True, with_imu=False, sigma_px=0.0,
           motion_scale=motion_scale)
    real, made = visual_motion.calibrate_visual_motion, []

    def keep(cal, image_t_ns, *args, **kwargs):
        made.append((cal, image_t_ns, real(cal, image_t_ns, *args, **kwargs)))
        return made[-1][2]

    # the knot spacing calibrate chooses on the noisy corners (the frame period on every seed of
    # corners_case); on exact corners a finer one fits the spline's own error better and is chosen
    fractions, visual_motion.KNOT_FRACTIONS = visual_motion.KNOT_FRACTIONS, (1.0,)
    visual_motion.calibrate_visual_motion = keep
    try:
        with Timer() as t:
            calibrate(d, WORK / f"{d.name}.yaml", CalibrateOptions(jobs=1))
    finally:
        visual_motion.calibrate_visual_motion, visual_motion.KNOT_FRACTIONS = real, fractions
    cal, image_t_ns, vm = made[-1]
    names, g, st0 = list(cal.cam_names), vm.reference, vm.state
    obs = visual_motion.views_of(cal, image_t_ns).corners
    models = [cal.rig.camera(n).intrinsics for n in names]
    lay = ir.layout_for(st0, visual_motion.HELD)
    ref_cols = np.r_[lay.cam + 6 * g + np.arange(6), lay.offset + g]

    def blocks_of(o):
        return lambda s: visual_motion._blocks(s, lay, o, models, sigma_px, ref_cols, vm.prior_sigma)

    Tt = np.stack([truth.camera(n).T_body_cam for n in names])
    off_t = np.array([truth.camera(n).time_offset_s for n in names])
    Rb = Tt[g, :3, :3]

    def errors(st) -> np.ndarray:
        """(C, 7) rotation (deg, body axes), position (mm), offset (ms) errors relative to camera g."""
        out = np.zeros((len(names), 7))
        for c in range(len(names)):
            Te, Tr = geo.inv_T(st.T_body_cam[g]) @ st.T_body_cam[c], geo.inv_T(Tt[g]) @ Tt[c]
            out[c, :3] = np.degrees(Rb @ geo.rotvec_from_R(Te[:3, :3] @ Tr[:3, :3].T))
            out[c, 3:6] = 1000 * Rb @ (Te[:3, 3] - Tr[:3, 3])
            out[c, 6] = 1000 * (st.time_offset_s[c] - (off_t[c] - off_t[g]))
        return out

    J, _ = ir.assemble(ir.normal_rows(blocks_of(obs)(st0)), lay.size)
    H = (J.T @ J).toarray()
    active = np.flatnonzero(np.diag(H) > 0)

    def sigma_of(cols, known=()) -> np.ndarray:
        keep_ = np.setdiff1d(active, np.asarray(list(known), int))
        cov = np.linalg.inv(H[np.ix_(keep_, keep_)])
        i = np.searchsorted(keep_, cols)
        return np.sqrt(cov[i, i])

    C = len(names)
    cols = np.concatenate([np.r_[lay.cam + 6 * c + np.arange(6), lay.offset + c] for c in range(C) if c != g])
    formal = np.zeros((C, 7))
    formal[np.arange(C) != g] = sigma_of(cols).reshape(C - 1, 7)
    formal[:, :3], formal[:, 3:6], formal[:, 6] = np.degrees(formal[:, :3]), 1000 * formal[:, 3:6], 1000 * formal[:, 6]
    parts = {"trajectory": range(0, lay.cam), "boards": range(lay.board, lay.intr),
             "intrinsics": range(lay.intr, lay.size)}
    rng = np.random.default_rng([seed, 35])
    errs = []
    with Timer() as t_mc:
        for _ in range(draws):
            o = replace(obs, uv=obs.uv + rng.normal(0.0, sigma_px, obs.uv.shape))
            errs.append(errors(ic.levenberg_marquardt(st0, lay, blocks_of(o), 60)[0]))
    errs = np.array(errs)
    w = np.array([np.linalg.norm(geo.rotvec_from_R(st0.spline.R[i].T @ st0.spline.R[i + 1]))
                  for i in range(len(st0.spline.R) - 1)]) / st0.spline.dt
    cams = {}
    for c, n in enumerate(names):
        if c == g:
            continue
        o = lay.offset + c
        nan = np.full(7, np.nan)
        cams[n] = {"noise_free_error": errors(st0)[c].tolist(),
                   "mean_error": (errs[:, c].mean(0) if draws > 0 else nan).tolist(),
                   "spread": (errs[:, c].std(0, ddof=1) if draws > 1 else nan).tolist(), "formal": formal[c].tolist(),
                   "offset_sigma_ms": {
                       "formal": 1000 * float(sigma_of([o])[0]),
                       **{f"{k} known": 1000 * float(sigma_of([o], v)[0]) for k, v in parts.items()},
                       "own pose known": 1000 * float(sigma_of([o], lay.cam + 6 * c + np.arange(6))[0])}}
    res = {"seed": seed, "duration_s": duration, "motion_scale": motion_scale, "draws": draws, "reference": names[g],
           "rms_angular_rate_deg_s": float(np.degrees(np.sqrt(np.mean(w ** 2)))), "knot_spacing_s": vm.knot_dt,
           "calibrate_s": t.wall, "draws_s": t_mc.wall, "cameras": cams}
    log(f"  limits seed {seed}: {duration:g} s x{motion_scale:g}, RMS rate {res['rms_angular_rate_deg_s']:.1f} deg/s; "
        f"calibrate {t.wall:.0f} s, {draws} draws {t_mc.wall:.0f} s")
    return res


def limits_table(res: dict) -> str:
    comp = ["rot F", "rot L", "rot U", "pos F", "pos L", "pos U", "offset"]
    rows = []
    for n, c in res["cameras"].items():
        for i, k in enumerate(comp):
            f = c["formal"][i]
            rows.append([n, k, f"{f:.4g}", f"{c['noise_free_error'][i] / f:+.2f}", f"{c['mean_error'][i] / f:+.2f}",
                         f"{c['spread'][i] / f:.2f}"])
    tab = md_table(["camera", "component", "formal 1-sigma (deg, mm, ms)", "noise-free error / sigma",
                    "draws' mean error / sigma", "draws' spread / sigma"], rows,
                   title=f"seed {res['seed']}, {res['duration_s']:g} s, motion x{res['motion_scale']:g} (RMS angular "
                         f"rate {res['rms_angular_rate_deg_s']:.1f} deg/s), {res['draws']} draws of 0.3 px, relative "
                         f"to {res['reference']}")
    off = md_table(["camera", *next(iter(res["cameras"].values()))["offset_sigma_ms"]],
                   [[n, *(f"{v:.4f}" for v in c["offset_sigma_ms"].values())] for n, c in res["cameras"].items()],
                   title="clock offset 1-sigma (ms) at 0.3 px, with parts held known")
    return tab + "\n\n" + off


def euroc_table(res: dict) -> str:
    rows = [[n, r["views"], f"{r['rot_deg']:.3f}", f"{r['pos_mm']:.2f}", f"{r['baseline_mm']:.2f}",
             f"{r['offset_ms']:+.3f} +- {r['offset_sigma_ms']:.3f}" if "offset_ms" in r else "-", f"{r['wall_s']:.0f}"]
            for n, r in res.items() if n != "seconds"]
    return md_table(["case", "views", "cam0-cam1 rot deg from EuRoC", "pos mm from EuRoC", "baseline mm (EuRoC 110.07)",
                     "clock offset ms (truth 0)", "wall s"], rows,
                    title=f"EuRoC imu_april's first {res['seconds']:g} s, cam0's even and cam1's odd frames "
                          f"(free-running, 10 Hz each), without the IMU")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--cases", nargs="+", choices=tuple(CASES), default=DEFAULT_CASES)
    ap.add_argument("--reuse", action="store_true", help="reuse the scores of earlier runs (same case, seed, duration)")
    ap.add_argument("--euroc", type=float, metavar="SECONDS", help="only the EuRoC case (euroc()) on its first SECONDS")
    ap.add_argument("--corners", type=int, metavar="SEEDS", help="only the projected-corners case (corners_case)")
    ap.add_argument("--limits", type=int, metavar="SEED", help="only corners_limits on this seed's geometry")
    ap.add_argument("--draws", type=int, default=30, help="--limits: noise draws")
    ap.add_argument("--motion-scale", type=float, default=1.0, help="--limits: the motion's amplitudes x this")
    a = ap.parse_args(argv)
    if a.limits is not None:
        res = corners_limits(a.limits, a.draws, a.duration, a.motion_scale)
        write_json(f"visual_freerun_limits_seed{a.limits}_{a.duration:g}s_x{a.motion_scale:g}", res)
        print(limits_table(res))
        return 0
    if a.corners:
        res = corners_case(a.corners, a.duration)
        write_json("visual_freerun_corners", res)
        print(f"{res['seeds']} seeds x {res['duration_s']:g} s: {100 * res['within_2_sigma']:.0f} % of "
              f"{res['components']} errors within 2 reported sigma, {100 * res['within_3_sigma']:.0f} % within 3 "
              f"(formal sigmas: {100 * res['formal_within_2_sigma']:.0f} % and "
              f"{100 * res['formal_within_3_sigma']:.0f} %); "
              f"max offset error {res['offset_ms_max']:.4f} ms; sigmas from subsets for {res['subsets']} of "
              f"{len(res['runs'])} cameras")
        return 0
    if a.euroc:
        res = euroc(a.euroc)
        if res is None:
            print("EuRoC's shared data are absent")
            return 1
        write_json("visual_freerun_euroc", res)
        print(euroc_table(res))
        print(z_table(res))
        return 0
    res = run(a.seeds, a.duration, reuse=a.reuse, cases=a.cases)
    write_json("visual_freerun", res)
    print(tables(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
