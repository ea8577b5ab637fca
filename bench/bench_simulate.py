"""Benchmark: `rigcal simulate rigs/drone-stereo-back.yaml --scene room --frames 60`
(180 images at 640x480, PNG writing included). Target: <= 6 s wall on 2 cores.

    python bench/bench_simulate.py [--jobs N] [--frames N] [--rig rigs/X.yaml]

Prints the wall time, CPU time of this process and its workers, and the machine's
load average (other work on the machine inflates the wall time)."""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from rigcal.rig import load_rig
from rigcal.simulate import simulate_dataset

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default=str(ROOT / "rigs" / "drone-stereo-back.yaml"))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scene", default="room")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    rig = load_rig(args.rig)
    jobs = args.jobs or os.cpu_count()
    walls = []
    for _ in range(args.repeat):
        out = Path(tempfile.mkdtemp(prefix="rigcal-bench-")) / "sim"
        c0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        res = simulate_dataset(rig, out, scene=args.scene, frames=args.frames, jobs=jobs)
        wall = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = sum(b.ru_utime + b.ru_stime - a.ru_utime - a.ru_stime for a, b in zip(c0, c1))
        n = sum(len(v) for v in res.image_paths.values())
        walls.append(wall)
        print(f"{Path(args.rig).name} {args.scene}: {n} images in {wall:.2f} s wall, {cpu:.2f} s CPU, "
              f"{jobs} jobs; load average {os.getloadavg()[0]:.2f}")
        shutil.rmtree(out.parent)
    if len(walls) > 1:
        print(f"best {min(walls):.2f} s wall")


if __name__ == "__main__":
    main()
