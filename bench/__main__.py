"""`python -m bench` (= `make bench`): every benchmark, every table.

Sections (each also runs alone: python -m bench.<name>):

  accuracy     4 simulated scenarios vs truth, the declared rig and the CRB (seed 0)
  peer         OpenCV 5 cv2.calibrateMultiview on the same detections
  speed        `rigcal calibrate` wall/CPU time on drone-stereo-back 60 frames
  noise        error / Cramér-Rao bound over 10 seeds per scenario, with diagnostics
  montecarlo   share of true errors inside the reported 2 sigma (synthetic + rendered)
  scale        solver time and memory, 6 cameras x 100 .. 1000 frames
  dome         `rigcal calibrate` on a 60-camera dome's corners/ files, 100 / 300 / 1000 frames: time, memory
  long_recording  `rigcal calibrate` end to end on 4 cameras x 1,500 rendered frames (render cached)
  real         real photographs vs published references
  indie        scenes from an independent renderer (tests/indie_render.py) vs its truth
  indie_noise  noise_limit's error / CRB on independent renders (fisheye pair + pinhole control)
  solvers      rigcal's bundle adjustment vs gtsam's factor graph on the same problem and start
  simulate_imu `simulate --scene imu` time, 3 cameras x 30 s x 20 Hz + 200 Hz IMU; trajectory and IMU figures
  imu_calib    prototype camera-IMU estimator (not in calibrate yet): errors vs truth, sigmas, time; 30 s x 3 seeds + 30 s rendered
  ingest       `rigcal ingest` wall time on a 60 s 2-camera 20 Hz + 200 Hz IMU bag (ROS 1, ROS 2 mcap)
  aprilgrid    AprilGrid corner error vs truth by method (box, detector, long arms, exact geometry) and
               tag size in the four rendered scenes of issue 19, ChArUco alongside; EuRoC PnP

Tables go to stdout and, together, to bench/out/summary.md; numbers to
bench/out/<section>.json. Renders and detections are cached in bench/out/cache, so
a rerun skips them. Measured on 2 cores: 760 s from a fresh clone, 490 s rerun.
The dome and long_recording sections (issue 21) add about 15 min and, on a fresh clone,
5 min of rendering (measured under load 7; --quick: dome 100 frames, 300-frame recording).

    python -m bench [--only SECTION ...] [--quick]
"""

from __future__ import annotations

import argparse
import time

from . import (accuracy, aprilgrid_excess, dome, imu_calib, indie, indie_noise, ingest, long_recording,
               montecarlo, noise_limit, peer_opencv, real, scale, simulate_imu, solver_libraries, speed)
from .common import OUT, machine, say, write_json

SECTIONS = ("accuracy", "peer", "speed", "noise", "montecarlo", "scale", "dome", "long_recording", "real", "indie",
            "indie_noise", "simulate_imu", "imu_calib", "solvers", "ingest", "aprilgrid")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=SECTIONS, help="run only these sections")
    ap.add_argument("--quick", action="store_true",
                    help="fewer seeds and sizes (noise limit 3 seeds, Monte Carlo 10, scale up to 200 frames, dome 100, long recording 300)")
    a = ap.parse_args(argv)
    todo = a.only or SECTIONS
    t0 = time.perf_counter()
    info = machine()
    say(f"rigcal benchmarks - {info['date']}, {info['cpus']} CPUs, load average {info['load_avg_1_5_15']}, "
        f"OpenCV {info['opencv']}, numpy {info['numpy']}, Python {info['python']}")
    out: list[str] = []
    timings = {}

    def section(name: str, fn):
        t = time.perf_counter()
        text = fn()
        timings[name] = time.perf_counter() - t
        say(text)
        say(f"\n({name}: {timings[name]:.0f} s)")
        out.append(text)

    acc = None
    if "accuracy" in todo:
        def accu():
            nonlocal acc
            acc = accuracy.run()
            write_json("accuracy", {"results": acc, "machine": info})
            return accuracy.tables(acc)
        section("accuracy", accu)
    if "peer" in todo:
        def peer():
            res = peer_opencv.run(accuracy=acc)
            write_json("peer_opencv", {"results": res, "machine": info})
            return peer_opencv.tables(res)
        section("peer", peer)
    if "speed" in todo:
        def sp():
            r = speed.run()
            write_json("speed", r)
            return speed.tables(r)
        section("speed", sp)
    nl = None
    if "noise" in todo:
        def noise():
            nonlocal nl
            nl = noise_limit.run(seeds=3 if a.quick else 10, diag_seeds=1 if a.quick else 3)
            write_json("noise_limit", {**nl, "machine": info})
            return noise_limit.tables(nl)
        section("noise", noise)
    if "montecarlo" in todo:
        def mc():
            r = montecarlo.run(seeds=10 if a.quick else 30)
            write_json("montecarlo", {**r, "machine": info})
            return montecarlo.tables(r, nl)
        section("montecarlo", mc)
    if "scale" in todo:
        def sc():
            r = scale.run((100, 200) if a.quick else scale.FRAMES)
            write_json("scale", {"results": r, "machine": info})
            return scale.tables(r)
        section("scale", sc)
    if "dome" in todo:
        def dm():
            r = dome.run((100,) if a.quick else dome.FRAMES)
            write_json("dome", {"results": r, "machine": info})
            return dome.tables(r)
        section("dome", dm)
    if "long_recording" in todo:
        def lr():
            r = long_recording.run(300 if a.quick else long_recording.FRAMES)
            write_json("long_recording", {**r, "machine": info})
            return long_recording.tables(r)
        section("long_recording", lr)
    if "real" in todo:
        def rl():
            r = real.run()
            write_json("real", {"results": r, "machine": info})
            return real.tables(r)
        section("real", rl)
    if "indie" in todo:
        def ind():
            r = indie.run()
            write_json("indie", {"results": r, "machine": info})
            return indie.tables(r)
        section("indie", ind)
    if "indie_noise" in todo:
        def ind_noise():
            r = indie_noise.run(seeds=3 if a.quick else 10)
            write_json("indie_noise", {**r, "machine": info})
            return indie_noise.tables(r)
        section("indie_noise", ind_noise)
    if "simulate_imu" in todo:
        def sim_imu():
            r = simulate_imu.run(duration=5.0 if a.quick else 30.0)
            write_json("simulate_imu", {**r, "machine": info})
            return simulate_imu.tables(r)
        section("simulate_imu", sim_imu)
    if "imu_calib" in todo:
        def imu_cal():
            r = imu_calib.run(duration=8.0 if a.quick else 30.0, seeds=1 if a.quick else 3,
                              rendered=4.0 if a.quick else 30.0)
            write_json("imu_calib", {**r, "machine": info})
            return imu_calib.tables(r)
        section("imu_calib", imu_cal)
    if "solvers" in todo:
        def solvers():
            r = solver_libraries.run((100,) if a.quick else solver_libraries.FRAMES)
            write_json("solver_libraries", {"results": r, "machine": info})
            return solver_libraries.tables(r)
        section("solvers", solvers)
    if "ingest" in todo:
        def ing():
            r = ingest.run(seconds=10.0 if a.quick else 60.0)
            write_json("ingest", {**r, "machine": info})
            return ingest.tables(r)
        section("ingest", ing)
    if "aprilgrid" in todo:
        def april():
            r = aprilgrid_excess.run(frames=1 if a.quick else 3)
            write_json("aprilgrid_excess", {**r, "machine": info})
            return aprilgrid_excess.tables(r)
        section("aprilgrid", april)
    total = time.perf_counter() - t0
    head = (f"# rigcal benchmarks\n\n{info['date']}; {info['cpus']} CPUs; load average at start "
            f"{info['load_avg_1_5_15']}; {info['platform']}; Python {info['python']}, OpenCV {info['opencv']}, "
            f"numpy {info['numpy']}. Total {total:.0f} s (" +
            ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ").\n")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "summary.md").write_text(head + "\n".join(out) + "\n", encoding="utf-8")
    say(f"\nall benchmarks: {total:.0f} s; tables in {OUT / 'summary.md'}")


if __name__ == "__main__":
    main()
