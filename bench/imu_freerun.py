"""Benchmark: `rigcal calibrate` on free-running and mixed-rate camera-IMU recordings against
a synchronised recording of the same motion.

Per case and seed: `rigcal simulate rigs/drone-stereo-back-imu.yaml --scene imu --duration D
--seed N` plus the case's options (rendered; kept in bench/out/imu_freerun/), `rigcal
calibrate` with its defaults, then every camera's T_imu_cam (rotation deg, translation mm),
clock offset (ms) and, with a rolling shutter, line delay (us/row) against truth.yaml, and
each component's error in units of its reported 1-sigma (bench.imu_coverage's
normalised_errors: rotation and translation in body axes, time offset, intrinsics).

Cases (the same seed gives the same motion, boards and true rig in every case):

  synchronised   every camera at 20 Hz on one stem grid (the reference)
  free-running   --free-running: own phase, period error, jitter, start and stop per camera
  mixed-rate     --free-running --camera-rate front_left=20 front_right=30 back=15
  rolling        free-running with a rolling shutter on every camera (line_delay_s 30 us/row
                 declared, 14 ms readout), line delays estimated
  rolling-synchronised  the same rolling-shutter rig synchronised (rolling's reference)

    python -m bench.imu_freerun [--seeds N] [--duration S] [--cases NAME ...] [--reuse]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import yaml

from rigcal.core.rig import load_rig
from rigcal.data.truth import load_truth
from rigcal.results.imu_outputs import compare_imu

from .common import JOBS, OUT, RIGS, Timer, md_table, say, write_json
from .imu_coverage import normalised_errors

RIG = RIGS / "drone-stereo-back-imu.yaml"
LINE_DELAY_S = 3.0e-5
CASES = {
    "synchronised": (),
    "free-running": ("--free-running",),
    "mixed-rate": ("--free-running", "--camera-rate", "front_left=20", "--camera-rate", "front_right=30",
                   "--camera-rate", "back=15"),
    "rolling": ("--free-running",),
    "rolling-synchronised": (),
}


def _rigcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rigcal", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "250"})


def _rig(case: str):
    """The rig file of a case: the shipped one, or with a rolling shutter on every camera."""
    if not case.startswith("rolling"):
        return RIG
    p = OUT / "imu_freerun" / "rig-rolling.yaml"
    p.parent.mkdir(parents=True, exist_ok=True)
    delay = f"    line_delay_s: {LINE_DELAY_S:.1e}\n"  # 3.0e-05: YAML reads 3e-05 as text
    text = RIG.read_text().replace("    axes: [-L, -U, F]\n", "    axes: [-L, -U, F]\n" + delay)
    p.write_text(text.replace("    axes: [L, -U, -F]\n", "    axes: [L, -U, -F]\n" + delay))
    return p


def one(case: str, seed: int, duration: float, log=say, reuse: bool = False) -> dict:
    """One case and seed: simulate (kept), calibrate, score. reuse: take the scores of an
    earlier run of this case, seed and duration when bench/out/imu_freerun holds them."""
    d = OUT / "imu_freerun" / f"{case}_{duration:g}s_seed{seed}"
    kept = OUT / "imu_freerun" / f"scores_{case}_{duration:g}s_seed{seed}.json"
    if reuse and kept.is_file():
        return json.loads(kept.read_text())
    if not (d / "truth.yaml").is_file():
        with Timer() as t:
            r = _rigcal("simulate", str(_rig(case)), "--out", str(d), "--scene", "imu", "--duration", f"{duration:g}",
                        "--seed", str(seed), "--jobs", str(JOBS), "--force", *CASES[case])
        if r.returncode != 0:
            raise RuntimeError(f"rigcal simulate failed: {r.stderr.strip()[-2000:]}")
        log(f"  {case} seed {seed}: simulated in {t.wall:.0f} s")
    out = OUT / "imu_freerun" / f"calibrated_{case}_{duration:g}s_seed{seed}.yaml"
    with Timer() as t:
        r = _rigcal("calibrate", str(d), "--out", str(out), "--jobs", str(JOBS))
    if r.returncode != 0:
        raise RuntimeError(f"rigcal calibrate failed ({r.returncode}): {r.stderr.strip()[-2000:]}")
    est, truth = load_rig(out), load_truth(d / "truth.yaml").rig
    doc = yaml.safe_load((d / "truth.yaml").read_text())
    errs = compare_imu(est, truth, doc)["cameras"]
    z = _normalised(est, truth, doc)
    z_formal = _normalised(with_formal_sigmas(est), truth, doc)
    images = {c: sum(1 for _ in (d / "images" / c).glob("*.png")) for c in est.names}
    res = {"case": case, "seed": seed, "wall_s": t.wall, "images": images,
           "cameras": {n: {k: float(v) for k, v in e.items()} for n, e in errs.items()},
           "z": {k: v.tolist() for k, v in z.items()}, "z_formal": {k: v.tolist() for k, v in z_formal.items()}}
    worst = max(e["imu0_rot_deg"] for e in errs.values()), max(e["imu0_pos_mm"] for e in errs.values())
    kept.write_text(json.dumps(res))
    log(f"  {case} seed {seed}: calibrate {t.wall:.0f} s; worst {worst[0]:.4f} deg, {worst[1]:.3f} mm, "
        f"offsets {', '.join('%+.4f' % e['offset_ms'] for e in errs.values())} ms")
    return res


def with_formal_sigmas(est):
    """The calibrated rig with each camera's sigmas the formal ones its sigma_check recorded
    (formal_sigma: before the halves raised any), where it recorded them."""
    formal = ((est.calibration or {}).get("camera_imu") or {}).get("sigma_check", {}).get("formal_sigma", {})
    cams = [replace(c, calibration={**c.calibration, "sigma": {**c.calibration["sigma"], **formal[c.name]}})
            if c.name in formal else c for c in est.cameras]
    return est.with_cameras(cams)


def _normalised(est, truth, doc) -> dict:
    """normalised_errors, the intrinsics left out when some reported intrinsic sigma is 0 (a
    value tied to another, e.g. fy with fx=fy)."""
    if all(v for c in est.cameras for v in c.calibration["sigma"].get("intrinsics", {}).values()):
        return normalised_errors(est, truth, doc)
    cams = [replace(c, calibration={**c.calibration, "sigma": {k: v for k, v in c.calibration["sigma"].items()
                                                               if k != "intrinsics"}}) for c in est.cameras]
    return normalised_errors(est.with_cameras(cams), truth, doc)


def run(seeds: int = 3, duration: float = 30.0, cases=tuple(CASES), log=say, reuse: bool = False) -> dict:
    return {"duration_s": duration, "seeds": seeds,
            "runs": [one(c, s, duration, log, reuse) for s in range(seeds) for c in cases]}


def summary(res: dict) -> dict[str, dict]:
    out = {}
    for case in dict.fromkeys(r["case"] for r in res["runs"]):
        runs = [r for r in res["runs"] if r["case"] == case]
        e = [c for r in runs for c in r["cameras"].values()]
        z = np.abs(np.concatenate([np.ravel(r["z"][k]) for r in runs for k in r["z"]]))
        zf = [np.ravel(r["z_formal"][k]) for r in runs if "z_formal" in r for k in r["z_formal"]]
        zf = np.abs(np.concatenate(zf)) if zf else np.zeros(0)
        row = {"runs": len(runs), "rot_deg_max": max(x["imu0_rot_deg"] for x in e),
               "rot_deg_rms": float(np.sqrt(np.mean([x["imu0_rot_deg"] ** 2 for x in e]))),
               "pos_mm_max": max(x["imu0_pos_mm"] for x in e),
               "pos_mm_rms": float(np.sqrt(np.mean([x["imu0_pos_mm"] ** 2 for x in e]))),
               "offset_ms_max": max(abs(x["offset_ms"]) for x in e), "within_2_sigma": float(np.mean(z <= 2)),
               "components": int(z.size), "z_rms": float(np.sqrt(np.mean(z ** 2)))}
        if zf.size:  # the same errors against the formal sigmas (before the halves raised any)
            row |= {"within_2_formal": float(np.mean(zf <= 2)), "z_formal_rms": float(np.sqrt(np.mean(zf ** 2))),
                    "components_formal": int(zf.size)}
        if all("line_delay_us" in x for x in e) and case.startswith("rolling"):
            row["line_delay_us_max"] = max(abs(x["line_delay_us"]) for x in e)
        out[case] = row
    return out


def tables(res: dict) -> str:
    rows = [[case, s["runs"], f"{s['rot_deg_rms']:.4f} / {s['rot_deg_max']:.4f}",
             f"{s['pos_mm_rms']:.3f} / {s['pos_mm_max']:.3f}", f"{s['offset_ms_max']:.4f}",
             f"{s['line_delay_us_max']:.3f}" if "line_delay_us_max" in s else "-",
             _share(s["within_2_sigma"], s["components"]),
             _share(s["within_2_formal"], s["components_formal"]) if "within_2_formal" in s else "-",
             f"{s['z_rms']:.2f} / {s['z_formal_rms']:.2f}" if "z_formal_rms" in s else f"{s['z_rms']:.2f} / -"]
            for case, s in summary(res).items()]
    return md_table(["case", "seeds", "T_imu_cam rot deg (RMS / max)", "T_imu_cam pos mm (RMS / max)",
                     "|offset| ms max", "|line delay| us max", "within 2 reported sigma",
                    "within 2 formal sigma", "error/sigma RMS (reported / formal)"], rows,
                    title=f"`rigcal calibrate` on {res['duration_s']:g} s rendered recordings of "
                          f"drone-stereo-back-imu: "
                          f"free-running and mixed-rate cameras vs synchronised (errors against truth.yaml)") + \
        "\n\n" + _coverage_table(res)


def _share(p: float, n: int) -> str:
    """A share of n components with its binomial 1-sigma (the components of one seed share
    its IMU's errors, so this is a lower bound)."""
    return f"{100 * p:.0f} +- {100 * np.sqrt(max(p * (1 - p), 1e-12) / max(n, 1)):.0f} % of {n}"


def _coverage_table(res: dict) -> str:
    """Per case and parameter kind the share of components within 2 reported sigmas."""
    cases = list(dict.fromkeys(r["case"] for r in res["runs"]))
    kinds = list(dict.fromkeys(k for r in res["runs"] for k in r["z"]))
    rows = []
    for k in kinds:
        row = [k]
        for case in cases:
            z = [np.abs(np.ravel(r["z"][k])) for r in res["runs"] if r["case"] == case and k in r["z"]]
            z = np.concatenate(z) if z else np.zeros(0)
            row.append(f"{100 * np.mean(z <= 2):.0f} % of {z.size}" if z.size else "-")
        rows.append(row)
    return md_table(["parameter", *cases], rows, title="components within 2 reported sigma (target 90-98 %)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--cases", nargs="+", choices=tuple(CASES), default=tuple(CASES))
    ap.add_argument("--reuse", action="store_true", help="reuse the scores of earlier runs (same case, seed, duration)")
    a = ap.parse_args(argv)
    res = run(a.seeds, a.duration, a.cases, reuse=a.reuse)
    write_json("imu_freerun", res)
    print(tables(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
