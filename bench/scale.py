"""Scale: solver time and memory for 6 cameras and many frames (issue 8; target 6 x 500 < 30 s).

Detections are synthetic (exact projections of four wall boards around rigs/surround-6
plus 0.1 px Gaussian noise, rigcal.synthetic.room_scene): rendering 3000 images would
measure the renderer, not the solver. Each size runs in its own process so the peak
resident memory (ru_maxrss) belongs to that calibration alone.

    python -m bench.scale [--frames 100 200 500 1000]
    python -m bench.scale --one 500          # one size, JSON on stdout
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys

import numpy as np

import rigcal
from rigcal.synthetic import room_scene, with_noise

from .common import ROOT, RIGS, Timer, calibrate, md_table, perturbed_truth, rig_errors, say, write_json

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
    out = []
    for n in frames:
        log(f"scale: 6 cameras x {n} frames ...")
        p = subprocess.run([sys.executable, "-m", "bench.scale", "--one", str(n)], cwd=ROOT, capture_output=True,
                           text=True, check=True)
        out.append(json.loads(p.stdout.strip().splitlines()[-1]))
    return out


def tables(res: list[dict]) -> str:
    rows = []
    base = res[0]
    for r in res:
        rows.append([r["frames"], r["views"], r["corners"], r["solver_s"], r["intrinsics_s"] + r["graph_s"],
                     r["calibration_s"], r["calibration_cpu_s"],
                     r["solver_s"] / base["solver_s"] / (r["frames"] / base["frames"]), r["peak_rss_mb"],
                     r["max_pair_trans_err_mm"], r["max_pair_rot_err_deg"],
                     f"{sum(m == 'radial2' for m in r['models'])}/{len(r['models'])}"])
    return md_table(["frames", "views", "corners", "solver s", "init s", "calibration s", "calibration CPU s",
                     "solver s per frame vs first", "peak RSS MB", "max pair trans err mm", "max pair rot err deg",
                     "cameras fitted radial2 (truth has p1, p2)"], rows,
                    "Scale: 6 cameras (surround-6), synthetic detections (0.1 px noise); target 500 frames < 30 s")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=list(FRAMES))
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(a.one)))
        return
    res = run(a.frames)
    say(tables(res))
    write_json("scale", {"results": res})


if __name__ == "__main__":
    main()
