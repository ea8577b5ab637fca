"""Benchmark: `rigcal calibrate` on camera + IMU recordings from an independent generator
(tests/support/indie_motion.py: closed-form motion, its own IMU model, indie_render's ray
caster; no rigcal code), errors against its truth.

Per seed: render the recording (12 s by default; three free-running pinhole cameras at
20 / 30 / 15 Hz, 480 x 360, 2 x 2 samples per pixel, clock offsets of 1.5-6 ms, one camera
starting late and one stopping early, dropped frames; a 400 Hz IMU mounted off-centre and
turned; kept in bench/out/indie_imu/), run `rigcal calibrate DATASET --out X` with nothing
else, as a new user would, then score the calibrated YAML against truth.yaml, both read as
plain YAML (no rigcal code in the scoring either):

  * per camera T_imu_cam: rotation error (deg) and translation error (mm), and per component
    (body axes of the estimate, as rigcal reports its sigmas) error / reported 1-sigma;
  * per camera the clock offset error (ms) / its 1-sigma;
  * the IMU's mean gyroscope and accelerometer biases against the mean of the true biases,
    per component / 1-sigma;
  * per camera fx, fy, cx, cy error / 1-sigma.

The share of all those components within 2 reported sigmas is the issue's 90-98 % target.

    python -m bench.indie_imu [--seeds N] [--duration S] [--first K] [--reuse]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import yaml

from .common import OUT, Timer, md_table, say, write_json

from tests.support import indie_motion as im
from tests.support import indie_render as ir

DIR = OUT / "indie_imu"


def _T(d: dict) -> np.ndarray:
    """A pose block of a rig YAML (`rotation` matrix, `position`) as a 4x4 matrix."""
    return ir.pose(np.asarray(d["rotation"], float), np.asarray(d["position"], float))


def score(cal: dict, truth: dict) -> dict:
    """Errors and error / reported sigma of a calibrated rig (dict) against truth.yaml (dict)."""
    imu_name = next(iter(truth["imus"]))
    imu = cal["imus"][imu_name]
    T_bi = _T(imu)
    R_bi = T_bi[:3, :3]
    T_bi_true = _T(truth["rig"]["imus"][imu_name])
    cams, z = {}, {"rotation": [], "translation": [], "time offset": [], "intrinsics": []}
    for name, tc in truth["rig"]["cameras"].items():
        c = cal["cameras"][name]
        sig = c["calibration"]["sigma"]
        T_est = ir.inv(T_bi) @ _T(c)
        T_true = ir.inv(T_bi_true) @ _T(tc)
        d_rot = cv2.Rodrigues(R_bi @ T_est[:3, :3] @ T_true[:3, :3].T @ R_bi.T)[0].ravel()  # rad, body axes
        d_pos = R_bi @ (T_est[:3, 3] - T_true[:3, 3])  # m, body axes
        d_off = float(c.get("time_offset_s", 0.0)) - float(tc["time_offset_s"])
        it, it_true = c["intrinsics"], tc["intrinsics"]
        d_int = {k: float(it[k]) - float(it_true[k]) for k in ("fx", "fy", "cx", "cy") if k in it}
        cams[name] = {"rot_deg": float(np.degrees(np.linalg.norm(d_rot))),
                      "pos_mm": float(1000 * np.linalg.norm(d_pos)), "offset_ms": 1000 * d_off,
                      "rot_deg_xyz": np.degrees(d_rot).tolist(), "pos_mm_xyz": (1000 * d_pos).tolist(),
                      "intrinsics_px": d_int}
        z["rotation"] += list(np.degrees(d_rot) / np.asarray(sig["rotation_deg"], float))
        z["translation"] += list(1000 * d_pos / np.asarray(sig["position_mm"], float))
        z["time offset"].append(1000 * d_off / float(sig["time_offset_ms"]))
        si = sig.get("intrinsics") or {}
        z["intrinsics"] += [d_int[k] / float(si[k]) for k in d_int if si.get(k)]
    biases = {}
    icals = imu.get("calibration") or {}
    for key, kind in (("gyroscope_bias", "gyroscope bias"), ("accelerometer_bias", "accelerometer bias")):
        if key not in icals:
            continue
        true = np.mean(np.asarray(truth["imus"][imu_name][key]["values"], float), axis=0)
        err = np.asarray(icals[key], float) - true
        biases[key] = {"error": err.tolist(), "true": true.tolist()}
        s = (icals.get("sigma") or {}).get(key)
        if s is not None:
            z[kind] = list(err / np.asarray(s, float))
    return {"cameras": cams, "biases": biases, "z": {k: [float(x) for x in v] for k, v in z.items() if v}}


def _rigcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rigcal", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "250"})


def one(seed: int, duration: float, log=say, reuse: bool = False) -> dict:
    """One seed: render (kept), calibrate, score. reuse: take the scores of an earlier run of
    this seed and duration when bench/out/indie_imu holds them."""
    ds = DIR / f"{duration:g}s_seed{seed}"
    kept = DIR / f"scores_{duration:g}s_seed{seed}.json"
    if reuse and kept.is_file():
        return json.loads(kept.read_text())
    res: dict = {"seed": seed, "duration_s": duration}
    if not (ds / "truth.yaml").is_file():
        with Timer() as t:
            im.write_recording(im.recording(seed=seed, duration=duration), ds, S=2)
        res["render_wall_s"], res["render_cpu_s"] = t.wall, t.cpu
        log(f"  seed {seed}: rendered {duration:g} s in {t.wall:.0f} s wall / {t.cpu:.0f} s CPU")
    res["images"] = {p.name: sum(1 for _ in p.glob("*.png")) for p in sorted((ds / "images").iterdir())}
    out = DIR / f"calibrated_{duration:g}s_seed{seed}.yaml"
    with Timer() as t:
        r = _rigcal("calibrate", str(ds), "--out", str(out))
    res["calibrate_wall_s"], res["calibrate_cpu_s"] = t.wall, t.cpu
    (DIR / f"calibrate_{duration:g}s_seed{seed}.log").write_text(r.stdout + r.stderr, encoding="utf-8")
    if r.returncode != 0:
        lines = (r.stdout + r.stderr).strip().splitlines()
        res["error"] = f"exit {r.returncode}: {lines[-1] if lines else ''}"
        log(f"  seed {seed}: calibrate FAILED {res['error']}")
        return res
    res |= score(yaml.safe_load(out.read_text()), yaml.safe_load((ds / "truth.yaml").read_text()))
    e = res["cameras"].values()
    log(f"  seed {seed}: calibrate {t.wall:.0f} s wall / {t.cpu:.0f} s CPU; "
        f"worst {max(x['rot_deg'] for x in e):.4f} deg, "
        f"{max(x['pos_mm'] for x in e):.3f} mm, offsets {', '.join('%+.4f' % x['offset_ms'] for x in e)} ms")
    kept.write_text(json.dumps(res), encoding="utf-8")
    return res


def run(seeds: int = 3, duration: float = 12.0, first: int = 0, log=say, reuse: bool = False) -> dict:
    DIR.mkdir(parents=True, exist_ok=True)
    return {"duration_s": duration, "runs": [one(s, duration, log, reuse) for s in range(first, first + seeds)]}


def tables(res: dict) -> str:
    ok = [r for r in res["runs"] if "error" not in r]
    rows = []
    for r in res["runs"]:
        if "error" in r:
            rows.append([r["seed"], "-", "-", "-", "-", "-", f"FAILED: {r['error']}"])
            continue
        for n, c in r["cameras"].items():
            rows.append([r["seed"], n, f"{c['rot_deg']:.4f}", f"{c['pos_mm']:.3f}", f"{c['offset_ms']:+.4f}",
                         ", ".join(f"{k} {v:+.2f}" for k, v in c["intrinsics_px"].items()), ""])
    out = [md_table(["seed", "camera", "T_imu_cam rot err deg", "pos err mm", "offset err ms", "intrinsics err px",
                     "note"], rows,
                    title=f"`rigcal calibrate` (defaults) on {res['duration_s']:g} s independent recordings "
                          f"(tests/support/indie_motion.py) vs their truth")]
    if ok:
        kinds = list(dict.fromkeys(k for r in ok for k in r["z"]))
        rows = []
        allz = []
        for k in kinds:
            z = np.abs(np.concatenate([np.asarray(r["z"][k]) for r in ok if k in r["z"]]))
            allz.append(z)
            rows.append([k, z.size, f"{100 * np.mean(z <= 2):.0f} %", f"{np.sqrt(np.mean(z ** 2)):.2f}",
                         f"{z.max():.1f}"])
        z = np.concatenate(allz)
        rows.append(["all", z.size, f"{100 * np.mean(z <= 2):.0f} %", f"{np.sqrt(np.mean(z ** 2)):.2f}",
                     f"{z.max():.1f}"])
        out.append(md_table(["parameter", "components", "within 2 sigma", "error/sigma RMS", "max"], rows,
                            title="error / reported 1-sigma (target 90-98 % within 2)"))
        e = [c for r in ok for c in r["cameras"].values()]
        b = [r["biases"] for r in ok]
        rms = lambda k: float(np.sqrt(np.mean([x[k] ** 2 for x in e])))  # noqa: E731
        top = lambda k: max(abs(x[k]) for x in e)  # noqa: E731
        bias = lambda k: max(np.abs(x[k]["error"]).max() for x in b if k in x)  # noqa: E731
        offsets = [x["offset_ms"] for x in e]
        out.append(
            f"\nover {len(ok)} seeds (RMS / max): T_imu_cam {rms('rot_deg'):.4f} / {top('rot_deg'):.4f} deg, "
            f"{rms('pos_mm'):.3f} / {top('pos_mm'):.3f} mm; |offset| {rms('offset_ms'):.4f} / "
            f"{top('offset_ms'):.4f} ms (mean {np.mean(offsets):+.4f}); max gyro bias "
            f"{bias('gyroscope_bias'):.2e} rad/s, accel bias {bias('accelerometer_bias'):.2e} m/s^2. "
            + "; ".join(f"seed {r['seed']}: calibrate {r['calibrate_wall_s']:.0f} s wall / "
                        f"{r['calibrate_cpu_s']:.0f} s CPU" for r in ok))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=12.0)
    ap.add_argument("--first", type=int, default=0, help="first seed")
    ap.add_argument("--reuse", action="store_true", help="reuse the scores of earlier runs (same seed, duration)")
    a = ap.parse_args(argv)
    res = run(a.seeds, a.duration, a.first, reuse=a.reuse)
    write_json("indie_imu", res)
    print(tables(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
