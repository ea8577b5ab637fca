"""The fisheye noise-limit excess, re-measured on images from the independent renderer.

bench.noise_limit finds the fisheye stereo pair's relative rotation 1.6x its Cramér-Rao
bound on rigcal's own renders (pinhole rigs 0.7-1.3x). Is that rigcal's renderer
(texture level choice, sampling of the compressed periphery) or its detector? Here the
images come from tests/indie_render.py (OpenCV and the spec only, exact rays, S x S
box-filtered supersampling) and everything after the render is noise_limit's own
machinery: rigcal detects (detect_dataset on list_dataset), bench.common.calibrate
calibrates, the bound is crb_pairs with the measured corner noise (detected vs true
projection, measured_corner_noise), and the same corners replaced by true projection +
white noise of that sigma (gaussian_views) give the solver's own ratio.

Two scenes per seed, both indie_render.waved_scene (board waved before a static pair,
20 frames, lossless grey PNGs, no dropped or corrupt files):
  fisheye  fisheye=True: rigs/fisheye-stereo.yaml's pair (800 x 800, f 250, 0.08 m) and
           simulate.py's `board` scene board for it (11 x 8 squares of 0.216 m, 0.5-3 m)
  pinhole  the pinhole stereo pair (640 x 480, f 420, 0.15 m), the control: ~1.0 if the
           machinery is right

Ratios are RMS(error over seeds) / RMS(bound over seeds), as noise_limit reports them.

    python -m bench.indie_noise [--seeds 10] [--samples 4]
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

import rigcal
from rigcal.bounds import measured_corner_noise
from rigcal.compare import load_truth
from rigcal.core import ViewIn
from rigcal.errors import RigcalError

from .common import (OUT, Timer, calibrate, gaussian_views, md_table, run_pool, say, true_projections, view_tuples,
                     write_json)
from .noise_limit import _pair_stats, _ratio, view_offsets

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import indie_render as ir  # noqa: E402

FRAMES = 20
SCENES = ("fisheye", "pinhole")
WORK = OUT / "indie_noise"


def render_and_detect(kind: str, seed: int, S: int) -> tuple:
    """Render one seeded scene with indie_render and detect it with rigcal.
    Returns (declared rig, truth, board corners {name: (N, 3)}, views, render s, detect s)."""
    from rigcal.dataset import list_dataset
    from rigcal.detect import detect_dataset
    from rigcal.target import load_target

    d = WORK / f"{kind}-s{seed}"
    shutil.rmtree(d, ignore_errors=True)
    scene = ir.waved_scene(n_frames=FRAMES, seed=seed, fisheye=kind == "fisheye")
    with Timer() as tr:
        ir.write_dataset(scene, d, seed=seed, S=S, drop=0, corrupt=False, formats=((".png", False),))
    rig = rigcal.load_rig(d / "rig.yaml")
    target = load_target(d / "target.yaml")
    with Timer() as td:
        det = detect_dataset(list_dataset(d, rig), target, rig=rig, jobs=1, progress=False)
    views = [ViewIn(*v) for v in view_tuples(det.views)]
    truth = load_truth(d / "truth.yaml")
    shutil.rmtree(d, ignore_errors=True)
    return rig, truth, {b.name: b.corners for b in target.boards}, views, tr.wall, td.wall


def run_seed(kind: str, seed: int, S: int) -> dict:
    """One (scene, seed) in a worker process; a failure is reported, not raised."""
    try:
        return _run_seed(kind, seed, S)
    except (np.linalg.LinAlgError, RigcalError, ValueError) as e:
        return {"scene": kind, "seed": seed, "failed": f"{type(e).__name__}: {e}"}


def _run_seed(kind: str, seed: int, S: int) -> dict:
    rig, truth, corners, views, render_s, detect_s = render_and_detect(kind, seed, S)
    with Timer() as tc:
        cal = calibrate(views, rig, corners)
    sigma = measured_corner_noise(cal, truth)
    uv_true = true_projections(cal, truth)
    rng = np.random.default_rng([seed, 7])
    gcal = calibrate(gaussian_views(cal, uv_true, corners, sigma, rng), rig, corners)
    return {"scene": kind, "seed": seed, "sigma_px": sigma, "render_s": render_s, "detect_s": detect_s,
            "calibration_s": tc.wall, "models": [cal.stats[n].distortion_model for n in cal.cam_names],
            "corners_used": len(cal.obs), "corners_detected": int(sum(len(v.ids) for v in views)),
            "auto": _pair_stats(cal, truth, sigma), "gauss": _pair_stats(gcal, truth, sigma),
            **view_offsets(cal, uv_true, sigma)}


def run(seeds: int = 10, S: int = 4, log=say) -> dict:
    tasks = [(k, s, S) for k in SCENES for s in range(seeds)]
    log(f"indie noise: {len(tasks)} (scene, seed) runs, {S}x{S} samples per pixel: render, detect, calibrate 2x ...")
    with Timer() as t:
        runs = run_pool(run_seed, tasks)
    return {"runs": runs, "summary": summarise(runs), "seconds": t.wall, "seeds": seeds, "samples": S,
            "frames": FRAMES}


def summarise(runs: list[dict]) -> dict:
    out = {}
    for kind in SCENES:
        rs = [r for r in runs if r["scene"] == kind and "failed" not in r]
        if not rs:
            continue
        out[kind] = {"seeds": len(rs), "sigma_px": float(np.mean([r["sigma_px"] for r in rs])),
                     "view_offset_rms_px": float(np.sqrt(np.mean([r["view_offset_rms_px"] ** 2 for r in rs]))),
                     "white_expectation_px": float(np.sqrt(np.mean([r["white_expectation_px"] ** 2 for r in rs]))),
                     **{v: {q: _ratio(rs, v, q) for q in ("rot_deg", "trans_mm")} for v in ("auto", "gauss")}}
    return out


def tables(res: dict) -> str:
    out = [f"\n## Noise limit on independent renders ({res['seeds']} seeds, {res['frames']} frames, "
           f"{res['samples']}x{res['samples']} samples per pixel)\n"]
    rows = []
    for r in res["runs"]:
        if "failed" in r:
            rows.append([r["scene"], r["seed"], "-", "-", "-", "-", "-", f"FAILED: {r['failed']}"])
            continue
        for pair, v in r["auto"].items():
            g = r["gauss"].get(pair, {})
            rows.append([r["scene"], r["seed"], r["sigma_px"], v["rot_deg"] / v["bound_rot_deg"],
                         v["trans_mm"] / v["bound_trans_mm"],
                         g["rot_deg"] / g["bound_rot_deg"] if g else None,
                         g["trans_mm"] / g["bound_trans_mm"] if g else None, "/".join(r["models"])])
    out.append(md_table(["scene", "seed", "sigma px", "rot / CRB", "trans / CRB", "white: rot / CRB",
                         "white: trans / CRB", "models"], rows, "per seed (one seed's error / its bound)"))
    rows = []
    for kind, s in res["summary"].items():
        for pair in s["auto"]["rot_deg"]:
            a, g = s["auto"], s["gauss"]
            rows.append([kind, pair, s["seeds"], s["sigma_px"], a["rot_deg"][pair]["ratio"],
                         a["trans_mm"][pair]["ratio"], g["rot_deg"].get(pair, {}).get("ratio"),
                         g["trans_mm"].get(pair, {}).get("ratio"), s["view_offset_rms_px"],
                         s["white_expectation_px"]])
    out.append(md_table(["scene", "pair", "seeds", "sigma px", "rot / CRB", "trans / CRB", "white: rot / CRB",
                         "white: trans / CRB", "view offset px", "white expect. px"], rows,
                        "over seeds: RMS error / RMS bound (white: detected corners replaced by truth + white noise)"))
    out.append(f"\n{res['seconds']:.0f} s on 2 processes")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--samples", type=int, default=4, help="S: S x S box-filtered samples per pixel")
    a = ap.parse_args(argv)
    res = run(a.seeds, a.samples)
    write_json("indie_noise", res)
    say(tables(res))


if __name__ == "__main__":
    main()
