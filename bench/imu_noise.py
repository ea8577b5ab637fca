"""Benchmark: `rigcal imu-noise` on simulated static recordings of known noise (rigcal.sim.static_imu),
beside the published procedures of allan_variance_ros and imu_utils applied to the same Allan
deviation; and its speed and memory on a long 400 Hz recording, end to end from the csv.

    python -m bench.imu_noise [--seeds N] [--hours H] [--rate HZ] [--speed-hours H] [--speed-rate HZ]
                              [--coverage-seeds N] [--reuse-curves]

Accuracy: the IMU of rigs/drone-stereo-back-imu.yaml (gyroscope N 1.7e-4 rad/s/sqrt(Hz), K 1.9e-5
rad/s^2/sqrt(Hz); accelerometer N 2e-3 m/s^2/sqrt(Hz), K 3e-3 m/s^3/sqrt(Hz)), flicker bias
instability at the level of the white/random-walk minimum, 16-bit quantisation; per seed and
axis the figure / truth and whether the 95 % interval holds the truth. Truth for N is the
density with the quantisation's white noise in it (what any Allan deviation sees).

Peers (their formulas, our overlapping Allan deviation at octave taus):
- allan_variance_ros (scripts/analysis.py): N = a slope -1/2 line fitted in log-log to the taus
  up to 10 s, read at 1 s; K = a slope +1/2 line fitted to *every* tau, read at 3 s; each sensor
  the worst axis.
- imu_utils (fitallan_*.cpp): sigma^2 = Q^2/tau^2 + N^2/tau + B^2 + K^2 tau + R^2 tau^2 fitted
  unweighted in log10(sigma^2); `*_n` = sqrt(rate) * the fitted deviation at 1 s, `*_w` = the
  fitted curve's minimum (its bias instability, without 0.664); the axes averaged.

Coverage (--coverage-seeds per simulator, each seed 6 independent axes, at --hours and
--rate): how often each 95 % interval holds the truth, with its binomial standard error, on
four simulators: rigcal's own (above; its flicker rolls off below about 0.1 s),
allantools' generators (`noise.white` + `noise.brown`, written apart from rigcal; white
noise + random walk), the same plus allantools' Kasdin-Walter flicker (`Noise(b=-1)`:
a bias instability flat down to the shortest taus) and tests/support/imu_static.py (white
noise + random walk). The Allan curves are kept in
bench/out (--reuse-curves reads them back instead of simulating again).

Speed: simulate --scene static's csv at --speed-rate for --speed-hours and half of it, then
`python -m rigcal imu-noise` on each in a child process: wall time and peak memory (ru_maxrss).
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from rigcal.core.rig import load_rig
from rigcal.imunoise.estimate import AXES, SENSORS, estimate
from rigcal.imunoise.recording import ImuRecording, check
from rigcal.sim.static_imu import imu_truth, simulate_imu, write_imu_csv

from .common import OUT, RIGS, md_table, say, write_json

RIG = RIGS / "drone-stereo-back-imu.yaml"
ROOT = Path(__file__).resolve().parents[1]


def avr_formulas(tau: np.ndarray, adev: np.ndarray) -> tuple[float, float]:
    """allan_variance_ros's (N, K) of one axis."""
    def intercept(sel, slope, at):
        b = np.mean(np.log(adev[sel]) - slope * np.log(tau[sel]))  # least squares with the slope fixed
        return float(np.exp(slope * np.log(at) + b))

    return intercept(tau < 10.0, -0.5, 1.0), intercept(np.ones(len(tau), bool), 0.5, 3.0)


def imu_utils_formulas(tau: np.ndarray, adev: np.ndarray, rate_hz: float) -> tuple[float, float]:
    """imu_utils's (white noise `*_n`, `*_w` = its bias instability) of one axis."""
    y2 = adev ** 2
    F = np.stack([np.sqrt(tau) ** k for k in range(-2, 3)], axis=1)  # its start: a polynomial in sqrt(tau)
    start = np.abs(np.linalg.lstsq(F, adev, rcond=None)[0])

    def model(p, t):
        Q, N, B, K, R = p
        return Q * Q / t ** 2 + N * N / t + B * B + K * K * t + R * R * t ** 2

    fit = least_squares(lambda p: np.log10(model(p, tau)) - np.log10(y2), start, method="trf")
    dense = np.asarray(tau, float)
    return float(np.sqrt(rate_hz) * np.sqrt(model(fit.x, 1.0))), float(np.sqrt(model(fit.x, dense).min()))


def one_seed(imu, duration_s: float, seed: int) -> dict:
    truth = imu_truth(imu, duration_s)
    t_ns, gyro, accel = simulate_imu(imu, duration_s, np.random.default_rng([seed, 5, 0]), truth)
    t0 = time.perf_counter()
    noise = estimate(imu.name, check(ImuRecording(f"seed {seed}", t_ns, gyro, accel)))
    secs = time.perf_counter() - t0
    out = {"seed": seed, "estimate_s": secs}
    for s in noise.sensors():
        tr = truth[s.sensor]
        n_true, k_true = tr.noise_density_with_quantisation, tr.random_walk
        axes = []
        for ax, a in zip(AXES, s.axes):
            avr_n, avr_k = avr_formulas(a.curve.tau, a.curve.adev)
            iu_n, iu_w = imu_utils_formulas(a.curve.tau, a.curve.adev, a.curve.rate_hz)
            axes.append({"axis": ax, "N": a.white.value / n_true, "K": a.random_walk.value / k_true,
                         "N_in": bool(a.white.lo <= n_true <= a.white.hi),
                         "K_in": bool(a.random_walk.lo <= k_true <= a.random_walk.hi),
                         "N_halfwidth": (a.white.hi - a.white.lo) / 2 / a.white.value,
                         "K_halfwidth": (a.random_walk.hi - a.random_walk.lo) / 2 / a.random_walk.value,
                         "B": a.bias_instability.value / tr.bias_instability,
                         "avr_N": avr_n / n_true, "avr_K": avr_k / k_true,
                         "iu_n": iu_n / n_true, "iu_w": iu_w / k_true})
        out[s.sensor] = {"axes": axes, "N_used": s.white.value / n_true, "K_used": s.random_walk.value / k_true}
    return out


# ----------------------------------------------------------------------------- coverage over many seeds
SIMULATORS = ("rigcal", "allantools", "allantools_flicker", "indie")


def simulate_axes(sim: str, imu, duration_s: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x (N, 6) gyroscope then accelerometer, true N (6,), true K (6,)) of one static recording.

    rigcal: rigcal.sim.static_imu (white, random walk, flicker as Gauss-Markov sum, 16-bit
    quantisation; N with the quantisation in it). allantools: its own generators, written
    apart from rigcal: `noise.white(b0)` (one-sided PSD b0 = 2 N^2, Allan variance N^2 / tau) plus
    `noise.brown(b_minus2)` (PSD b_minus2 / f^2 with b_minus2 = K^2 / (2 pi^2), Allan variance
    K^2 tau / 3); seeded through numpy's legacy global generator, which allantools draws from.
    allantools_flicker: allantools' generators as above plus its Kasdin-Walter flicker
    (`allantools.Noise(b=-1)` over 2^21 samples, the largest power of two in the recording: a
    discrete 1/f series taken as the rate: frequency PSD
    h_-1 / f with h_-1 = qd / pi, Allan variance 2 ln2 h_-1 = (2 ln2 / pi) qd, so qd = B^2
    gives the flat 0.664 B) at the level where the flat floor equals the white + random-walk
    minimum, as rigcal's: a bias instability flat down to the shortest taus (above it at one
    and two samples: 1.4 and 1.15 x, the discrete 1/f's full band), where rigcal's rolls off.
    indie: tests/support/imu_static.py (white + random walk, written apart from rigcal.sim)."""
    nd = np.array([imu.gyroscope_noise_density] * 3 + [imu.accelerometer_noise_density] * 3)
    kw = np.array([imu.gyroscope_random_walk] * 3 + [imu.accelerometer_random_walk] * 3)
    rate, n = imu.update_rate, int(round(duration_s * imu.update_rate))
    if sim == "rigcal":
        truth = imu_truth(imu, duration_s)
        _, g, a = simulate_imu(imu, duration_s, np.random.default_rng([seed, 5, 0]), truth)
        nq = np.repeat([truth["gyroscope"].noise_density_with_quantisation,
                        truth["accelerometer"].noise_density_with_quantisation], 3)
        return np.hstack([g, a]), nq, kw
    if sim in ("allantools", "allantools_flicker"):
        import allantools

        np.random.seed(7_000 + seed if sim == "allantools" else 9_000 + seed)
        if sim == "allantools_flicker":
            n = 2 ** int(np.floor(np.log2(n)))  # the Kasdin generator's power-of-two length (2.9 h of 3 h)
        x = np.empty((n, 6))
        for k in range(6):
            x[:, k] = (allantools.noise.white(n, b0=2.0 * nd[k] ** 2, fs=rate)
                       + allantools.noise.brown(n, b_minus2=kw[k] ** 2 / (2.0 * np.pi ** 2), fs=rate))
            if sim == "allantools_flicker":
                flicker = allantools.Noise(nr=n, qd=2.0 * nd[k] * kw[k] / np.sqrt(3.0) / (2.0 * np.log(2.0) / np.pi),
                                           b=-1)
                flicker.generateNoise()
                x[:, k] += flicker.time_series
        x[:, 5] += 9.80665
        return x, nd, kw
    if sim == "indie":
        from tests.support.imu_static import static_imu

        _, g, a = static_imu(duration_s, rate, nd, kw, seed=1000 + seed)
        return np.hstack([g, a]), nd, kw
    raise KeyError(sim)


def coverage_curves(sim: str, imu, duration_s: float, seeds: int) -> list[dict]:
    """Per seed and axis the Allan curve (what estimate fits) with the truth beside it."""
    from rigcal.imunoise.allan import allan_deviation

    out = []
    for seed in range(seeds):
        x, nd, kw = simulate_axes(sim, imu, duration_s, seed)
        for k in range(6):
            c = allan_deviation(x[:, k], imu.update_rate)
            out.append({"sim": sim, "seed": seed, "axis": k, "tau": c.tau, "adev": c.adev, "m": c.m, "n": c.n,
                        "rate_hz": c.rate_hz, "N": float(nd[k]), "K": float(kw[k])})
        del x
    return out


def cached_curves(sim: str, imu, hours: float, seeds: int, reuse: bool) -> list[dict]:
    """coverage_curves, kept in OUT (pickle) so that a change in how the terms are read from
    the curves can be measured again without simulating again (--reuse-curves)."""
    path = OUT / f"imu_noise_curves_{sim}_{seeds}x{hours:g}h_{imu.update_rate:g}hz.pkl"
    if reuse and path.exists():
        return pickle.loads(path.read_bytes())
    curves = coverage_curves(sim, imu, hours * 3600, seeds)
    OUT.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(curves))
    return curves


def coverage(curves: list[dict]) -> dict:
    """Per sensor and term: how often the 95 % interval holds the truth (with its binomial
    standard error), the figure / truth, and the errors in units of the interval's sigma."""
    from rigcal.imunoise.allan import AllanCurve
    from rigcal.imunoise.terms import TooShort, fit_axis

    rows: dict[str, list] = {}
    short = 0
    for c in curves:
        try:
            a = fit_axis(AllanCurve(c["tau"], c["adev"], c["m"], c["n"], c["rate_hz"]))
        except TooShort:
            short += 1
            continue
        sensor = SENSORS[0] if c["axis"] < 3 else SENSORS[1]
        for term, fit, truth in (("N", a.white, c["N"]), ("K", a.random_walk, c["K"])):
            sigma = (fit.hi - fit.lo) / 2 / 1.96
            rows.setdefault(f"{sensor} {term}", []).append(
                (fit.value / truth, fit.lo <= truth <= fit.hi, (fit.hi - fit.lo) / 2 / fit.value, (fit.value - truth) / sigma))
    out = {"too_short": short}
    for key, v in rows.items():
        v = np.asarray(v, float)
        n, cov = len(v), float(v[:, 1].mean())
        out[key] = {"n": n, "covered": int(v[:, 1].sum()), "coverage": cov, "coverage_se": float(np.sqrt(cov * (1 - cov) / n)),
                    "ratio_median": float(np.median(v[:, 0])), "ratio_sd": float(np.std(v[:, 0])),
                    "worst": float(np.max(np.abs(v[:, 0] - 1))), "err_median": float(np.median(np.abs(v[:, 0] - 1))),
                    "err_p90": float(np.percentile(np.abs(v[:, 0] - 1), 90)), "halfwidth_median": float(np.median(v[:, 2])),
                    "z_sd": float(np.std(v[:, 3]))}
    return out


def coverage_table(cov: dict, seeds: int, hours: float, rate_hz: float) -> str:
    rows = []
    for sim, res in cov.items():
        for key in (f"{s} {t}" for s in SENSORS for t in ("N", "K")):
            if key not in res:
                continue
            r = res[key]
            rows.append([sim, key, f"{r['covered']}/{r['n']}",
                         f"{100 * r['coverage']:.1f} +- {100 * r['coverage_se']:.1f} %",
                         f"{100 * r['halfwidth_median']:.2g} %", f"{r['ratio_median']:.4f}", f"{100 * r['ratio_sd']:.2g} %",
                         f"{100 * r['err_median']:.2g} / {100 * r['err_p90']:.2g} / {100 * r['worst']:.2g} %",
                         f"{r['z_sd']:.2f}"])
    return md_table(["simulator", "figure", "truth inside", "coverage (binomial se)", "95 % half-width (median)",
                     "figure / truth (median)", "sd of figure / truth", "error: median / 90th percentile / worst",
                     "sd of error / sigma"], rows,
                    title=f"95 % interval coverage: {seeds} seeds x 3 axes per sensor, {hours:g} h at {rate_hz:g} Hz "
                          f"(target 90-98 %; a sd of error / sigma near 1 means the intervals are as wide as the errors)")


def speed(imu, hours: float, rate_hz: float) -> list[dict]:
    """End to end (csv -> imu.yaml) in a child process at hours/2 and hours: wall s and peak MB."""
    imu = dataclasses.replace(imu, update_rate=rate_hz)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigcal-bench-imunoise-") as tmp:
        for h in (hours / 2, hours):
            csv = Path(tmp) / f"imu_{h:g}h.csv"
            t0 = time.perf_counter()
            truth = imu_truth(imu, h * 3600)
            t_ns, g, a = simulate_imu(imu, h * 3600, np.random.default_rng([0, 5, 0]), truth)
            sim_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            write_imu_csv(csv, t_ns, g, a)
            write_s = time.perf_counter() - t0
            n = len(t_ns)
            del t_ns, g, a
            script = ("import resource, sys, time; from rigcal.cli import main; sys.argv = ['rigcal'] + sys.argv[1:]\n"
                      "t = time.perf_counter()\ntry:\n    main()\nexcept SystemExit as e:\n    code = e.code\n"
                      "r = resource.getrusage(resource.RUSAGE_SELF)\n"
                      "print('BENCH', time.perf_counter() - t, r.ru_maxrss, code, r.ru_utime + r.ru_stime, file=sys.stderr)")
            res = subprocess.run([sys.executable, "-c", script, "imu-noise", str(csv), "--out",
                                  str(Path(tmp) / "imu.yaml")], capture_output=True, text=True,
                                 env={**__import__("os").environ, "PYTHONPATH": str(ROOT / "app")})
            line = [ln for ln in res.stderr.splitlines() if ln.startswith("BENCH")]
            if not line:
                raise RuntimeError(res.stderr[-2000:])
            _, wall, rss_kb, code, cpu = line[0].split()
            rows.append({"hours": h, "rate_hz": rate_hz, "samples": n, "simulate_s": sim_s, "write_csv_s": write_s,
                         "csv_mb": csv.stat().st_size / 1e6, "imu_noise_s": float(wall), "imu_noise_cpu_s": float(cpu),
                         "peak_mb": int(rss_kb) / 1024, "exit": code})
            csv.unlink()
    return rows


def run(seeds: int = 10, hours: float = 3.0, rate_hz: float = 200.0, speed_hours: float = 3.0,
        speed_rate: float = 400.0, coverage_seeds: int = 40, reuse_curves: bool = False) -> dict:
    imu = dataclasses.replace(load_rig(RIG).imus[0], update_rate=rate_hz)
    t0 = time.perf_counter()
    results = [one_seed(imu, hours * 3600, s) for s in range(seeds)]
    acc_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    cov = {sim: coverage(cached_curves(sim, imu, hours, coverage_seeds, reuse_curves)) for sim in SIMULATORS} \
        if coverage_seeds else {}
    return {"rig": RIG.name, "seeds": seeds, "hours": hours, "rate_hz": rate_hz, "accuracy_s": acc_s,
            "results": results, "coverage_seeds": coverage_seeds, "coverage": cov,
            "coverage_s": time.perf_counter() - t0,
            "speed": speed(imu, speed_hours, speed_rate) if speed_hours > 0 else [],
            "load_avg": __import__("os").getloadavg()[0]}


def _stats(vals: list[float]) -> str:
    v = np.asarray(vals)
    return f"{np.median(v):.3f} [{v.min():.3f}, {v.max():.3f}]"


def tables(r: dict) -> str:
    out = []
    rows = []
    for sensor in SENSORS if r["results"] else ():
        ax = [a for res in r["results"] for a in res[sensor]["axes"]]
        n_err = max(abs(a["N"] - 1) for a in ax)
        k_err = max(abs(a["K"] - 1) for a in ax)
        rows.append([sensor, _stats([a["N"] for a in ax]), f"{100 * n_err:.1f} %",
                     f"{100 * np.mean([a['N_in'] for a in ax]):.0f} % (+-{100 * np.median([a['N_halfwidth'] for a in ax]):.1f} %)",
                     _stats([a["K"] for a in ax]), f"{100 * k_err:.0f} %",
                     f"{100 * np.mean([a['K_in'] for a in ax]):.0f} % (+-{100 * np.median([a['K_halfwidth'] for a in ax]):.0f} %)",
                     _stats([a["B"] for a in ax])])
    out.append("" if not rows else md_table(["sensor", "N / truth: median [min, max]", "worst N", "N in 95 % interval (half-width)",
                         "K / truth", "worst K", "K in 95 % interval", "B (flat min / 0.664) / design B"], rows,
                        title=f"imu-noise on {r['seeds']} seeds x 3 axes, {r['hours']:g} h at {r['rate_hz']:g} Hz "
                              f"(targets: N within 3 %, K within 20 %, intervals hold the truth 90-98 %)"))
    if r.get("coverage"):
        out.append(coverage_table(r["coverage"], r["coverage_seeds"], r["hours"], r["rate_hz"]))
    rows = []
    for sensor in SENSORS if r["results"] else ():
        ax = [a for res in r["results"] for a in res[sensor]["axes"]]
        rows.append([sensor, _stats([a["N"] for a in ax]), _stats([a["avr_N"] for a in ax]),
                     _stats([a["iu_n"] for a in ax]), _stats([a["K"] for a in ax]), _stats([a["avr_K"] for a in ax]),
                     _stats([a["iu_w"] for a in ax])])
    out.append("" if not rows else md_table(["sensor", "N rigcal", "N allan_variance_ros", "`*_n` imu_utils", "K rigcal",
                         "K allan_variance_ros", "`*_w` imu_utils"], rows,
                        title="the same Allan deviations through the peers' formulas (figure / truth; imu_utils's "
                              "`_n` is sqrt(rate) x the deviation at 1 s, `_w` its bias instability, which Kalibr "
                              "users paste as N and K)"))
    if r["speed"]:
        rows = [[f"{s['hours']:g} h x {s['rate_hz']:g} Hz", s["samples"], f"{s['csv_mb']:.0f}",
                 f"{s['simulate_s']:.1f}", f"{s['write_csv_s']:.1f}", f"{s['imu_noise_s']:.1f}",
                 f"{s['imu_noise_cpu_s']:.1f}",
                 f"{s['peak_mb']:.0f}", s["exit"]] for s in r["speed"]]
        out.append(md_table(["recording", "samples", "csv MB", "simulate s", "write csv s", "imu-noise s (end to end)", "its CPU s (user + sys)",
                             "imu-noise peak MB", "exit"], rows,
                            title=f"speed and memory (target: 3 h at 400 Hz in <= 30 s on 2 cores; load average "
                                  f"{r['load_avg']:.1f})"))
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--hours", type=float, default=3.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--speed-hours", type=float, default=3.0, help="0: skip the speed runs")
    ap.add_argument("--speed-rate", type=float, default=400.0)
    ap.add_argument("--coverage-seeds", type=int, default=40, help="per simulator (x 6 axes); 0: skip")
    ap.add_argument("--reuse-curves", action="store_true", help="the coverage runs' Allan curves from bench/out")
    a = ap.parse_args(argv)
    r = run(a.seeds, a.hours, a.rate, a.speed_hours, a.speed_rate, a.coverage_seeds, a.reuse_curves)
    write_json("imu_noise" if a.seeds else "imu_noise_speed", r)
    text = tables(r)
    say(text)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / ("imu_noise.md" if a.seeds else "imu_noise_speed.md")).write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
