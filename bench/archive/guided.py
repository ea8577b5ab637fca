"""The guided corner pass (rigcal.detect.guided), measured: the same detections calibrated with and
without it, on rigcal's renders and on the independent renderer's (tests/support/indie_render.py).

    python -m bench.archive.guided [--seeds 6] [--scenes fisheye-rigcal fisheye-indie pinhole-indie stereo-forward]

Per scene and seed: the corners the calibration used against their exact projections
(RMS px), each camera pair's relative rotation / translation error against truth, the
Cramér-Rao bound for the corner noise measured in that run (so a cleaner pass also has a
lower bound), and the guided pass's own time. Scenes:

  fisheye-rigcal  rigs/fisheye-stereo.yaml, `board` scene, 20 frames (bench.noise_limit's)
  stereo-forward  rigs/stereo-forward.yaml, `board` scene, 20 frames
  fisheye-indie   indie_render.waved_scene(fisheye=True), 20 frames
  pinhole-indie   indie_render.waved_scene(), 20 frames

The figures go to the README (Accuracy: the guided pass), which explains why the pass is
on for fisheye cameras only by default.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import rigcal

from bench.common import OUT, ROOT, get_dataset, md_table, say, scenario, write_json
from bench.noise_limit import pair_stats

SCENES = ("fisheye-indie", "pinhole-indie", "stereo-forward", "fisheye-rigcal")
FRAMES = 20
WORK = OUT / "guided"


def dataset(scene: str, seed: int) -> Path:
    """The dataset folder (with images) of one scene and seed, rendered once."""
    if scene in ("fisheye-rigcal", "stereo-forward"):
        name = "fisheye-stereo" if scene == "fisheye-rigcal" else scene
        return get_dataset(scenario(name).with_frames(FRAMES), seed, keep_images=True, jobs=2).path
    d = WORK / f"{scene}-s{seed}"
    if not (d / "truth.yaml").is_file():
        sys.path.insert(0, str(ROOT / "tests"))
        import indie_render as ir

        scene_ = ir.waved_scene(n_frames=FRAMES, seed=seed, fisheye=scene.startswith("fisheye"))
        ir.write_dataset(scene_, d, seed=seed, S=4, drop=0, corrupt=False, formats=((".png", False),))
    return d


def run_one(d: Path) -> dict:
    from rigcal.camcal.bounds import measured_corner_noise
    from rigcal.data.truth import load_truth
    from rigcal.camcal.pipeline import calibrate_views
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.detect.guided import rerefiner
    from rigcal.core.target import load_target

    rig, target = rigcal.load_rig(d / "rig.yaml"), load_target(d / "target.yaml")
    truth = load_truth(d / "truth.yaml")
    images = list_dataset(d, rig)
    det = detect_dataset(images, target, rig=rig, jobs=2, progress=False)
    views = list(det.views)
    corners = {b.name: b.corners for b in target.boards}
    out = {"detection_s": det.seconds}
    for name, hook in (("off", None), ("on", rerefiner(images, rig, target, jobs=2, mode="on"))):
        t0 = time.perf_counter()
        cal = calibrate_views(views, rig, corners, rerefine=hook)
        sigma = measured_corner_noise(cal, truth)
        out[name] = {"corner_rms_px": sigma, "pairs": pair_stats(cal, truth, sigma),
                     "calibrate_s": time.perf_counter() - t0, "guided_s": cal.timings.get("guided_s")}
    return out


def summarise(runs: dict) -> list[list]:
    rows = []
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    for scene, rs in runs.items():
        if not rs:
            continue
        for pair in rs[0]["off"]["pairs"]:
            cells = [scene, len(rs), pair]
            for k in ("rot_deg", "trans_mm"):
                for mode in ("off", "on"):
                    e = rms([r[mode]["pairs"][pair][k] for r in rs])
                    b = rms([r[mode]["pairs"][pair][f"bound_{k}"] for r in rs])
                    cells.append(f"{e:.5f} ({e / b:.2f}x)" if k == "rot_deg" else f"{e:.4f} ({e / b:.2f}x)")
            cells.append(f"{rms([r['off']['corner_rms_px'] for r in rs]):.4f} -> "
                         f"{rms([r['on']['corner_rms_px'] for r in rs]):.4f}")
            cells.append(f"{np.mean([r['on']['guided_s'] for r in rs]):.1f} / {np.mean([r['detection_s'] for r in rs]):.1f}")
            rows.append(cells)
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    a = ap.parse_args(argv)
    runs: dict[str, list] = {}
    for scene in a.scenes:
        for seed in range(a.seeds):
            say(f"  {scene} seed {seed} ...")
            runs.setdefault(scene, []).append(run_one(dataset(scene, seed)))
            write_json("guided", {"runs": runs, "seeds": a.seeds, "frames": FRAMES})  # so far, if stopped
    print(md_table(["scene", "seeds", "pair", "rotation deg, off (x bound)", "on", "translation mm, off", "on",
                    "corner RMS px off -> on", "guided pass s / detection s"], summarise(runs),
                   "The guided pass, off and on (every camera), same detections"))


if __name__ == "__main__":
    main()
