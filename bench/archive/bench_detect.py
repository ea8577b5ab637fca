"""Benchmark: board detection - throughput and corner accuracy.

    python -m bench.archive.bench_detect                 # throughput: real sets and a simulated set, jobs 1 and 2
    python -m bench.archive.bench_detect --accuracy      # corner error vs truth on rigcal simulate renders
    python -m bench.archive.bench_detect --real-rms      # mono calibration RMS on the real sets per refinement

Throughput is images per second of `detect_dataset` end to end (reading, detection,
refinement; the process pool's start-up included), and for jobs 1 the CPU time per
image (which other load on the machine barely changes), on: the samples/real/ chessboard
sets, the caliscope ChArUco frames and the wide-angle ChArUco set from
../shared/data/real (when present), and a `rigcal simulate` room dataset. The
machine's load average is printed beside it: other work on the machine inflates it.

--accuracy renders `rigcal simulate` datasets (the project's renderer, exact
geometry, its default nuisances), detects them with each refinement mode
("none" = OpenCV's corners, "subpix", "symmetric") and compares every corner with
its true projection from truth.yaml: RMS, the per-view mean offset, the 99th
percentile and the worst corner.

--real-rms calibrates each camera of the real sets alone (cv2.calibrateCamera,
the reference's lens model) from the corners of each refinement mode: a lower
reprojection RMS on the same views means less corner noise.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "app"))

from rigcal.core import geometry as geo  # noqa: E402
from rigcal.data.dataset import list_dataset  # noqa: E402
from rigcal.detect.board_detectors import BoardDetector  # noqa: E402
from rigcal.detect.corner_refine import REFINE_MODES  # noqa: E402
from rigcal.detect.detect import detect_dataset  # noqa: E402
from rigcal.data.image_read import read_gray  # noqa: E402
from rigcal.core.rig import load_rig, rig_from_dict  # noqa: E402
from rigcal.core.target import load_target  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
SAMPLES = ROOT / "samples" / "real"


def _load():
    return f"load average {os.getloadavg()[0]:.2f}"


def _real_datasets(tmp: Path) -> list[tuple[str, Path]]:
    """(name, dataset folder): the committed samples plus the big sets linked from ../shared."""
    out = [(p.name, p) for p in sorted(SAMPLES.iterdir()) if (p / "rig.yaml").is_file()] if SAMPLES.is_dir() else []
    if REAL.is_dir():
        sys.path.insert(0, str(SAMPLES))
        from make_datasets import BUILDERS  # samples/real/make_datasets.py

        for name in ("caliscope", "wideangle"):
            dst = tmp / name
            BUILDERS[name](dst)
            out.append((name, dst))
    return out


def throughput(jobs_list: list[int], sim_frames: int) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="rigcal-bench-detect-"))
    try:
        sets = _real_datasets(tmp)
        if sim_frames:
            from rigcal.sim.simulate import simulate_dataset

            sim = tmp / "sim"
            simulate_dataset(load_rig(ROOT / "rigs" / "drone-stereo-back.yaml"), sim, scene="room",
                             frames=sim_frames, seed=0)
            sets.append((f"simulate drone-stereo-back room {sim_frames} frames", sim))
        for name, path in sets:
            rig = load_rig(path / "rig.yaml")
            target = load_target(path / "target.yaml")
            images = list_dataset(path, rig)
            for jobs in jobs_list:
                cpu0 = time.process_time()
                res = detect_dataset(images, target, rig=rig, jobs=jobs, progress=False)
                cpu = time.process_time() - cpu0
                n = sum(res.n_images.values())
                corners = sum(len(v.ids) for v in res.views)
                # CPU time of this process: the whole work when serial (a figure other load
                # on the machine barely moves); workers of a pool are not its children
                cpu_s = f", {1000 * cpu / n:.0f} ms CPU per image" if res.jobs == 1 else ""
                print(f"{name}: {n} images ({'/'.join(f'{w}x{h}' for w, h in sorted(set(res.image_size.values())))}), "
                      f"jobs {res.jobs}: {res.seconds:.2f} s, {n / res.seconds:.1f} images/s{cpu_s}; "
                      f"{len(res.views)} views, {corners} corners; {_load()}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _truth_corners(dataset: Path):
    """Per (camera, stem, board): the true pixel of every corner id (N, 2), from truth.yaml."""
    truth = yaml.safe_load((dataset / "truth.yaml").read_text())
    rig = rig_from_dict(truth["rig"])
    target = load_target(dataset / "target.yaml")
    out = {}
    for cam in rig.cameras:
        for stem, fr in truth["frames"].items():
            T_cam_world = geo.inv_T(geo.make_T(np.array(fr["rotation"]), fr["position"]) @ cam.T_body_cam)
            for b in target.boards:
                pose = fr.get("boards", {}).get(b.name, truth["boards"][b.name])
                T = T_cam_world @ geo.make_T(np.array(pose["rotation"]), pose["position"])
                uv, _ = cam.intrinsics.project(geo.transform(T, b.corners))
                out[(cam.name, str(stem), b.name)] = uv
    return out


def accuracy(seeds: int) -> None:
    from rigcal.sim.simulate import simulate_dataset

    cases = [("stereo-forward", "board", 12), ("drone-stereo-back", "room", 12), ("fisheye-stereo", "board", 12)]
    for rig_name, scene, frames in cases:
        errs = {m: [] for m in REFINE_MODES}
        for seed in range(seeds):
            out = Path(tempfile.mkdtemp(prefix="rigcal-acc-")) / "sim"
            try:
                rig = load_rig(ROOT / "rigs" / f"{rig_name}.yaml")
                simulate_dataset(rig, out, scene=scene, frames=frames, seed=seed)
                truth = _truth_corners(out)
                images = list_dataset(out, rig)
                target = load_target(out / "target.yaml")
                for mode in REFINE_MODES:
                    res = detect_dataset(images, target, jobs=2, progress=False, refine=mode)
                    for v in res.views:
                        errs[mode].append(v.uv - truth[(v.camera, v.frame, v.board)][v.ids])
            finally:
                shutil.rmtree(out.parent, ignore_errors=True)
        for mode, es in errs.items():
            e = np.concatenate(es)
            n = np.linalg.norm(e, axis=1)
            offs = np.array([x.mean(0) for x in es])
            print(f"{rig_name} {scene} ({seeds} seeds x {frames} frames) refine={mode:9s}: {len(es)} views, {len(e)} corners, "
                  f"RMS {np.sqrt((n ** 2).mean()):.4f} px, per-view offset RMS {np.sqrt((offs ** 2).sum(1).mean()):.4f}, "
                  f"mean ({e[:, 0].mean():+.4f}, {e[:, 1].mean():+.4f}), p99 {np.quantile(n, 0.99):.3f}, max {n.max():.3f}",
                  flush=True)


def real_rms() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="rigcal-bench-detect-"))
    flags = {"bumblebee2": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3, "opencv_stereo": 0, "caliscope": 0,
             "wideangle": cv2.CALIB_RATIONAL_MODEL}
    try:
        for name, path in _real_datasets(tmp):
            rig = load_rig(path / "rig.yaml")
            target = load_target(path / "target.yaml")
            images = list_dataset(path, rig)
            for cam in images.cameras:
                grays = [read_gray(p)[0] for p in images.frames[cam].values()]
                size = grays[0].shape[::-1]
                line = []
                for mode in REFINE_MODES:
                    det = BoardDetector(target, refine=mode)
                    obj, img = [], []
                    for g in grays:
                        for bname, ids, uv, _ in det.detect(g)[0]:
                            obj.append(target.board(bname).corners[ids].astype(np.float32))
                            img.append(uv.astype(np.float32))
                    rms = cv2.calibrateCamera(obj, img, size, None, None, flags=flags.get(name, 0))[0]
                    line.append(f"{mode} {rms:.4f} ({len(obj)} views, {sum(len(i) for i in img)} corners)")
                print(f"{name} {cam}: mono RMS px: " + ", ".join(line), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--accuracy", action="store_true", help="corner errors on simulate renders instead")
    ap.add_argument("--real-rms", action="store_true", help="mono calibration RMS per refinement on the real sets")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--sim-frames", type=int, default=20, help="frames of the simulated set (0: none)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.accuracy:
        accuracy(args.seeds)
    elif args.real_rms:
        real_rms()
    else:
        throughput(args.jobs, args.sim_frames)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
