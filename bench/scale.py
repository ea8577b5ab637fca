"""Scale: solver time and memory for 6 cameras and many frames (target: 6 x 500 < 30 s).

Peak memory per corner (target: <= 1 kB) is the process's peak RSS over the corners; the
table also gives it above the RSS before calibrating (interpreter, libraries, the views).

Detections are synthetic (exact projections of four wall boards around rigs/surround-6
plus 0.1 px Gaussian noise, rigcal.sim.synthetic.room_scene): rendering 3000 images would
measure the renderer, not the solver. Each size runs in its own process so the peak
resident memory (ru_maxrss) belongs to that calibration alone.

    python -m bench.scale [--frames 100 200 500 1000]
    python -m bench.scale --one 500          # one size, JSON on stdout
"""

from __future__ import annotations

import resource

import numpy as np

import rigcal
from rigcal.sim.synthetic import room_scene, with_noise

from .common import RIGS, Timer, calibrate, md_table, perturbed_truth, rig_errors, run_sizes, say, sizes_main

FRAMES = (100, 200, 500, 1000)
SIGMA_PX = 0.1


def one(frames: int) -> dict:
    rig = rigcal.load_rig(RIGS / "surround-6.yaml")
    truth_rig = perturbed_truth(rig, 0)
    sc = room_scene(truth_rig, np.random.default_rng([frames, 5]), frames)
    views = with_noise(sc.views, SIGMA_PX, np.random.default_rng([frames, 6]))
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with Timer() as t:
        cal = calibrate(views, rig, sc.corners)
    e = rig_errors(cal.rig, truth_rig)
    return {"frames": frames, "cameras": len(rig.cameras), "views": len(views),
            "corners": int(sum(len(v.ids) for v in views)), "calibration_s": t.wall, "calibration_cpu_s": t.cpu,
            "intrinsics_s": cal.timings["intrinsics_s"], "graph_s": cal.timings["graph_s"],
            "solver_s": cal.timings["solve_s"], "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "rss_before_mb": rss_before, "max_pair_trans_err_mm": max(p["trans_mm"] for p in e["pairs"].values()),
            "max_pair_rot_err_deg": max(p["rot_deg"] for p in e["pairs"].values()),
            "models": [cal.stats[n].distortion_model for n in cal.cam_names]}


def run(frames=FRAMES, log=say) -> list[dict]:
    return run_sizes("bench.scale", frames, log, "scale: 6 cameras")


def tables(res: list[dict]) -> str:
    rows = []
    base = res[0]
    for r in res:
        rows.append([r["frames"], r["views"], r["corners"], r["solver_s"], r["intrinsics_s"] + r["graph_s"],
                     r["calibration_s"], r["calibration_cpu_s"],
                     r["solver_s"] / base["solver_s"] / (r["frames"] / base["frames"]), r["peak_rss_mb"],
                     r["peak_rss_mb"] * 2**20 / r["corners"], (r["peak_rss_mb"] - r["rss_before_mb"]) * 2**20 / r["corners"],
                     r["max_pair_trans_err_mm"], r["max_pair_rot_err_deg"],
                     f"{sum(m == 'radial2' for m in r['models'])}/{len(r['models'])}"])
    return md_table(["frames", "views", "corners", "solver s", "init s", "calibration s", "calibration CPU s",
                     "solver s per frame vs first", "peak RSS MB", "peak bytes per corner",
                     "bytes per corner above the data's", "max pair trans err mm", "max pair rot err deg",
                     "cameras fitted radial2 (truth has p1, p2)"], rows,
                    "Scale: 6 cameras (surround-6), synthetic detections (0.1 px noise); targets 500 frames < 30 s, "
                    "peak memory <= 1 kB per corner")


def main(argv=None) -> None:
    sizes_main(argv, __doc__, FRAMES, one, run, tables, "scale")


if __name__ == "__main__":
    main()
