"""Speed of `rigcal ingest` on a bag: 60 s, 2 cameras at 20 Hz (752x480 mono8,
EuRoC's size), IMU at 200 Hz, ROS 1 raw images and ROS 2 mcap with PNG-compressed images.

The bag is written with rosbags' writer from rendered frames of a stereo rig (20 frames
cycled, so the pixels look like a calibration recording, not noise); `rigcal ingest` runs
in a subprocess, as a user runs it, and its wall clock (start-up included) is measured.
Target: <= 20 s on 2 cores for the ROS 1 bag. The bags live in a temporary folder.

    python -m bench.ingest [--seconds S]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from .common import ROOT, md_table, say, write_json

BIN = Path(sys.executable).parent / "rigcal"
TARGET_S = 20.0
RIG = """
rig: bench-stereo
cameras:
  cam0: {model: pinhole, resolution: [752, 480], intrinsics: {focal: 460.0}, distortion: [-0.28, 0.07, 0.0, 0.0],
         position: [0.0, 0.055, 0.0], look: forward}
  cam1: {model: pinhole, resolution: [752, 480], intrinsics: {focal: 460.0}, distortion: [-0.28, 0.07, 0.0, 0.0],
         position: [0.0, -0.055, 0.0], look: forward}
"""


def _frames(tmp: Path, n: int = 20, scale: float = 1.0) -> dict[str, list[np.ndarray]]:
    from rigcal.core.rig import parse_rig
    from rigcal.sim.simulate import simulate_dataset

    text = RIG
    if scale != 1.0:  # the smoke test renders tiny images
        text = text.replace("[752, 480]", f"[{int(752 * scale)}, {int(480 * scale)}]").replace(
            "focal: 460.0", f"focal: {460.0 * scale}")
    simulate_dataset(parse_rig(text), tmp / "sim", scene="board", frames=n, jobs=2, seed=0)
    return {c: [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((tmp / "sim" / "images" / c).glob("*.png"))]
            for c in ("cam0", "cam1")}


def _bag(tmp: Path, kind: str, frames: dict[str, list[np.ndarray]], seconds: float) -> tuple[Path, float]:
    from tests.support import recordings as R

    n = int(round(seconds * 20))
    images = {c: [(R.T0_NS + i * R.DT_NS, imgs[i % len(imgs)]) for i in range(n)] for c, imgs in frames.items()}
    t = R.stamps(n)
    imu = R.synthetic_imu(int(t[0]), int(t[-1]))
    path = tmp / ("rec.bag" if kind == "ros1" else "rec_mcap")
    t0 = time.perf_counter()
    R.write_bag(path, kind, images, imu, compressed=kind != "ros1")
    return path, time.perf_counter() - t0


def _size(path: Path) -> int:
    return path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def run(seconds: float = 60.0, scale: float = 1.0, log=say) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="rigcal-bench-ingest-"))
    rows = []
    try:
        log(f"ingest: rendering frames and writing {seconds:g} s bags ...")
        frames = _frames(tmp, scale=scale)
        for kind in ("ros1", "mcap"):
            bag, write_s = _bag(tmp, kind, frames, seconds)
            topic = "/{c}/image_raw" + ("/compressed" if kind != "ros1" else "")
            cmd = [str(BIN) if BIN.exists() else "rigcal", "ingest", str(bag), "--out", str(tmp / f"ds_{kind}"),
                   "--imu", "imu0=/imu0"] + [a for c in ("cam0", "cam1") for a in ("--camera", f"{c}={topic.format(c=c)}")]
            load0 = os.getloadavg()[0]
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            p = subprocess.run(cmd, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
            if p.returncode != 0:
                rows.append({"kind": kind, "ok": False, "error": (p.stdout + p.stderr).strip().splitlines()[-1]})
                continue
            n_img = sum(1 for _ in (tmp / f"ds_{kind}" / "images").rglob("*.*"))
            rows.append({"kind": kind, "ok": True, "seconds": seconds, "images": n_img, "bag_mb": _size(bag) / 1e6,
                         "bag_write_s": write_s, "ingest_s": wall, "ingest_cpu_s": cpu, "images_per_s": n_img / wall, "load_avg": load0,
                         "within_target": bool(kind != "ros1" or wall <= TARGET_S * seconds / 60.0)})
            shutil.rmtree(tmp / f"ds_{kind}")
            shutil.rmtree(bag) if bag.is_dir() else bag.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"rows": rows, "target_s": TARGET_S, "cpus": os.cpu_count()}


def tables(r: dict) -> str:
    rows = [[x["kind"], f"{x['seconds']:g}", x["images"], f"{x['bag_mb']:.0f}", f"{x['ingest_s']:.1f}",
             f"{x['ingest_cpu_s']:.1f}", f"{x['images_per_s']:.0f}", f"{x['load_avg']:.1f}"] if x["ok"] else [x["kind"], "failed: " + x["error"]]
            for x in r["rows"]]
    return md_table(["bag", "recording s", "images", "bag MB", "ingest wall s", "CPU s", "images/s", "load avg"], rows,
                    title=f"rigcal ingest: 2 cameras x 20 Hz 752x480 + IMU 200 Hz (target <= {r['target_s']:g} s "
                          f"for 60 s of ROS 1 on 2 cores; {r['cpus']} CPUs here)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    a = ap.parse_args(argv)
    r = run(a.seconds)
    write_json("ingest", r)
    say(tables(r))


if __name__ == "__main__":
    main()
