"""Benchmark: magnetometer calibration against the IMU on simulated compass dances.

Per seed: `rigcal simulate rigs/drone-imu-mag.yaml --scene mag --duration D --seed N` (60 s
of IMU at 200 Hz and magnetometer at 100 Hz, 0.5 uT per reading in a 50 uT field, hard iron
up to 30 uT, soft iron eigenvalues within +-15 %, chip misaligned 1-3 deg from its declared
FRD mount), then the magnetometer step of `rigcal calibrate` (rigcal.mag.step) and its
result against truth.yaml: the largest error per quantity, and each reported component's
error in units of its own 1-sigma (hard iron 3, soft iron 6, R_body_mag 3 about body F/L/U,
inclination 1: 13 per seed) for the share within 2 sigma (the issue asks 90-98 %).

Side by side, the heading error each calibration leaves, level at 36 headings, on the true
noise-free readings: rigcal's joint fit, and an ellipsoid fit alone with the declared
(enum) orientation, as the onboard calibrators of PX4 and ArduPilot fit hard and soft iron
and take the chip's orientation from a list of 90-degree rotations.

    python -m bench.mag [--seeds N] [--duration S]

Speed (`--speed [S]`, default 600): `rigcal calibrate` in a fresh interpreter on a simulated
S-second dance (200 Hz IMU, 100 Hz magnetometer), its wall time and CPU time (user + system,
the child's rusage: other engineers' load inflates the wall time, not the CPU time), and the
fit's own seconds as the command prints them. The issue's budget: 10 s for 600 s on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.core import geometry as geo
from rigcal.core.rig import load_rig
from rigcal.data.imu_csv import read_imu_csv
from rigcal.data.mag_csv import read_mag_csv
from rigcal.mag import model
from rigcal.mag.ellipsoid import fit_ellipsoid
from rigcal.mag.step import check_recording, check_residuals, mag_input
from rigcal.mag.estimator import estimate
from rigcal.sim.mag_scene import simulate_mag_dataset

from .common import RIGS, md_table, say, write_json

RIG = RIGS / "drone-imu-mag.yaml"
LIMITS = {"hard_iron_uT": 0.1, "soft_iron": 0.002, "rotation_deg": 0.1, "inclination_deg": 0.05}


def one(seed: int, duration: float, work: Path) -> dict:
    rig = load_rig(RIG)
    sim = simulate_mag_dataset(rig, work / f"s{seed}", duration=duration, seed=seed)
    mag = rig.magnetometers[0]
    imu = rig.mag_imu(mag)
    inp = mag_input(rig, mag, read_mag_csv(sim.out_dir / "mag" / "mag0.csv"),
                    read_imu_csv(sim.out_dir / "imu" / f"{imu.name}.csv"), imu.T_body_imu[:3, :3])
    t0 = time.perf_counter()
    check_recording(inp)
    r = estimate(inp)
    check_residuals(inp, r)
    seconds = time.perf_counter() - t0
    truth = sim.mags["mag0"]
    R_true = sim.truth.magnetometers[0].T_body_mag[:3, :3]
    err = {"hard_iron_uT": r.hard_iron - truth.hard_iron,
           "soft_iron": model.vec_from_sym(r.soft_iron - truth.soft_iron),
           "rotation_deg": np.degrees(geo.rotvec_from_R(r.R_body_mag @ R_true.T)),
           "inclination_deg": np.array([r.inclination_deg - sim.field.inclination_deg])}
    sig = {"hard_iron_uT": r.sigma_hard_iron, "soft_iron": model.vec_from_sym(r.sigma_soft_iron),
           "rotation_deg": r.sigma_rotation_deg, "inclination_deg": np.array([r.sigma_inclination_deg])}
    # heading error on the true, noise-free readings, level at 36 headings
    psi = model.level_headings()
    incl = np.radians(sim.field.inclination_deg)
    m = model.readings(model.level_fields(sim.field.field_uT, incl, psi), truth.hard_iron, truth.soft_iron, R_true)
    joint = np.degrees(model.heading_errors(m, psi, r.hard_iron, r.soft_iron, r.R_body_mag))
    ell = fit_ellipsoid(inp.m)
    alone = np.degrees(model.heading_errors(m, psi, ell.hard_iron, ell.soft_iron, mag.T_body_mag[:3, :3]))
    return {"seed": seed, "seconds": seconds, "sigma_basis": r.sigma_basis,
            "misalignment_deg": geo.rotation_angle_deg(R_true @ mag.T_body_mag[:3, :3].T),
            "max_error": {k: float(np.abs(v).max()) for k, v in err.items()},
            "z": {k: (err[k] / sig[k]).tolist() for k in err},
            "residual_rms_uT": r.residual_rms_uT, "heading_sigma_deg": r.heading_sigma_deg,
            "heading_joint_max_deg": float(np.abs(joint).max()), "heading_joint_rms_deg": float(np.sqrt((joint ** 2).mean())),
            "heading_ellipsoid_max_deg": float(np.abs(alone).max()),
            "heading_ellipsoid_rms_deg": float(np.sqrt((alone ** 2).mean()))}


def run(seeds: int = 20, duration: float = 60.0) -> dict:
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-mag-") as tmp:
        for s in range(seeds):
            rows.append(one(s, duration, Path(tmp)))
            say(f"  seed {s}: {rows[-1]['seconds']:.1f} s, max errors "
                + ", ".join(f"{k} {v:.4f}" for k, v in rows[-1]["max_error"].items()))
    z = {k: np.concatenate([np.abs(r["z"][k]) for r in rows]) for k in LIMITS}
    allz = np.concatenate(list(z.values()))
    return {"seeds": seeds, "duration_s": duration, "rows": rows,
            "worst": {k: max(r["max_error"][k] for r in rows) for k in LIMITS},
            "within_2_sigma": {k: float((v < 2).mean()) for k, v in z.items()} | {"all": float((allz < 2).mean())},
            "seconds_mean": float(np.mean([r["seconds"] for r in rows]))}


def tables(res: dict) -> str:
    n = res["seeds"]
    acc = md_table(["quantity", "worst error over seeds", "issue's limit", "within 2 sigma"],
                   [[k, f"{res['worst'][k]:.4f}", f"{LIMITS[k]:g}", f"{100 * res['within_2_sigma'][k]:.0f} %"]
                    for k in LIMITS] + [["all components", "", "", f"{100 * res['within_2_sigma']['all']:.1f} %"]],
                   title=f"Magnetometer vs truth, {n} simulated {res['duration_s']:.0f} s compass dances "
                         f"(fit {res['seconds_mean']:.1f} s each)")
    rows = res["rows"]
    head = md_table(["calibration", "heading error, mean of max over headings (deg)", "worst (deg)",
                     "mean RMS (deg)"],
                    [["rigcal (joint, against the IMU)", f"{np.mean([r['heading_joint_max_deg'] for r in rows]):.3f}",
                      f"{max(r['heading_joint_max_deg'] for r in rows):.3f}",
                      f"{np.mean([r['heading_joint_rms_deg'] for r in rows]):.3f}"],
                     ["ellipsoid fit alone + declared enum orientation",
                      f"{np.mean([r['heading_ellipsoid_max_deg'] for r in rows]):.3f}",
                      f"{max(r['heading_ellipsoid_max_deg'] for r in rows):.3f}",
                      f"{np.mean([r['heading_ellipsoid_rms_deg'] for r in rows]):.3f}"]],
                    title="Heading error left, level, 36 headings, true readings (chip 1-3 deg off its enum)")
    pred = (f"\nPredicted heading 1-sigma (rigcal, RMS over headings): mean "
            f"{np.mean([r['heading_sigma_deg'] for r in rows]):.3f} deg; residual RMS mean "
            f"{np.mean([r['residual_rms_uT'] for r in rows]):.3f} uT (declared 0.500).\n")
    return acc + "\n" + head + pred


def speed(duration: float = 600.0, seed: int = 1, repeats: int = 2) -> dict:
    """`rigcal calibrate` on a simulated `duration`-second dance, in a fresh interpreter (its
    imports count): wall and CPU seconds per run, and the fit's seconds it prints."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-magspeed-") as tmp:
        sim = simulate_mag_dataset(load_rig(RIG), Path(tmp) / "d", duration=duration, seed=seed,
                                   rig_text=RIG.read_text(encoding="utf-8"))
        app = Path(__file__).resolve().parents[1] / "app"
        env = {**os.environ, "PYTHONPATH": str(app) + os.pathsep + os.environ.get("PYTHONPATH", "")}
        for _ in range(repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "rigcal", "calibrate", str(sim.out_dir), "--out",
                                str(Path(tmp) / "cal.yaml")], capture_output=True, text=True, env=env)
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if p.returncode != 0:
                raise RuntimeError(p.stderr)
            fit = re.search(r"readings in ([0-9.]+) s", p.stderr)
            runs.append({"wall_s": wall, "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
                         "fit_wall_s": float(fit.group(1)) if fit else None})
            say(f"  {duration:.0f} s dance: wall {wall:.1f} s, CPU {runs[-1]['cpu_s']:.1f} s, fit {runs[-1]['fit_wall_s']} s")
    return {"duration_s": duration, "runs": runs, "load_average": os.getloadavg()}


def speed_table(res: dict) -> str:
    return md_table(["run", "wall s", "CPU s (user + system)", "the fit, wall s"],
                    [[str(i + 1), f"{r['wall_s']:.1f}", f"{r['cpu_s']:.1f}", f"{r['fit_wall_s']:.1f}"]
                     for i, r in enumerate(res["runs"])],
                    title=f"`rigcal calibrate` on a {res['duration_s']:.0f} s dance (200 Hz IMU, 100 Hz magnetometer), "
                          f"load average {res['load_average'][0]:.1f} on {os.cpu_count()} cores")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--speed", type=float, nargs="?", const=600.0, default=None,
                    help="time `rigcal calibrate` on a dance of this many seconds (default 600) instead")
    a = ap.parse_args(argv)
    if a.speed is not None:
        res = speed(a.speed)
        write_json("mag_speed", res)
        say(speed_table(res))
        return
    res = run(a.seeds, a.duration)
    write_json("mag", res)
    say(tables(res))


if __name__ == "__main__":
    main()
