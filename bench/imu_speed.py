"""Benchmark: issue 18's speed target for `rigcal calibrate` with an IMU, "a simulated 30 s,
3-camera recording: whole `calibrate` <= 1.5x its detection time", and its errors.

`rigcal simulate rigs/drone-stereo-back-imu.yaml --scene imu --duration 30 --seed 0`
(1,800 images at 640x480 + a 200 Hz IMU; the render is kept in bench/out/imu_speed/ and
reused), then `rigcal calibrate` (2 detection processes) timed from start to YAML, with the
stage times its console prints (detection, intrinsics, solve, total) and the camera-IMU
step's from the YAML, then `rigcal compare` against truth.yaml.

    python -m bench.imu_speed [--duration S] [--seed N]
    python -m bench.imu_speed --after-detection [--duration S] [--seed N]

`--after-detection` times what `calibrate` does after detection, in this process (its
rusage: CPU of the main process, every thread), with the detected views read from a pickle
made by the first such run (bench/out/imu_speed/detected_<duration>s_seed<N>.pickle): the
part the speed work changes, timed in a minute instead of detection's three on a loaded
machine. The YAML goes to bench/out/imu_speed/after_detection_<duration>s_seed<N>.yaml.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import yaml

from rigcal.data.truth import load_truth
from rigcal.results.imu_outputs import compare_imu
from rigcal.core.rig import load_rig

from .common import JOBS, OUT, RIGS, Timer, md_table, say, write_json

RIG = RIGS / "drone-stereo-back-imu.yaml"
TARGET_RATIO = 1.5
_ENV = {**os.environ, "COLUMNS": "250"}  # one console line per stage line


def _rigcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rigcal", *args], capture_output=True, text=True, env=_ENV)


def simulated(duration: float, seed: int, log=say) -> Path:
    """The recording, rendered once per (duration, seed) and kept."""
    d = OUT / "imu_speed" / f"sim_{duration:g}s_seed{seed}"
    if not (d / "truth.yaml").is_file():
        log(f"  simulating {duration:g} s (seed {seed}) into {d} ...")
        with Timer() as t:
            r = _rigcal("simulate", str(RIG), "--out", str(d), "--scene", "imu", "--duration", f"{duration:g}",
                        "--seed", str(seed), "--jobs", str(JOBS))
        if r.returncode != 0:
            raise RuntimeError(f"rigcal simulate failed: {r.stderr.strip()[-2000:]}")
        (d / "simulate_seconds.json").write_text(json.dumps({"wall_s": t.wall}))
    return d


def stage_times(console: str) -> dict:
    """The console's `time: detection X s, intrinsics X s, solve X s, ..., total X s` line."""
    line = next((ln for ln in console.splitlines() if "time: detection" in ln), "")
    return {k.strip().replace(" ", "_") + "_s": float(v) for k, v in re.findall(r"([a-z ]+?) ([0-9.]+) s", line.split(":", 1)[-1])}


def run(duration: float = 30.0, seed: int = 0, log=say) -> dict:
    d = simulated(duration, seed, log)
    out_yaml = OUT / "imu_speed" / f"calibrated_{duration:g}s_seed{seed}.yaml"
    with Timer() as t:
        r = _rigcal("calibrate", str(d), "--out", str(out_yaml), "--jobs", str(JOBS))
    if r.returncode != 0:
        raise RuntimeError(f"rigcal calibrate failed ({r.returncode}): {r.stderr.strip()[-2000:]}")
    times = stage_times(r.stdout)
    doc = yaml.safe_load(out_yaml.read_text())
    cmp_run = _rigcal("compare", str(out_yaml), str(d / "truth.yaml"))
    est, truth = load_rig(out_yaml), load_truth(d / "truth.yaml")
    errs = compare_imu(est, truth.rig, yaml.safe_load((d / "truth.yaml").read_text()))
    cams = {}
    for name, e in errs["cameras"].items():
        sig = est.camera(name).calibration["sigma"]
        cams[name] = {**{k: float(v) for k, v in e.items()}, "sigma_rot_deg": sig["rotation_deg"],
                      "sigma_pos_mm": sig["position_mm"], "sigma_offset_ms": sig["time_offset_ms"]}
    images = sum(1 for _ in (d / "images").rglob("*.png"))
    res = {"duration_s": duration, "seed": seed, "images": images, "wall_s": t.wall, "stages": times,
           "camera_imu": doc["calibration"].get("camera_imu"), "cameras": cams,
           "ratio_total_to_detection": times.get("total_s", float("nan")) / times.get("detection_s", float("nan")),
           "compare_console": cmp_run.stdout[-4000:], "load_avg": os.getloadavg()[0]}
    log(f"  calibrate {t.wall:.1f} s wall; stages {times}; camera-IMU {res['camera_imu']['seconds']} s; "
        f"total / detection {res['ratio_total_to_detection']:.2f}")
    return res


def after_detection(duration: float = 30.0, seed: int = 0, log=say) -> dict:
    """`rigcal calibrate` (rigcal.commands.calibrate.run, --jobs JOBS) in this process with
    detection read from a pickle of its views (made by the first run): wall and CPU seconds
    (user + system, every thread of this process) of the rest."""
    import pickle
    import resource
    import time

    import rigcal.commands.calibrate as cal_cmd

    d = simulated(duration, seed, log)
    cache = OUT / "imu_speed" / f"detected_{duration:g}s_seed{seed}.pickle"
    out_yaml = OUT / "imu_speed" / f"after_detection_{duration:g}s_seed{seed}.yaml"
    detect = cal_cmd._detect_views

    def cached(inp, *a, **k):
        if cache.is_file():
            views, det, rig, warnings = pickle.loads(cache.read_bytes())
            return cal_cmd._Detected(views, det, rig, inp.images, warnings)
        found = detect(inp, *a, **k)
        cache.write_bytes(pickle.dumps((found.views, found.det, found.rig, found.warnings)))
        raise _Cached

    cal_cmd._detect_views = cached
    try:
        if not cache.is_file():
            try:
                cal_cmd.run(d, out_yaml, cal_cmd.CalibrateOptions(jobs=JOBS))
            except _Cached:
                log(f"  detected views kept in {cache}")
        # what run() imports on first use, imported before the clock starts
        import rigcal.camcal.pipeline, rigcal.camcal.stereo_checks, rigcal.commands.calibrate_imu  # noqa: F401, E401
        import rigcal.detect.guided, rigcal.results.outputs, rigcal.results.imu_outputs  # noqa: F401, E401
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        cal_cmd.run(d, out_yaml, cal_cmd.CalibrateOptions(jobs=JOBS))
        wall, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF)
    finally:
        cal_cmd._detect_views = detect
    res = {"duration_s": duration, "seed": seed, "wall_s": wall, "cpu_user_s": r1.ru_utime - r0.ru_utime,
           "cpu_system_s": r1.ru_stime - r0.ru_stime, "load_avg": os.getloadavg()[0], "yaml": str(out_yaml)}
    log(f"  after detection: {wall:.1f} s wall, {res['cpu_user_s']:.1f} s user + {res['cpu_system_s']:.1f} s system "
        f"CPU (load {res['load_avg']:.1f})")
    return res


class _Cached(Exception):
    """after_detection's first run: the views are kept, the rest is the timed run's."""


def tables(r: dict) -> str:
    s = r["stages"]
    head = md_table(["recording", "images", "detection s", "camera-only (intrinsics + solve) s", "camera-IMU s",
                     "whole calibrate s", "total / detection (target <= 1.5)"],
                    [[f"{r['duration_s']:g} s, seed {r['seed']}", r["images"], f"{s.get('detection_s', 0):.1f}",
                      f"{s.get('intrinsics_s', 0) + s.get('solve_s', 0):.1f}", f"{r['camera_imu']['seconds']:.1f}",
                      f"{s.get('total_s', 0):.1f}", f"{r['ratio_total_to_detection']:.2f}"]],
                    title="`rigcal calibrate` on a simulated 30 s, 3-camera IMU recording (issue 18's speed target)")
    rows = [[n, f"{e.get('imu0_rot_deg', float('nan')):.4f}", f"{e.get('imu0_pos_mm', float('nan')):.2f}",
             f"{e.get('offset_ms', float('nan')):+.4f} ({e['sigma_offset_ms']:.4f})"] for n, e in r["cameras"].items()]
    return head + "\n" + md_table(["camera", "T_imu_cam rotation err deg", "translation err mm",
                                   "time offset err ms (1-sigma)"], rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--after-detection", action="store_true",
                    help="time calibrate after detection only, in this process, detection read from a pickle")
    a = ap.parse_args(argv)
    if a.after_detection:
        write_json("imu_speed_after_detection", after_detection(a.duration, a.seed))
        return 0
    res = run(a.duration, a.seed)
    write_json("imu_speed", res)
    print(tables(res))
    print(res["compare_console"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
