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
  holdout      caliscope's webcams: intrinsics and whole rigs scored on held-out frames (2-fold)
  indie        scenes from an independent renderer (tests/support/indie_render.py) vs its truth
  indie_noise  noise_limit's error / CRB on independent renders (fisheye pair + pinhole control)
  solvers      rigcal's bundle adjustment vs gtsam's factor graph on the same problem and start
  simulate_imu `simulate --scene imu` time, 3 cameras x 30 s x 20 Hz + 200 Hz IMU; trajectory and IMU figures
  imu_calib    the camera-IMU estimator alone (true intrinsics, board poses): errors vs truth, sigmas, time;
               30 s x 3 seeds + 30 s rendered
  imu_euroc    the camera-IMU estimator on EuRoC's real 72 s imu_april corners + IMU vs EuRoC's T_BS (Kalibr);
               with EuRoC's intrinsics and on each half of the recording; then `rigcal calibrate` on it
  imu_euroc_defaults  `rigcal calibrate` on EuRoC with nothing but --jobs 2: knot spacing chosen, the
               accuracy band without and with a camera calibration as --rig, halves / sigma, time
  imu_speed    `rigcal calibrate` on a simulated 30 s 3-camera IMU recording: whole time / detection time
               (target <= 1.5), errors via compare
  imu_coverage `rigcal calibrate` end to end on 20 rendered 4 s IMU recordings: every reported camera-IMU
               and intrinsic parameter's error / its 1-sigma (target: 90-98 % within 2 sigma)
  imu_freerun  `rigcal calibrate` on free-running, mixed-rate and rolling-shutter free-running 30 s recordings
               vs a synchronised one: T_imu_cam, clock offset and line delay errors, share within 2 sigma
  indie_imu    `rigcal calibrate` on free-running camera + 400 Hz IMU recordings from an independent generator
               (tests/support/indie_motion.py, no rigcal code), 12 s x 3 seeds: T_imu_cam, clock offsets,
               biases vs truth, share within 2 sigma
  visual_freerun  `rigcal calibrate` without an IMU: free-running cameras (continuous-time trajectory from the
               views alone) vs a synchronised camera-only recording of the same length, 10 s x 3 seeds:
               relative poses (deg, mm), camera-camera clock offsets (ms), share within 2 sigma
  ingest       `rigcal ingest` wall time on a 60 s 2-camera 20 Hz + 200 Hz IMU bag (ROS 1, ROS 2 mcap)
  mag          magnetometer vs truth on 20 simulated 60 s compass dances (hard/soft iron, R_body_mag,
               inclination, share within 2 sigma) and the heading error beside an ellipsoid fit alone
  check        `rigcal check`: false alarms on an unchanged drone-stereo-back and detection of one camera
               turned 0.2 deg, moved 2 mm, focal +0.3 %, principal point +2 px (20-frame recordings, level 0.01)
  aprilgrid    AprilGrid corner error vs truth by method (box, detector, long arms, exact geometry) and
               tag size in four rendered AprilGrid scenes, ChArUco alongside; EuRoC PnP
  imu_noise    `rigcal imu-noise` on simulated static recordings (seeds x 3 h at 200 Hz) vs truth, interval
               coverage, allan_variance_ros's and imu_utils's formulas on the same data; 3 h at 400 Hz end to end
  imu_noise_real  `rigcal imu-noise` on a real IMU: six published 2.8 h static recordings of an ADIS16405 beside
               its datasheet and the publishers' Allan deviation (skipped unless the .rda files are in
               bench/out/cache/imudata); simulated chips whose samples are filtered and decimated (30 x 1 h per
               filter): N vs its low-frequency truth, interval coverage

Not sections (checks run by hand, each also `python -m bench.<name>`):

  same_outputs `rigcal calibrate` on every benchmark dataset, calibrated YAMLs compared to 1e-9
               (before and after a change to the pipeline)
  faults       a messy capture (blur, truncated, black and missing images) calibrates within 1.5x of the
               clean one's error
  indie_corners  detected corners of an independent camera+IMU recording (tests/support/indie_motion.py)
               against the renderer's exact ones, by distance to the other boards' sheet edges, with and
               without detection's overlap step (`python -m bench.indie_corners DATASET`)

Finished studies, whose conclusions the documentation records (docs/accuracy.md,
docs/decisions.md), are in bench/archive/ (its README
says what each concluded and where); they are not run here and not smoke-tested.

Tables go to stdout and, together, to bench/out/summary.md; numbers to
bench/out/<section>.json. Renders and detections are cached in bench/out/cache, so
a rerun skips them. Measured on 2 cores: 760 s from a fresh clone, 490 s rerun.
The dome and long_recording sections add about 15 min and, on a fresh clone,
5 min of rendering (measured under load 7; --quick: dome 100 frames, 300-frame recording).

    python -m bench [--only SECTION ...] [--quick]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Callable

from . import (accuracy, aprilgrid_excess, check, dome, imu_calib, imu_coverage, imu_euroc, imu_freerun, imu_noise,
               imu_noise_real, imu_speed, indie, indie_imu, indie_noise, ingest, intrinsics_holdout, long_recording, mag,
               montecarlo, noise_limit, peer_opencv, real, scale, simulate_imu, solver_libraries, speed, visual_freerun)
from .common import OUT, machine, say, write_json

@dataclass(frozen=True)
class Section:
    """One benchmark section: `run(quick, done)` gives its result (`done`: the results of
    the sections before it, by name), written to bench/out/<json>.json; `tables(result,
    done)` gives its markdown."""

    name: str
    json: str
    run: Callable[[bool, dict], Any]
    tables: Callable[[Any, dict], str]


def _only(mod: ModuleType) -> Callable[[Any, dict], str]:
    return lambda r, done: mod.tables(r)


# The one table of sections, in running order (the module docstring says what each measures).
TABLE = (
    Section("accuracy", "accuracy", lambda q, d: accuracy.run(), _only(accuracy)),
    Section("peer", "peer_opencv", lambda q, d: peer_opencv.run(accuracy=d.get("accuracy")), _only(peer_opencv)),
    Section("speed", "speed", lambda q, d: speed.run(), _only(speed)),
    Section("noise", "noise_limit", lambda q, d: noise_limit.run(seeds=3 if q else 10, diag_seeds=1 if q else 3),
            _only(noise_limit)),
    Section("montecarlo", "montecarlo", lambda q, d: montecarlo.run(seeds=10 if q else 30),
            lambda r, d: montecarlo.tables(r, d.get("noise"))),
    Section("scale", "scale", lambda q, d: scale.run((100, 200) if q else scale.FRAMES), _only(scale)),
    Section("dome", "dome", lambda q, d: dome.run((100,) if q else dome.FRAMES), _only(dome)),
    Section("long_recording", "long_recording", lambda q, d: long_recording.run(300 if q else long_recording.FRAMES),
            _only(long_recording)),
    Section("real", "real", lambda q, d: real.run(), _only(real)),
    Section("holdout", "intrinsics_holdout", lambda q, d: intrinsics_holdout.run(), _only(intrinsics_holdout)),
    Section("indie", "indie", lambda q, d: indie.run(), _only(indie)),
    Section("indie_noise", "indie_noise", lambda q, d: indie_noise.run(seeds=3 if q else 10), _only(indie_noise)),
    Section("simulate_imu", "simulate_imu", lambda q, d: simulate_imu.run(duration=5.0 if q else 30.0),
            _only(simulate_imu)),
    Section("imu_calib", "imu_calib", lambda q, d: imu_calib.run(duration=8.0 if q else 30.0, seeds=1 if q else 3,
                                                                 rendered=4.0 if q else 30.0), _only(imu_calib)),
    Section("imu_euroc", "imu_euroc",
            lambda q, d: imu_euroc.run(halves=not q, euroc_intrinsics=not q, calibrate=True),
            _only(imu_euroc)),
    Section("imu_euroc_defaults", "imu_euroc_defaults", lambda q, d: imu_euroc.defaults_runs(),
            lambda r, d: imu_euroc.defaults_tables(r)),
    Section("imu_speed", "imu_speed", lambda q, d: imu_speed.run(duration=8.0 if q else 30.0), _only(imu_speed)),
    Section("imu_coverage", "imu_coverage", lambda q, d: imu_coverage.run(seeds=3 if q else 20), _only(imu_coverage)),
    Section("imu_freerun", "imu_freerun",
            lambda q, d: imu_freerun.run(seeds=1 if q else 3, duration=8.0 if q else 30.0), _only(imu_freerun)),
    Section("indie_imu", "indie_imu", lambda q, d: indie_imu.run(seeds=1 if q else 3, duration=8.0 if q else 12.0),
            _only(indie_imu)),
    Section("visual_freerun", "visual_freerun",
            lambda q, d: visual_freerun.run(seeds=1 if q else 3, duration=5.0 if q else 10.0), _only(visual_freerun)),
    Section("solvers", "solver_libraries", lambda q, d: solver_libraries.run((100,) if q else solver_libraries.FRAMES),
            _only(solver_libraries)),
    Section("ingest", "ingest", lambda q, d: ingest.run(seconds=10.0 if q else 60.0), _only(ingest)),
    Section("mag", "mag", lambda q, d: mag.run(seeds=3 if q else 20, duration=30.0 if q else 60.0), _only(mag)),
    Section("check", "check", lambda q, d: check.run(seeds=3 if q else 40, frames=20), _only(check)),
    Section("aprilgrid", "aprilgrid_excess", lambda q, d: aprilgrid_excess.run(frames=1 if q else 3),
            _only(aprilgrid_excess)),
    Section("imu_noise", "imu_noise", lambda q, d: imu_noise.run(seeds=3 if q else 10, hours=1.0 if q else 3.0,
                                                                 speed_hours=1.0 if q else 3.0,
                                                                 coverage_seeds=2 if q else 40), _only(imu_noise)),
    Section("imu_noise_real", "imu_noise_real", lambda q, d: imu_noise_real.run(filtered_seeds=10 if q else 30),
            _only(imu_noise_real)),
)
SECTIONS = tuple(s.name for s in TABLE)


def _record(result: Any, info: dict) -> dict:
    """What bench/out/<section>.json holds: a dict result with the machine beside its keys
    (a result that records its own machine facts, as speed's does, keeps them), a list as
    `results`."""
    return {"machine": info, **result} if isinstance(result, dict) else {"results": result, "machine": info}


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
    timings: dict[str, float] = {}
    done: dict[str, Any] = {}
    for sec in (s for s in TABLE if s.name in todo):
        t = time.perf_counter()
        done[sec.name] = result = sec.run(a.quick, done)
        write_json(sec.json, _record(result, info))
        text = sec.tables(result, done)
        timings[sec.name] = time.perf_counter() - t
        say(text)
        say(f"\n({sec.name}: {timings[sec.name]:.0f} s)")
        out.append(text)
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
