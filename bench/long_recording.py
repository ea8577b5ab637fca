"""Long recordings: 4 cameras x 1,500 frames rendered at 640x480, then
`rigcal calibrate` end to end. Target: < 5 min on 2 cores.

rigs/quad-forward (four forward cameras, 2x2 block) with the `board` scene (one board
moved in front of the rig), rendered once with `rigcal simulate` into
bench/out/cache/long_recording (kept: a rerun only calibrates). The calibration runs
as a user runs it, in a subprocess; its own "time:" line gives detection, intrinsics
and solve seconds. The machine is shared, so the load average before and after is
stated beside the figures. (No CPU seconds: the detection workers are children of
multiprocessing's fork server, not of the command, so getrusage would miss them.)

    python -m bench.long_recording [--frames 1500]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from .common import CACHE, JOBS, OUT, RIGS, Timer, md_table, say, write_json

BIN = Path(sys.executable).parent / "rigcal"
FRAMES = 1500
RIG = RIGS / "quad-forward.yaml"


def _rigcal() -> str:
    return str(BIN) if BIN.exists() else "rigcal"


def render(frames: int, log=say) -> tuple[Path, float | None]:
    """The rendered dataset folder, and the render's seconds (None: taken from the cache)."""
    d = CACHE / f"long_recording-{frames}"
    if (d / "truth.yaml").is_file():
        return d, None
    log(f"long_recording: rendering 4 cameras x {frames} frames (board scene) ...")
    d.parent.mkdir(parents=True, exist_ok=True)
    with Timer() as t:
        subprocess.run([_rigcal(), "simulate", str(RIG), "--out", str(d), "--scene", "board", "--frames", str(frames),
                        "--seed", "0", "--force", "--jobs", str(JOBS)], check=True, capture_output=True, text=True)
    return d, t.wall


def run(frames: int = FRAMES, log=say) -> dict:
    d, render_s = render(frames, log)
    out = OUT / f"long_recording-{frames}.yaml"
    log(f"long_recording: rigcal calibrate on 4 x {frames} images ...")
    load0 = os.getloadavg()
    with Timer() as t:
        p = subprocess.run([_rigcal(), "calibrate", str(d), "--out", str(out), "--jobs", str(JOBS)],
                           capture_output=True, text=True)
    load1 = os.getloadavg()
    text = p.stdout + p.stderr
    if p.returncode != 0:
        return {"ok": False, "frames": frames, "error": text.strip().splitlines()[-1] if text.strip() else "?"}
    m = re.search(r"time: detection ([\d.]+) s, intrinsics ([\d.]+) s, solve ([\d.]+) s, total ([\d.]+) s", text)
    rate = re.search(r"\(([\d.]+) images/s", text)
    det, intr, solve, total = (float(x) for x in m.groups())
    return {"ok": True, "frames": frames, "images": 4 * frames, "render_s": render_s, "detection_s": det,
            "images_per_s": float(rate.group(1)) if rate else 4 * frames / det, "intrinsics_s": intr,
            "solver_s": solve, "total_s": total, "wall_s": t.wall, "cpu_s": t.cpu,
            "load_avg_before": load0, "load_avg_after": load1, "jobs": JOBS, "date": time.strftime("%Y-%m-%d %H:%M")}


def tables(r: dict) -> str:
    if not r.get("ok"):
        return f"\nlong_recording: rigcal calibrate failed: {r.get('error')}"
    rows = [[r["frames"], r["images"], r["detection_s"], r["images_per_s"], r["intrinsics_s"], r["solver_s"],
             r["total_s"], r["wall_s"],
             " / ".join(f"{x:.1f}" for x in r["load_avg_before"]) + " ; " +
             " / ".join(f"{x:.1f}" for x in r["load_avg_after"])]]
    return md_table(["frames", "images", "detection s", "images/s", "intrinsics s", "solver s",
                     "total s (command's own)", "wall s", "load avg 1/5/15 before ; after"], rows,
                    f"Long recording: rigcal calibrate, quad-forward 4 cameras x {r['frames']} frames 640x480, "
                    f"--jobs {r['jobs']} (target: end to end < 5 min on 2 cores)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=FRAMES)
    a = ap.parse_args(argv)
    r = run(a.frames)
    say(tables(r))
    write_json(f"long_recording-{a.frames}" if a.frames != FRAMES else "long_recording", r)


if __name__ == "__main__":
    main()
