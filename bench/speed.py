"""Speed of `rigcal calibrate` as a user runs it: drone-stereo-back, 60 frames.

The command runs in a subprocess on the rendered dataset (bench/out/cache, seed 0);
its own "time:" line gives detection, intrinsics and solve seconds; the wall clock
of the whole command (Python start-up and imports included) is measured here.
Targets: solver <= 2 s; total <= 1.3 x detection time. Wall times depend on what
else the machine runs, so the load average is printed beside them, and the CPU
seconds of the command (its process and its detection workers).

    python -m bench.speed
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from .common import JOBS, OUT, Timer, get_dataset, md_table, say, scenario, write_json

BIN = Path(sys.executable).parent / "rigcal"


def run(log=say) -> dict:
    ds = get_dataset(scenario("drone-stereo-back"), 0, keep_images=True, log=log)
    log("speed: rigcal calibrate on drone-stereo-back (60 frames, 180 images) ...")
    out = OUT / "speed-drone.yaml"
    cmd = [str(BIN) if BIN.exists() else "rigcal", "calibrate", str(ds.path), "--out", str(out), "--jobs", str(JOBS)]
    load0 = os.getloadavg()[0]
    with Timer() as t:
        p = subprocess.run(cmd, capture_output=True, text=True)
    text = p.stdout + p.stderr
    if p.returncode != 0:
        return {"ok": False, "error": text.strip().splitlines()[-1] if text.strip() else f"exit {p.returncode}"}
    m = re.search(r"time: detection ([\d.]+) s, intrinsics ([\d.]+) s, solve ([\d.]+) s, total ([\d.]+) s", text)
    rate = re.search(r"\(([\d.]+) images/s", text)
    det, intr, solve, total = (float(x) for x in m.groups())
    return {"ok": True, "images": ds.n_images, "detection_s": det, "images_per_s": float(rate.group(1)) if rate else None,
            "intrinsics_s": intr, "solver_s": solve, "total_s": total, "wall_s": t.wall, "cpu_s": t.cpu,
            "total_over_detection": total / det, "load_avg_1min": [load0, os.getloadavg()[0]],
            "jobs": JOBS, "date": time.strftime("%Y-%m-%d %H:%M")}


def tables(r: dict) -> str:
    if not r.get("ok"):
        return f"\nspeed: rigcal calibrate failed: {r.get('error')}"
    rows = [[r["images"], r["detection_s"], r["images_per_s"], r["intrinsics_s"], r["solver_s"], r["total_s"],
             r["wall_s"], r["cpu_s"], f"{r['total_over_detection']:.2f}x",
             f"{r['load_avg_1min'][0]:.1f} / {r['load_avg_1min'][1]:.1f}"]]
    return md_table(["images", "detection s", "images/s", "intrinsics s", "solver s", "total s (command's own)",
                     "wall s (incl. start-up)", "CPU s", "total / detection", "load avg before/after"], rows,
                    f"Speed: rigcal calibrate drone-stereo-back, 60 frames, --jobs {r['jobs']} "
                    f"(targets: solver <= 2 s, total <= 1.3x detection)")


def main(argv=None) -> None:
    r = run()
    say(tables(r))
    write_json("speed", r)


if __name__ == "__main__":
    main()
