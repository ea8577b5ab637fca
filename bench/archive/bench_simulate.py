"""Benchmark: `rigcal simulate rigs/drone-stereo-back.yaml --scene room --frames 60`
(180 images at 640x480, PNG writing included). Target: <= 6 s wall on 2 cores.

    python -m bench.archive.bench_simulate [--jobs N] [--frames N] [--rig rigs/X.yaml] [--repeat N]
    python -m bench.archive.bench_simulate --accuracy [--seeds 3]

Prints the wall time, CPU time of this process and its workers, and the machine's
load average (other work on the machine inflates the wall time).

--accuracy renders noise-free datasets (pinhole and fisheye, board and room scenes),
detects the boards with cv2.aruco.CharucoDetector and compares the corners with
their true projections read back from truth.yaml: raw detector output, and after
cv2.cornerSubPix re-refinement with windows (2,2) .. (5,5)."""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig, rig_from_dict
from rigcal.sim.simulate import simulate_dataset
from rigcal.core.target import load_target

ROOT = Path(__file__).resolve().parents[2]


def corner_errors(dataset: Path, windows=(2, 3, 4, 5)) -> dict[str, dict[str, np.ndarray]]:
    """Per camera: 'raw' and 'spN' errors (N, 2) in px, 'incidence' (N,) in degrees, and
    'offset' (V, 2): the mean error of each board view."""
    truth = yaml.safe_load((dataset / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(dataset / "target.yaml")
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    out = {}
    for cam in rig.cameras:
        acc: dict[str, list] = {"raw": [], "incidence": [], "offset": [], **{f"sp{w}": [] for w in windows}}
        for stem, fr in truth["frames"].items():
            img = cv2.imread(str(dataset / "images" / cam.name / f"{stem}.png"), cv2.IMREAD_GRAYSCALE)
            T_cam_world = geo.inv_T(geo.make_T(np.array(fr["rotation"]), fr["position"]) @ cam.T_body_cam)
            for b in target.boards:
                pose = fr.get("boards", {}).get(b.name, truth["boards"][b.name])
                corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv_board()).detectBoard(img)
                if ids is None or len(ids) < 4:
                    continue
                ids = ids.reshape(-1)
                corners = corners.reshape(-1, 2).astype(np.float64)
                T = T_cam_world @ geo.make_T(np.array(pose["rotation"]), pose["position"])
                p = geo.transform(T, b.corners[ids])
                uv, _ = cam.intrinsics.project(p)
                acc["raw"].append(corners - uv)
                acc["offset"].append((corners - uv).mean(axis=0, keepdims=True))
                acc["incidence"].append(np.degrees(np.arccos(np.abs(p @ T[:3, 2]) / np.linalg.norm(p, axis=1))))
                for w in windows:
                    sp = cv2.cornerSubPix(img, corners.astype(np.float32).reshape(-1, 1, 2).copy(), (w, w), (-1, -1), crit)
                    acc[f"sp{w}"].append(sp.reshape(-1, 2) - uv)
        out[cam.name] = {k: np.concatenate(v) for k, v in acc.items() if v}
    return out


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt((e**2).sum(axis=1).mean()))


def accuracy(seeds: int) -> None:
    cases = [("stereo-forward", "board", 12), ("drone-stereo-back", "room", 20), ("fisheye-stereo", "board", 12)]
    for rig_name, scene, frames in cases:
        rig = load_rig(ROOT / "rigs" / f"{rig_name}.yaml")
        per_seed = []
        for seed in range(seeds):
            out = Path(tempfile.mkdtemp(prefix="rigcal-acc-")) / "sim"
            simulate_dataset(rig, out, scene=scene, frames=frames, noise=0.0, seed=seed)
            per_seed.append(corner_errors(out))
            shutil.rmtree(out.parent)
        for cam in per_seed[0]:
            e = {k: np.concatenate([d[cam][k] for d in per_seed]) for k in per_seed[0][cam]}
            inc = e["incidence"]
            mean = e["raw"].mean(axis=0)
            sp = " ".join(f"{k} {_rms(e[k]):.3f}" for k in e if k.startswith("sp"))
            print(f"{rig_name} {scene} {cam} ({e['raw'].shape[0]} corners, {seeds} seeds): raw RMS {_rms(e['raw']):.3f} px "
                  f"(incidence < 60 deg: {_rms(e['raw'][inc < 60]):.3f}, >= 60: "
                  f"{_rms(e['raw'][inc >= 60]) if (inc >= 60).any() else float('nan'):.3f}; median "
                  f"{np.median(np.linalg.norm(e['raw'], axis=1)):.3f}), mean ({mean[0]:+.4f}, {mean[1]:+.4f}), "
                  f"per-view mean offset RMS {_rms(e['offset']):.3f}; cornerSubPix re-refined: {sp}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default=str(ROOT / "rigs" / "drone-stereo-back.yaml"))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scene", default="room")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--accuracy", action="store_true", help="corner accuracy of noise-free renders instead")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    if args.accuracy:
        accuracy(args.seeds)
        return
    rig = load_rig(args.rig)
    jobs = args.jobs or os.cpu_count()
    walls = []
    for _ in range(args.repeat):
        out = Path(tempfile.mkdtemp(prefix="rigcal-bench-")) / "sim"
        c0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        res = simulate_dataset(rig, out, scene=args.scene, frames=args.frames, jobs=jobs)
        wall = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_SELF)
        main_cpu = c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime
        n = sum(len(v) for v in res.image_paths.values())
        walls.append(wall)
        # the workers are children of multiprocessing's fork server, not of this process:
        # their CPU time comes back with the images
        print(f"{Path(args.rig).name} {args.scene}: {n} images in {wall:.2f} s wall; CPU {main_cpu:.2f} s here "
              f"(planning, ray maps, truth) + {res.image_cpu_seconds:.2f} s in {jobs} workers (images incl. PNG); "
              f"load average {os.getloadavg()[0]:.2f}")
        shutil.rmtree(out.parent)
    if len(walls) > 1:
        print(f"best {min(walls):.2f} s wall")


if __name__ == "__main__":
    main()
