"""Accuracy against truth: simulate (seeded) -> detect -> calibrate -> compare.

For each scenario (rigs/drone-stereo-back room 60 frames, stereo-forward board 40,
surround-6 room 60, fisheye-stereo board 40), seed 0: per camera pair the relative
rotation / translation error of the calibrated rig next to the Cramér-Rao bound of
the same corners (at the measured corner noise) and next to the DECLARED rig's error
(what you get without calibrating); per camera the focal error; stereo baseline
errors; reprojection RMS against the measured corner noise; detection, solver and
total times. Calibration is what `rigcal calibrate` does by default (--distortion auto,
--guided auto: the fisheye pair's corners are re-measured once the rig is solved).

    python -m bench.accuracy [--scenario NAME ...]
"""

from __future__ import annotations

import argparse
import time

from rigcal.camcal.bounds import measured_corner_noise

from .common import (JOBS, SCENARIOS, Timer, calibrate_dataset, crb_pairs, get_dataset, md_table, rig_errors, say, scenario,
                     write_json)


def run_scenario(scn, seed: int = 0, log=say) -> dict:
    ds = get_dataset(scn, seed, keep_images=True, log=log)
    with Timer() as t:
        cal = calibrate_dataset(ds, jobs=JOBS)
    noise = measured_corner_noise(cal, ds.truth)
    bounds, weak_frames = crb_pairs(cal, ds.truth, noise) if noise is not None else ({}, 0)
    est = rig_errors(cal.rig, ds.truth.rig)
    declared = rig_errors(ds.rig, ds.truth.rig)
    pairs = {}
    for k, e in est["pairs"].items():
        b = bounds.get(tuple(k.split("/")), {})
        d = declared["pairs"].get(k, {})
        pairs[k] = {**e, "bound_rot_deg": b.get("rot_deg"), "bound_trans_mm": b.get("trans_mm"),
                    "declared_rot_deg": d.get("rot_deg"), "declared_trans_mm": d.get("trans_mm")}
    cams = {}
    for n, e in est["cameras"].items():
        d = declared["cameras"][n]
        cams[n] = {"focal_rel_pct": e["focal_rel_pct"], "proj_rms_px": e["proj_rms_px"],
                   "rot_deg": e.get("rot_deg"), "pos_mm": e.get("pos_mm"),
                   "declared_focal_rel_pct": d["focal_rel_pct"], "declared_proj_rms_px": d["proj_rms_px"],
                   "model": cal.stats[n].distortion_model, "rms_px": cal.stats[n].rms_px,
                   "intrinsics_model": cal.stats[n].intrinsics_model,
                   "observations": cal.stats[n].observations, "outliers": cal.stats[n].outliers}
    stereo = {k: {**e, "declared_error_mm": declared["stereo"].get(k, {}).get("error_mm")}
              for k, e in est["stereo"].items()}
    n_corners = int(sum(len(v.ids) for v in ds.views))
    return {
        "scenario": scn.name, "scene": scn.scene, "frames": scn.frames, "seed": seed,
        "cameras": len(ds.rig.cameras), "images": ds.n_images, "views": len(ds.views), "corners": n_corners,
        "render_s": ds.sim_s, "detection_s": ds.det_s, "detection_cached": ds.cached,
        "detection_images_per_s": ds.det_rate,
        "calibration_s": t.wall, "calibration_cpu_s": t.cpu, "solver_s": cal.timings["solve_s"],
        "intrinsics_s": cal.timings["intrinsics_s"], "guided_s": cal.timings.get("guided_s"),
        "total_s": ds.det_s + t.wall,
        "reprojection_rms_px": cal.rms_px, "residual_sigma_px": cal.sigma_px, "measured_corner_noise_px": noise,
        "inliers": int(cal.inliers.sum()), "outliers": int((~cal.inliers).sum()),
        "sigma_reported": all(st.sigma_position_mm is not None for st in cal.stats.values()),
        "frames_left_with_under_4_corners": weak_frames,
        "pairs": pairs, "cameras_detail": cams, "stereo": stereo, "notes": cal.notes,
    }


def run(names: list[str] | None = None, log=say) -> list[dict]:
    out = []
    for scn in (SCENARIOS if not names else [scenario(n) for n in names]):
        log(f"accuracy: {scn.name} ...")
        out.append(run_scenario(scn, log=log))
    return out


def tables(results: list[dict]) -> str:
    rows = []
    for r in results:
        models = sorted({c["model"] for c in r["cameras_detail"].values()})
        rows.append([r["scenario"], f"{r['scene']} {r['frames']}", r["images"], r["views"], r["corners"],
                     r["reprojection_rms_px"], r["measured_corner_noise_px"], "/".join(models),
                     "yes" if r["sigma_reported"] else "NO", r["detection_s"], r["solver_s"], r.get("guided_s"),
                     r["calibration_s"], r["total_s"]])
    parts = [md_table(["scenario", "scene, frames", "images", "views", "corners", "reproj RMS px (2D)",
                       "corner noise px (per axis)", "model (auto)", "sigma in YAML", "detection s", "solver s",
                       "guided pass s", "calibration s", "total s"],
                      rows, "Accuracy scenarios (seed 0): run summary")]
    rows = []
    for r in results:
        for k, p in r["pairs"].items():
            rows.append([r["scenario"], k, p["distance_m"], p["rot_deg"], p["bound_rot_deg"], p["trans_mm"],
                         p["bound_trans_mm"], p["declared_rot_deg"], p["declared_trans_mm"]])
    parts.append(md_table(["scenario", "pair", "dist m", "rot err deg", "CRB deg", "trans err mm", "CRB mm",
                           "declared rot deg", "declared trans mm"], rows,
                          "Per camera pair: calibrated error, Cramér-Rao bound (one seed), declared rig's error"))
    rows = []
    for r in results:
        for n, c in r["cameras_detail"].items():
            rows.append([r["scenario"], n, c["model"], c["focal_rel_pct"], c["declared_focal_rel_pct"],
                         c["proj_rms_px"], c["declared_proj_rms_px"], c["rms_px"], c["outliers"]])
    parts.append(md_table(["scenario", "camera", "model", "focal err %", "declared focal err %",
                           "projection diff px", "declared projection diff px", "reproj RMS px", "outliers"], rows,
                          "Per camera: intrinsics (projection diff = RMS pixel distance of the same rays over "
                          "the image)"))
    rows = []
    for r in results:
        for k, s in r["stereo"].items():
            rows.append([r["scenario"], k, 1000 * s["true_baseline_m"], s["error_mm"], s["declared_error_mm"]])
    if rows:
        parts.append(md_table(["scenario", "stereo pair", "true baseline mm", "calibrated err mm",
                               "declared err mm"], rows, "Stereo baselines"))
    return "\n".join(parts)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", action="append", help="one of: " + ", ".join(s.name for s in SCENARIOS))
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = run(a.scenario)
    say(tables(res))
    write_json("accuracy", {"results": res, "seconds": time.perf_counter() - t0})


if __name__ == "__main__":
    main()
